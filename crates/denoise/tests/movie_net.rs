//! `--method temporal-net` (the bundled `movie` network) on stacks of the virtual camera: a
//! streamed stack is the windows computed in memory, a movie's ends show the frames mirrored
//! about the frame and a lone frame shows itself in every slot; the window is the network's;
//! and against known truth, as the classical method is tested (crates/classical/tests): an event
//! in one frame stays in that frame, a uniform region's mean and a bleaching scene's mean per
//! frame stay the data's (the window is brought to the frame's brightness along the scene's
//! trend first), and nothing crosses a scene cut (the window ends at a neighbour of another
//! scene), down to half an electron per pixel.

mod common;

use emccd_camera::{PhysicalParams, VirtualCamera};
use emccd_classical::frame::preprocess;
use emccd_denoise::movie::{guide, net_window};
use emccd_denoise::stack::denoise_file;
use emccd_denoise::{resolve, Denoiser, Method, Units};
use emccd_nn::norm::mirror;
use emccd_nn::{Inference, Model, MOVIE_WINDOW};
use emccd_profile::{CameraProfile, Recording};

const W: usize = 64;
const H: usize = 64;
const EXPOSURE: f64 = 0.01;

fn profile() -> CameraProfile {
    emccd_profile::default_profile()
        .crop(emccd_profile::Roi::corner(W, H))
        .unwrap()
}

fn model() -> Model {
    emccd_denoise::bundled::load("movie", &emccd_nn::cpu()).unwrap()
}

fn net<'a>(p: &'a CameraProfile, m: &'a Model) -> Denoiser<'a> {
    Denoiser {
        profile: p,
        method: Method::TemporalNet,
        model: Some(m),
        tiling: Default::default(),
        ensemble: 1,
        units: Units::Dn,
        window: MOVIE_WINDOW,
    }
}

/// Raw frames of the virtual camera (photons per pixel per frame), seeds from `seed`.
fn shoot(p: &CameraProfile, photons: &[Vec<f32>], seed: u64) -> Vec<Vec<f32>> {
    let cam = VirtualCamera::new(p.clone(), PhysicalParams::default()).unwrap();
    let e = cam.exposure(EXPOSURE);
    photons
        .iter()
        .enumerate()
        .map(|(k, ph)| {
            let mut raw = vec![0f32; W * H];
            e.frame(ph, seed + k as u64, &mut raw);
            raw
        })
        .collect()
}

/// DN per photon (the ground truth's factor: `K·QE`).
fn dn_per_photon(p: &CameraProfile) -> f64 {
    let cam = VirtualCamera::new(p.clone(), PhysicalParams::default()).unwrap();
    cam.k_dn() * PhysicalParams::default().qe
}

/// Bars, a gradient and a blob, `peak` photons at the brightest.
fn scene(peak: f32) -> Vec<f32> {
    (0..W * H)
        .map(|i| {
            let (x, y) = ((i % W) as f32, (i / W) as f32);
            let bars = 0.325 + 0.175 * (std::f32::consts::PI * x / 8.0).sin().signum();
            let blob = (-((x - 40.0).powi(2) + (y - 20.0).powi(2)) / 30.0).exp();
            peak * (bars + 0.25 * y / H as f32 + 0.25 * blob)
        })
        .collect()
}

/// Every frame of `raws` denoised by the network (through the `Denoiser`, in memory).
fn every_frame(fd: &Denoiser, raws: &[Vec<f32>]) -> Vec<Vec<f32>> {
    let mut out = Vec::new();
    let flat: Vec<f32> = raws.concat();
    emccd_denoise::movie::denoise_slice(fd, EXPOSURE, &flat, &mut |_, f| {
        out.push(f);
        Ok(())
    })
    .unwrap();
    out
}

fn mean(v: &[f32]) -> f64 {
    v.iter().map(|&x| x as f64).sum::<f64>() / v.len() as f64
}

/// A bad frame in the middle is named, and the frames whose windows were found before it are
/// handed over first: the network denoises a frame's window while the next one's is found, so
/// frame 2's (complete once frame 4 was read) is still waiting when frame 5 fails.
#[test]
fn a_bad_frame_in_the_middle_is_named_after_the_frames_before_it() {
    let (p, m) = (profile(), model());
    let mut raws = shoot(&p, &vec![scene(4.0); 7], 900);
    raws[4][17] = f32::NAN;
    let (e, emitted) = common::stream(&net(&p, &m), EXPOSURE, &raws);
    let e = e.expect("a NaN frame is refused");
    assert!(
        e.contains("nan.tif: frame 5") && e.contains("non-finite value at pixel (17, 0)"),
        "{e}"
    );
    // Frames 1 and 2 need frames up to 3 and 4; frame 3's window holds frame 5.
    assert_eq!(emitted, vec![0, 1]);
}

#[test]
fn a_streamed_stack_is_the_mirrored_windows_computed_in_memory() {
    let (p, m) = (profile(), model());
    let dir = tempfile::tempdir().unwrap();
    let raws = shoot(&p, &vec![scene(4.0); 6], 500);
    let input = dir.path().join("movie.tif");
    let mut wr =
        emccd_io::StackWriter::create(&input, W, H, emccd_io::SampleFormat::F32, Some(6)).unwrap();
    wr.set_metadata(&emccd_io::Metadata {
        exposure_s: Some(EXPOSURE),
        ..Default::default()
    });
    for f in &raws {
        wr.write_frame(f).unwrap();
    }
    wr.finish().unwrap();
    let out = dir.path().join("out.tif");
    let rec = Recording::open(&input, &p, None, "--exposure-s", false).unwrap();
    assert_eq!(
        denoise_file(&net(&p, &m), rec, &out, &mut || ()).unwrap(),
        6
    );
    let (_, got) = emccd_io::read_all(&out).unwrap();
    let pre: Vec<Vec<f32>> = raws
        .iter()
        .map(|r| preprocess(&p, r, EXPOSURE).unwrap())
        .collect();
    let inference = Inference::new(&m, &p);
    let noise = emccd_classical::frame::vst_params(&p, EXPOSURE).unwrap();
    let guides: Vec<Vec<f32>> = pre.iter().map(|f| guide(f, W)).collect();
    let k = MOVIE_WINDOW;
    for (t, g) in got.iter().enumerate() {
        let (lo, hi) = (t.saturating_sub(k), (t + k + 1).min(6));
        let window: Vec<&[f32]> = pre[lo..hi].iter().map(Vec::as_slice).collect();
        let gw: Vec<&[f32]> = guides[lo..hi].iter().map(Vec::as_slice).collect();
        let shown = net_window(&window, &gw, t - lo, k, W, noise);
        // A still scene: every frame is the frame's scene, mirrored at the ends.
        for (d, f) in (-(k as isize)..=k as isize).zip(&shown) {
            let j = mirror(t, d, 6);
            let s = f[0] / pre[j][0];
            assert!(
                (s - 1.0).abs() < 0.05,
                "frame {t}, slot {d}: brightness × {s}"
            );
            assert!(f
                .iter()
                .zip(&pre[j])
                .all(|(a, b)| (a - s * b).abs() <= 1e-3 * b.abs().max(1.0)));
        }
        let shown: Vec<&[f32]> = shown.iter().map(Vec::as_slice).collect();
        assert_eq!(
            g,
            &inference.denoise_window(&shown, EXPOSURE).unwrap(),
            "frame {t}"
        );
    }
    // A lone frame is shown in every slot.
    let lone = net(&p, &m).run(&raws[0], EXPOSURE).unwrap();
    let window = vec![pre[0].as_slice(); 2 * MOVIE_WINDOW + 1];
    assert_eq!(lone, inference.denoise_window(&window, EXPOSURE).unwrap());
    // The network is a temporal one: it denoises no frame alone, and a window must be its own.
    assert!(inference.denoise_preprocessed(&pre[0], EXPOSURE).is_err());
    assert!(inference.denoise_window(&window[..3], EXPOSURE).is_err());
}

#[test]
fn the_window_is_the_networks_and_a_temporal_model_runs_its_method() {
    let load = |n: &str| emccd_denoise::bundled::load(n, &emccd_nn::cpu());
    let r = resolve(Some(Method::TemporalNet), None, load).unwrap();
    assert_eq!(r.model_name.as_deref(), Some("movie"));
    assert_eq!(r.window(None).unwrap(), MOVIE_WINDOW);
    assert_eq!(r.window(Some(MOVIE_WINDOW)).unwrap(), MOVIE_WINDOW);
    for w in [0, 1, 4] {
        let e = r.window(Some(w)).unwrap_err().to_string();
        assert!(e.contains("temporal-net") && e.contains("2 frames"), "{e}");
    }
    assert_eq!(
        resolve(None, Some("movie"), load).unwrap().method,
        Method::TemporalNet
    );
    for (method, model) in [
        (Method::Net, "movie"),
        (Method::Blend, "movie"),
        (Method::TemporalNet, "lowlight"),
    ] {
        let e = resolve(Some(method), Some(model), load)
            .err()
            .expect("a model of another kind is refused")
            .to_string();
        assert!(e.contains(&format!("--model {model}")), "{e}");
    }
}

/// A spot in one frame only (a blink, a transient) on a scene of about 2 photoelectrons per
/// pixel: the frame keeps at least 80 % of the spot's photo-signal and each neighbour takes
/// less than 10 %. Measured as the difference between the movie with the spot and the same
/// movie (the same noise seeds) without it, so the scene's own error drops out.
#[test]
fn a_spot_in_one_frame_stays_in_that_frame() {
    let (p, m) = (profile(), model());
    let fd = net(&p, &m);
    let background = scene(4.0);
    // 500 photons in a Gaussian spot of σ = 1.5 px at (20, 44), in frame 2 of 5.
    let spot: Vec<f32> = (0..W * H)
        .map(|i| {
            let (x, y) = ((i % W) as f32, (i / W) as f32);
            let r2 = (x - 20.0).powi(2) + (y - 44.0).powi(2);
            500.0 / (2.0 * std::f32::consts::PI * 2.25) * (-r2 / 4.5).exp()
        })
        .collect();
    let with: Vec<Vec<f32>> = (0..5)
        .map(|k| {
            if k == 2 {
                background.iter().zip(&spot).map(|(b, s)| b + s).collect()
            } else {
                background.clone()
            }
        })
        .collect();
    let (a, b) = (
        every_frame(&fd, &shoot(&p, &with, 900)),
        every_frame(&fd, &shoot(&p, &vec![background.clone(); 5], 900)),
    );
    let in_box = |t: usize| -> f64 {
        let mut s = 0.0;
        for y in 38..51 {
            for x in 14..27 {
                s += (a[t][y * W + x] - b[t][y * W + x]) as f64;
            }
        }
        s
    };
    let total = dn_per_photon(&p) * spot.iter().map(|&v| v as f64).sum::<f64>();
    let kept = in_box(2) / total;
    let leaked = [in_box(1) / total, in_box(3) / total];
    println!("kept {kept:.3}, leaked {leaked:.3?}");
    assert!(kept >= 0.8, "the spot's frame keeps {kept:.3} of it");
    for l in leaked {
        assert!(l.abs() < 0.1, "a neighbour takes {l:.3} of it");
    }
}

/// How far the mean of every frame's estimate of a uniform scene at `electrons` per pixel is
/// from the data's, as a fraction of the signal, over `movies` movies of 5 frames: measured
/// against the preprocessed frames' mean, so the data's own noise drops out and what remains is
/// the network's bias (and the little noise of its response to each movie's noise).
fn mean_off(electrons: f32, movies: u64) -> f64 {
    let (p, m) = (profile(), model());
    let fd = net(&p, &m);
    let qe = PhysicalParams::default().qe as f32;
    let photons = vec![vec![electrons / qe; W * H]; 5];
    let signal = dn_per_photon(&p) * (electrons / qe) as f64;
    let mut off = 0.0;
    for movie in 0..movies {
        let raws = shoot(&p, &photons, 1000 + 10 * movie);
        let data: f64 = raws
            .iter()
            .map(|r| mean(&preprocess(&p, r, EXPOSURE).unwrap()))
            .sum::<f64>()
            / 5.0;
        let est: f64 = every_frame(&fd, &raws).iter().map(|f| mean(f)).sum::<f64>() / 5.0;
        off += (est - data) / signal / movies as f64;
    }
    println!("{electrons} e⁻: mean off by {:.2} %", 100.0 * off);
    off
}

/// A uniform scene at 2 and 8 photoelectrons per pixel: the mean of every frame's estimate is
/// the data's within 1 % of the signal, over eight movies (measured −0.19 and −0.12 %).
#[test]
fn the_mean_of_a_uniform_region_stays() {
    for electrons in [2.0, 8.0] {
        let off = mean_off(electrons, 8);
        assert!(
            off.abs() < 0.01,
            "{electrons} e⁻: mean off by {:.2} %",
            100.0 * off
        );
    }
}

/// The same at half an electron per pixel, over twelve movies (measured −0.40 %; −1.04 % for
/// the network trained with the Charbonnier loss alone, which estimates nearer the median of a
/// pixel's skewed posterior than its mean: models/README.md).
#[test]
fn the_mean_of_a_uniform_region_stays_at_half_an_electron() {
    let off = mean_off(0.5, 12);
    assert!(off.abs() < 0.01, "0.5 e⁻: mean off by {:.2} %", 100.0 * off);
}

/// A scene bleaching by 4 % per frame at about 2 photoelectrons per pixel: each frame's
/// estimate keeps its own frame's mean as on the still scene (the same noise seeds), the ends
/// too, within 1 % (shown unscaled, the first frame's mirrored neighbours are all dimmer and
/// it came out 1.8 % darker than the still scene's; measured now: within 0.5 %).
#[test]
fn a_bleaching_scene_keeps_each_frames_mean() {
    let (p, m) = (profile(), model());
    let fd = net(&p, &m);
    let off = |rate: f32| -> Vec<f64> {
        let mut off = vec![0.0; 5];
        for movie in 0..4u64 {
            let photons: Vec<Vec<f32>> = (0..5)
                .map(|t| {
                    scene(8.0)
                        .iter()
                        .map(|v| v * (-rate * t as f32).exp())
                        .collect()
                })
                .collect();
            let est = every_frame(&fd, &shoot(&p, &photons, 2000 + 10 * movie));
            for (t, o) in off.iter_mut().enumerate() {
                let want = dn_per_photon(&p) * photons[t].iter().map(|&v| v as f64).sum::<f64>()
                    / (W * H) as f64;
                *o += (mean(&est[t]) / want - 1.0) / 4.0;
            }
        }
        off
    };
    let (still, bleaching) = (off(0.0), off(0.04));
    for t in 0..5 {
        println!(
            "frame {t}: {:.2} % bleaching, {:.2} % still",
            100.0 * bleaching[t],
            100.0 * still[t]
        );
        assert!(
            (bleaching[t] - still[t]).abs() < 0.01,
            "frame {t}: {:.2} % bleaching, {:.2} % still",
            100.0 * bleaching[t],
            100.0 * still[t]
        );
    }
}

/// Frames 0–5 with a cut between frames 2 and 3 to the scene turned by 90°: frame 2's estimate
/// from the whole movie is what frames 0–2 alone give it (within 0.2 dB), and frame 3's what
/// frames 3–5 give it: nothing of the other scene crosses the cut. The tracking does not see
/// this cut (the turned bars' 8×8 blocks are all found again within their search: the
/// classical method's mean is unharmed by them, a network shown the whole frames is not; it
/// lost 3.3 dB here), the correlation of the whole frames does.
#[test]
fn nothing_crosses_a_scene_cut() {
    let (p, m) = (profile(), model());
    let fd = net(&p, &m);
    let a = scene(4.0);
    let b: Vec<f32> = (0..W * H).map(|i| a[(i % W) * W + i / W]).collect();
    let photons: Vec<Vec<f32>> = (0..6)
        .map(|t| if t < 3 { a.clone() } else { b.clone() })
        .collect();
    let raws = shoot(&p, &photons, 3000);
    let cam = VirtualCamera::new(p.clone(), PhysicalParams::default()).unwrap();
    let exposure = cam.exposure(EXPOSURE);
    let truth = |s: &[f32]| exposure.ground_truth(s);
    let whole = every_frame(&fd, &raws);
    let (first, second) = (every_frame(&fd, &raws[..3]), every_frame(&fd, &raws[3..]));
    for (name, across, within, t) in [
        ("frame 2", &whole[2], &first[2], truth(&a)),
        ("frame 3", &whole[3], &second[0], truth(&b)),
    ] {
        let peak = t.iter().copied().fold(0.0f32, f32::max) as f64;
        let (x, w) = (
            emccd_eval::psnr(across, &t, peak),
            emccd_eval::psnr(within, &t, peak),
        );
        println!("{name}: {w:.2} dB from its own scene, {x:.2} dB across the cut");
        assert!(x > w - 0.2, "{name}: {w:.2} → {x:.2} dB");
    }
}
