//! The characterization against cameras of known truth: frames drawn from the
//! Poisson–Gamma–Normal chain (photoelectrons, an exponential per electron out of the register,
//! Gaussian read noise, a bias, whole DN, a 16-bit ceiling) over fluorescence-like scenes.

use super::*;
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Gamma, Normal, Poisson};

/// A camera: DN per electron out of the register, read noise, bias (DN).
#[derive(Clone, Copy)]
struct Camera {
    k: f64,
    sigma: f64,
    bias: f64,
}

/// The camera: 75 DN per photoelectron, bias 500 DN, read noise 11 DN.
const USER: Camera = Camera {
    k: 75.0,
    sigma: 11.0,
    bias: 500.0,
};
/// A low-gain, low-noise one: 15 DN per electron, 5 DN read noise, bias 100 DN.
const LOW: Camera = Camera {
    k: 15.0,
    sigma: 5.0,
    bias: 100.0,
};

/// Cells on a dark background: blobs of 3–8 px over 3 % of the brightest level, scaled to a
/// mean of `mean` electrons per pixel; `(dx, dy)` shifts it (px) for moving scenes.
fn scene(w: usize, h: usize, mean: f64, shift: (f64, f64), seed: u64) -> Vec<f64> {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let blobs: Vec<(f64, f64, f64, f64)> = (0..(w * h / 600).max(4))
        .map(|_| {
            (
                rng.random::<f64>() * w as f64,
                rng.random::<f64>() * h as f64,
                rng.random_range(3.0..8.0),
                rng.random_range(0.3..1.0),
            )
        })
        .collect();
    let mut s: Vec<f64> = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f64 - shift.0, (i / w) as f64 - shift.1);
            0.03 + blobs
                .iter()
                .map(|&(bx, by, r, a)| {
                    a * (-((x - bx).powi(2) + (y - by).powi(2)) / (2.0 * r * r)).exp()
                })
                .sum::<f64>()
        })
        .collect();
    let m = s.iter().sum::<f64>() / s.len() as f64;
    s.iter_mut().for_each(|v| *v *= mean / m);
    s
}

/// One frame of `scene` (electrons) through `cam`.
fn frame(cam: Camera, scene: &[f64], rng: &mut rand_pcg::Pcg64) -> Vec<f32> {
    let noise = Normal::new(0.0, cam.sigma).unwrap();
    scene
        .iter()
        .map(|&l| {
            let n = if l > 0.0 {
                Poisson::new(l).unwrap().sample(rng) as u32
            } else {
                0
            };
            let em = if n > 0 {
                Gamma::new(n as f64, cam.k).unwrap().sample(rng)
            } else {
                0.0
            };
            (cam.bias + em + noise.sample(rng))
                .round()
                .clamp(0.0, 65535.0) as f32
        })
        .collect()
}

/// A movie of `frames` frames; `drift` px a frame to the right.
fn movie(
    cam: Camera,
    w: usize,
    h: usize,
    mean: f64,
    frames: usize,
    drift: f64,
    seed: u64,
) -> Vec<Vec<f32>> {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed + 1000);
    (0..frames)
        .map(|t| {
            frame(
                cam,
                &scene(w, h, mean, (drift * t as f64, 0.0), seed),
                &mut rng,
            )
        })
        .collect()
}

/// The targets of issue 67: the slope (2K, this camera's f² being 2) within 5 %, the bias
/// within 1 DN, the read noise within 5 %.
fn check(c: &Characterization, cam: Camera, what: &str) {
    let s = 2.0 * cam.k;
    assert!(
        (c.slope_dn.value / s - 1.0).abs() < 0.05,
        "{what}: slope {} ± {} vs {s}",
        c.slope_dn.value,
        c.slope_dn.se
    );
    assert!(
        (c.bias_dn.value - cam.bias).abs() < 1.0,
        "{what}: bias {} ± {}",
        c.bias_dn.value,
        c.bias_dn.se
    );
    // Where the darkest pixels hold a few electrons a frame (16 e⁻ on average) the core of
    // read noise is small and the fit says so in its error: the truth within four of them.
    let tol = (0.05 * cam.sigma).max(4.0 * c.read_noise_dn.se);
    assert!(
        (c.read_noise_dn.value - cam.sigma).abs() < tol,
        "{what}: read noise {} ± {}",
        c.read_noise_dn.value,
        c.read_noise_dn.se
    );
}

#[test]
fn a_still_movie_gives_its_camera_at_every_level() {
    for (i, &mean) in [0.5, 1.0, 4.0, 16.0].iter().enumerate() {
        for (j, cam) in [USER, LOW].into_iter().enumerate() {
            let frames = movie(cam, 128, 128, mean, 20, 0.0, (10 * i + j) as u64);
            let c = characterize(&frames, 128, 128).unwrap();
            check(&c, cam, &format!("{mean} e⁻, camera {j}"));
            assert_eq!(c.slope_from, SlopeFrom::TemporalPtc);
            assert!(
                (c.mean_electrons / mean - 1.0).abs() < 0.05,
                "{mean}: {}",
                c.mean_electrons
            );
            // The temporal line's error is honest: the truth within four of them.
            assert!(
                (c.slope_dn.value - 2.0 * cam.k).abs() < 4.0 * c.slope_dn.se,
                "{mean} e⁻: {} ± {}",
                c.slope_dn.value,
                c.slope_dn.se
            );
        }
    }
}

#[test]
fn a_drifting_movie_gives_its_camera() {
    for (i, &mean) in [1.0, 4.0].iter().enumerate() {
        let frames = movie(USER, 128, 128, mean, 20, 1.3, 40 + i as u64);
        let c = characterize(&frames, 128, 128).unwrap();
        check(&c, USER, &format!("drift at {mean} e⁻"));
    }
}

#[test]
fn one_frame_gives_its_camera_at_low_light() {
    // At 4 e⁻ the darkest pixels hold about half an electron and their rates differ: the read
    // noise comes out about 9 % high there (docs/calibration.md), so the targets are held at
    // 0.5 and 1 e⁻.
    for (i, &mean) in [0.5, 1.0].iter().enumerate() {
        let frames = movie(USER, 256, 256, mean, 1, 0.0, 60 + i as u64);
        let c = characterize(&frames, 256, 256).unwrap();
        assert_eq!(c.slope_from, SlopeFrom::EmTail);
        check(&c, USER, &format!("one frame at {mean} e⁻"));
    }
}

#[test]
fn what_cannot_be_estimated_is_said() {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
    // Bright everywhere: no zero-electron pixel.
    let bright: Vec<Vec<f32>> = (0..8)
        .map(|_| frame(USER, &vec![25.0; 64 * 64], &mut rng))
        .collect();
    let e = characterize(&bright, 64, 64).unwrap_err().to_string();
    assert!(e.contains("no zero-electron peak"), "{e}");
    // Bias frames: no electrons anywhere; their bias and read noise are said.
    let dark: Vec<Vec<f32>> = (0..8)
        .map(|_| frame(USER, &vec![0.0; 64 * 64], &mut rng))
        .collect();
    let e = characterize(&dark, 64, 64).unwrap_err().to_string();
    assert!(
        e.contains("no measurable light") && e.contains("bias 500."),
        "{e}"
    );
    // Saturated.
    let sat = vec![vec![65535.0f32; 64 * 64]; 4];
    let e = characterize(&sat, 64, 64).unwrap_err().to_string();
    assert!(e.contains("saturated"), "{e}");
    // One frame of 8×8.
    let e = characterize(&[vec![500.0; 64]], 8, 8)
        .unwrap_err()
        .to_string();
    assert!(e.contains("too little"), "{e}");
    // A photograph: smooth, noiseless, 8-bit.
    let photo: Vec<f32> = (0..128 * 128)
        .map(|i| {
            (((i % 128) as f64 * 0.05).sin() * 60.0 + 120.0 + (i / 128) as f64 * 0.3).round() as f32
        })
        .collect();
    let e = characterize(&[photo], 128, 128).unwrap_err().to_string();
    assert!(!e.is_empty());
    // A synthetic sawtooth (whole steps of 30 DN): its fits once wandered to a register scale
    // far beyond the data and took minutes; now refused like any other non-EMCCD frame.
    let saw: Vec<f32> = (0..512 * 512)
        .map(|i| 500.0 + (i % 13) as f32 * 30.0)
        .collect();
    assert!(characterize(&[saw], 512, 512).is_err());
}

#[test]
fn the_profile_says_where_it_came_from() {
    let frames = movie(USER, 64, 64, 1.0, 16, 0.0, 80);
    let c = characterize(&frames, 64, 64).unwrap();
    let p = c.profile("rec.tif", 0.01, Some(300.0), 65535.0).unwrap();
    assert_eq!(p.provenance.source, RECORDING_SOURCE);
    assert_eq!(
        p.bias_dn(),
        emccd_profile::median(c.bias_map.values.iter().copied()).unwrap()
    );
    assert_eq!(p.ptc_slope_dn, Some(c.slope_dn.value));
    assert!(p.summary_text().contains("characterized from"));
}

/// A recording on disk to a profile folder and its report, as `calibrate --from-recording`
/// writes them: the profile loads back, says where it came from, and takes the recording's own
/// exposure where its header records none.
#[test]
fn a_file_becomes_a_profile_and_a_report() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rec.tif");
    let frames = movie(LOW, 64, 64, 1.0, 12, 0.0, 90);
    let mut w = emccd_io::StackWriter::create(&path, 64, 64, emccd_io::SampleFormat::U16, Some(12))
        .unwrap();
    for f in &frames {
        w.write_frame(f).unwrap();
    }
    w.finish().unwrap();
    let read = read(&[path.as_path()]).unwrap();
    assert_eq!(read.frames.len(), 12);
    assert_eq!(read.adc_max_dn, 65535.0);
    let c = read.characterize().unwrap();
    check(&c, LOW, "from a file");
    let p = read.profile(&c).unwrap();
    let (out, rep) = (dir.path().join("prof"), dir.path().join("rep"));
    c.save(&p, &read.source, &out, Some(&rep), false).unwrap();
    let back = CameraProfile::load(&out).unwrap();
    assert!(back.from_recording());
    assert_eq!(back.ptc_slope_dn, p.ptc_slope_dn);
    let html = std::fs::read_to_string(rep.join("index.html")).unwrap();
    assert!(
        html.contains("zero-electron peak") && html.contains("<svg"),
        "report"
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(rep.join("results.json")).unwrap()).unwrap();
    assert!((json["slope_dn"]["value"].as_f64().unwrap() - c.slope_dn.value).abs() < 1e-9);
    // Opened through its own profile, the header's missing exposure is the profile's.
    let r = emccd_profile::Recording::open(&path, &back, None, "--exposure-s", false).unwrap();
    assert_eq!(r.exposure, NOMINAL_EXPOSURE_S);
}

/// `cam`'s own profile, `w × h`: its bias, read noise and slope (2K) as the truth has them, the
/// rest as a characterization makes it.
fn truth_profile(cam: Camera, c: &Characterization) -> CameraProfile {
    let mut p = c.profile("truth", 0.01, Some(300.0), 65535.0).unwrap();
    p.maps.fpn_base.fill(cam.bias as f32);
    p.maps.read_noise[0].fill(cam.sigma as f32);
    p.ptc_slope_dn = Some(2.0 * cam.k);
    p
}

#[test]
fn a_profile_that_does_not_fit_is_named_and_the_right_one_never() {
    let (w, h) = (128, 128);
    for (what, frames) in [
        ("a movie", movie(USER, w, h, 1.0, 20, 0.0, 90)),
        ("one frame", movie(USER, 2 * w, 2 * h, 1.0, 1, 0.0, 91)),
    ] {
        let (w, h) = if frames.len() == 1 {
            (2 * w, 2 * h)
        } else {
            (w, h)
        };
        let c = characterize(&frames, w, h).unwrap();
        let right = truth_profile(USER, &c);
        let off = |p: &CameraProfile| disagreements(&c, p, 0.01, Some(300.0));
        assert!(off(&right).is_empty(), "{what}: {:?}", off(&right));
        // Another camera's bias: 10 read-noise σ away (the mark).
        let mut p = right.clone();
        p.maps.fpn_base.fill((USER.bias + 10.0 * USER.sigma) as f32);
        let d = off(&p);
        assert!(d.len() == 1 && d[0].starts_with("bias"), "{what}: {d:?}");
        // Another gain: 30 % off either way is caught in a movie; one frame leaves the excess
        // noise factor (30 % besides 3 errors of its gain, check.rs) unknown, so only a gain
        // twice or half the profile's (EM gain 300 against 150) is caught there.
        let factor = if frames.len() > 1 { 1.3 } else { 2.0 };
        for f in [factor, 1.0 / factor] {
            let mut p = right.clone();
            p.ptc_slope_dn = Some(2.0 * USER.k * f);
            let d = off(&p);
            assert!(
                d.len() == 1 && d[0].starts_with("gain"),
                "{what} ×{f}: {d:?}"
            );
        }
        // A noisier readout's profile: the recording's read noise below the profile's.
        let mut p = right.clone();
        p.maps.read_noise[0].fill((1.5 * USER.sigma) as f32);
        let d = off(&p);
        assert!(
            d.len() == 1 && d[0].starts_with("read noise"),
            "{what}: {d:?}"
        );
        // The header's EM gain against the profile's.
        let d = disagreements(&c, &right, 0.01, Some(1000.0));
        assert!(
            d.len() == 1 && d[0].contains("EM gain 1000"),
            "{what}: {d:?}"
        );
    }
}

#[test]
fn a_bias_that_drifts_across_the_frame_is_followed() {
    // 20 DN from the first row to the last (a gradient like the bundled profile's, 35 DN over
    // 512 rows), on a movie and on one frame.
    let drift = 20.0;
    for (frames, side, seed) in [(20, 128, 100), (1, 256, 101)] {
        let mut m = movie(USER, side, side, 1.0, frames, 0.0, seed);
        for f in &mut m {
            for (i, v) in f.iter_mut().enumerate() {
                *v += (drift * (i / side) as f64 / (side - 1) as f64).round() as f32;
            }
        }
        let c = characterize(&m, side, side).unwrap();
        let map = &c.bias_map;
        assert!(map.fitted > 1, "{frames} frames: {map:?}");
        // Each row's bias within 1 DN (the target), a tile's peak being known to about
        // a tenth of the read noise and the gradient being linear.
        for y in (0..side).step_by(side / 16) {
            let want = USER.bias + drift * y as f64 / (side - 1) as f64;
            let got = map.values[y * side + side / 2] as f64;
            assert!(
                (got - want).abs() < 1.0,
                "{frames} frames, row {y}: {got} vs {want}"
            );
        }
        assert!(
            c.notes
                .iter()
                .any(|n| n.contains("drifts across the frame")),
            "{:?}",
            c.notes
        );
    }
}

#[test]
fn a_bias_drift_does_not_flatten_the_mean_variance_line() {
    // 20 DN from the first row to the last under a scene whose light spans about as much (15 DN
    // per electron at 1 e⁻): levels taken in raw DN spread with the drift and not with the
    // variance, and the line came out at 0.56 of its slope on this camera.
    let (side, drift) = (128, 20.0);
    let mut m = movie(LOW, side, side, 1.0, 20, 0.0, 120);
    for f in &mut m {
        for (i, v) in f.iter_mut().enumerate() {
            *v += (drift * (i / side) as f64 / (side - 1) as f64).round() as f32;
        }
    }
    let c = characterize(&m, side, side).unwrap();
    assert_eq!(c.slope_from, SlopeFrom::TemporalPtc, "{:?}", c.notes);
    let s = 2.0 * LOW.k;
    assert!(
        (c.slope_dn.value - s).abs() < (0.05 * s).max(4.0 * c.slope_dn.se),
        "slope {} ± {} vs {s}",
        c.slope_dn.value,
        c.slope_dn.se
    );
}

#[test]
fn a_movie_maps_each_dark_pixels_own_bias() {
    // A pixel-to-pixel pattern of 4 DN beside 11 DN of read noise, on a still movie of 32 frames.
    let (side, frames, tau) = (128, 32, 4.0);
    let mut rng = rand_pcg::Pcg64::seed_from_u64(110);
    let pattern: Vec<f64> = (0..side * side)
        .map(|_| Normal::new(0.0, tau).unwrap().sample(&mut rng))
        .collect();
    let light = scene(side, side, 1.0, (0.0, 0.0), 111);
    let mut m = movie(USER, side, side, 1.0, frames, 0.0, 111);
    for f in &mut m {
        for (v, p) in f.iter_mut().zip(&pattern) {
            *v += p.round() as f32;
        }
    }
    let c = characterize(&m, side, side).unwrap();
    let pattern_dn = c.pattern_dn.unwrap();
    assert!((pattern_dn / tau - 1.0).abs() < 0.2, "pattern {pattern_dn}");
    // The background's pixels (its fifth with the least light, a few tenths of an electron a
    // frame) spend most frames at zero electrons: their own peak is known to about
    // σ/√(zero frames) ≈ 2.5 DN and kept by τ²/(τ² + se²) ≈ 0.7, which leaves about
    // se·τ/√(τ² + se²) ≈ 2.1 DN of the pattern, about half its 4 DN.
    let mut order: Vec<usize> = (0..side * side).collect();
    order.sort_by(|&a, &b| light[a].total_cmp(&light[b]));
    let dark = &order[..side * side / 5];
    eprintln!("background {:.2} e⁻ a frame", light[dark[dark.len() - 1]]);
    let rms = |f: &dyn Fn(usize) -> f64| {
        (dark.iter().map(|&i| f(i).powi(2)).sum::<f64>() / dark.len() as f64).sqrt()
    };
    let left = rms(&|i| c.bias_map.values[i] as f64 - (USER.bias + pattern[i].round()));
    assert!(left < 0.6 * tau, "pattern left {left} of {tau}");
}

#[test]
fn a_strip_frame_keeps_a_flat_bias_flat() {
    // 512 × 40 px (one row of tiles): no y terms to swing the map at its top and bottom rows.
    // Each row's mean (the surface; single pixels carry their own peaks' noise, shrunk) within
    // half a DN, a few of the surface's errors.
    let (w, h) = (512, 40);
    let m = movie(USER, w, h, 1.0, 20, 0.0, 120);
    let c = characterize(&m, w, h).unwrap();
    for y in 0..h {
        let row = &c.bias_map.values[y * w..(y + 1) * w];
        let mean = row.iter().map(|&v| v as f64).sum::<f64>() / w as f64;
        assert!((mean - USER.bias).abs() < 0.5, "row {y}: {mean}");
    }
}

/// Point sources (1–2 px, brightness heavy-tailed) on a dark sky, drifting `drift` px a frame
/// to the right, with frame-transfer smear `x` (each pixel gains `x` times its column's mean
/// light): photoelectrons per pixel, frame by frame.
fn smeared_stars(
    w: usize,
    h: usize,
    frames: usize,
    drift: f64,
    x: f64,
    seed: u64,
) -> Vec<Vec<f64>> {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let stars: Vec<(f64, f64, f64, f64)> = (0..w * h / 300)
        .map(|_| {
            (
                rng.random::<f64>() * w as f64,
                rng.random::<f64>() * h as f64,
                rng.random_range(1.0..2.0),
                // Pareto-like brightness: a few bright stars among many faint ones.
                20.0 / rng.random_range(0.1f64..1.0).powf(1.2),
            )
        })
        .collect();
    (0..frames)
        .map(|t| {
            let mut s: Vec<f64> = (0..w * h)
                .map(|i| {
                    let (px, py) = ((i % w) as f64 - drift * t as f64, (i / w) as f64);
                    0.02 + stars
                        .iter()
                        .map(|&(sx, sy, r, a)| {
                            let dx = (px - sx).rem_euclid(w as f64);
                            let (dx, dy) = (dx.min(w as f64 - dx), py - sy);
                            if dx.abs() > 8.0 || dy.abs() > 8.0 {
                                return 0.0;
                            }
                            a * (-(dx * dx + dy * dy) / (2.0 * r * r)).exp()
                        })
                        .sum::<f64>()
                })
                .collect();
            let cols: Vec<f64> = (0..w)
                .map(|c| (0..h).map(|y| s[y * w + c]).sum::<f64>() / h as f64)
                .collect();
            for (i, v) in s.iter_mut().enumerate() {
                *v += x * cols[i % w];
            }
            s
        })
        .collect()
}

#[test]
fn smear_is_measured_where_the_scene_shows_it_and_never_made_up() {
    let (w, h) = (256, 256);
    let mut rng = rand_pcg::Pcg64::seed_from_u64(77);
    let shoot = |scenes: &[Vec<f64>], rng: &mut rand_pcg::Pcg64| -> Vec<Vec<f32>> {
        scenes.iter().map(|s| frame(USER, s, rng)).collect()
    };
    // Drifting stars with 5 % smear: the factor within four of its errors, and those errors
    // small enough to remove it by.
    let frames = shoot(&smeared_stars(w, h, 20, 1.0, 0.05, 3), &mut rng);
    let c = characterize(&frames, w, h).unwrap();
    let sm = c.smear.expect("a 256² movie is searched for smear");
    assert!(sm.significant, "{sm:?}");
    assert!(
        (sm.factor.value - 0.05).abs() < 4.0 * sm.factor.se && sm.factor.se < 0.01,
        "{sm:?}"
    );
    // The profile removes it as blooming at the recording's exposure, the bias map un-bloomed.
    let p = c.profile("stars", 0.01, None, 65535.0).unwrap();
    assert!((p.blooming_factor(0.01) - sm.factor.value).abs() < 1e-12);
    let unbloomed = p.maps.fpn_base.iter().map(|&v| v as f64).sum::<f64>() / (w * h) as f64;
    let map = c.bias_map.values.iter().map(|&v| v as f64).sum::<f64>() / (w * h) as f64;
    assert!((unbloomed - map / (1.0 + sm.factor.value)).abs() < 1e-3 * map);
    // A calibrated profile of the camera without a blooming calibration takes it from the
    // recording: the output's mean is the light's, where it held the smear's 5 % more.
    let scenes = smeared_stars(w, h, 20, 1.0, 0.0, 3);
    let light = scenes.iter().flatten().sum::<f64>() / (20 * w * h) as f64;
    let mut calibrated = truth_profile(USER, &c);
    calibrated.blooming = None;
    calibrated.maps.fpn_base.fill(USER.bias as f32);
    let output_mean = |p: &CameraProfile| -> f64 {
        let mut fpn = vec![0f32; w * h];
        p.fpn_at(0.01, &mut fpn);
        let per_e = p.dn_per_electron().unwrap();
        frames
            .iter()
            .map(|f| {
                let mut d = f.clone();
                emccd_profile::preprocess(&mut d, w, p.blooming_factor(0.01), &fpn);
                d.iter().map(|&v| v as f64).sum::<f64>() / per_e
            })
            .sum::<f64>()
            / (20 * w * h) as f64
    };
    let kept = output_mean(&calibrated) / light;
    assert!((kept - 1.05).abs() < 0.01, "with the smear kept: {kept}");
    let said = add_measured_smear(&mut calibrated, &c, 0.01).expect("smear added");
    assert!(said.contains("smear"), "{said}");
    let removed = output_mean(&calibrated) / light;
    assert!(
        (removed - 1.0).abs() < 0.01 + 3.0 * sm.factor.se,
        "with the smear removed: {removed}"
    );
    // A profile that has its own blooming calibration keeps it.
    assert!(add_measured_smear(&mut calibrated, &c, 0.01).is_none());

    // The same stars without smear, drifting or still, and cells: none claimed.
    for (what, scenes) in [
        ("drifting stars", smeared_stars(w, h, 20, 1.0, 0.0, 3)),
        ("still stars", smeared_stars(w, h, 20, 0.0, 0.0, 4)),
        (
            "drifting cells",
            (0..20)
                .map(|t| scene(w, h, 2.0, (t as f64, 0.0), 5))
                .collect(),
        ),
    ] {
        let frames = shoot(&scenes, &mut rng);
        let c = characterize(&frames, w, h).unwrap();
        // Point sources drifting through the mean–variance blocks do not take the slope
        // (2K, this camera's f² being 2) off by more than the targets' 5 %.
        assert!(
            (c.slope_dn.value / (2.0 * USER.k) - 1.0).abs() < 0.05,
            "{what}: slope {} ± {} ({:?})",
            c.slope_dn.value,
            c.slope_dn.se,
            c.slope_from
        );
        let sm = c.smear;
        assert!(sm.is_some_and(|s| !s.significant), "{what}: {sm:?}");
        let p = c.profile(what, 0.01, None, 65535.0).unwrap();
        assert!(p.blooming.is_none(), "{what}");
    }
}

/// The movie suite's particles: 40 spots (σ 1.2 px) diffusing 1 px a frame on a background of
/// 0.03 of their peak, each blinking (on → off with p 0.15, off → on with p 0.3 a frame), scaled
/// to a mean of `mean` electrons per pixel over the movie.
fn particles(w: usize, h: usize, mean: f64, frames: usize, seed: u64) -> Vec<Vec<f64>> {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let step = Normal::new(0.0, 1.0).unwrap();
    let mut spots: Vec<(f64, f64, f64, bool)> = (0..40)
        .map(|_| {
            (
                rng.random_range(8.0..w as f64 - 8.0),
                rng.random_range(8.0..h as f64 - 8.0),
                rng.random_range(0.5..1.0),
                rng.random::<f64>() < 0.7,
            )
        })
        .collect();
    let mut out: Vec<Vec<f64>> = (0..frames)
        .map(|_| {
            for s in spots.iter_mut() {
                s.0 = (s.0 + step.sample(&mut rng)).clamp(4.0, w as f64 - 5.0);
                s.1 = (s.1 + step.sample(&mut rng)).clamp(4.0, h as f64 - 5.0);
                s.3 = if s.3 {
                    rng.random::<f64>() > 0.15
                } else {
                    rng.random::<f64>() < 0.3
                };
            }
            (0..w * h)
                .map(|i| {
                    let (x, y) = ((i % w) as f64, (i / w) as f64);
                    0.03 + spots
                        .iter()
                        .filter(|s| s.3)
                        .map(|&(sx, sy, a, _)| {
                            a * (-((x - sx).powi(2) + (y - sy).powi(2)) / (2.0 * 1.44)).exp()
                        })
                        .sum::<f64>()
                })
                .collect()
        })
        .collect();
    let m = out.iter().flatten().sum::<f64>() / (frames * w * h) as f64;
    out.iter_mut().flatten().for_each(|v| *v *= mean / m);
    out
}

#[test]
fn blinking_particles_and_bright_drifts_do_not_take_the_slope() {
    // Blinking particles raise the frame differences beyond their shot noise where the motion
    // test does not see them (the line of emccd-detect camera A's particles at 4 e⁻ was 5× its
    // slope, f² ≈ 10); cells drifting at 16 e⁻ hold their darkest pixels near an electron a
    // frame, where the tail's K runs high.
    let (w, h) = (256, 256);
    let mut rng = rand_pcg::Pcg64::seed_from_u64(91);
    for (what, scenes) in [
        ("particles at 1 e⁻", particles(w, h, 1.0, 16, 5)),
        ("particles at 4 e⁻", particles(w, h, 4.0, 16, 6)),
        (
            "cells drifting at 16 e⁻",
            (0..16)
                .map(|t| scene(w, h, 16.0, (t as f64, 0.5 * t as f64), 7))
                .collect(),
        ),
    ] {
        let frames: Vec<Vec<f32>> = scenes.iter().map(|s| frame(USER, s, &mut rng)).collect();
        let c = characterize(&frames, w, h).unwrap();
        // Under the flat background at 4 e⁻ the darkest pixels hold about three electrons a
        // frame and neither the line nor the tail is good to 5 %: there the truth within three
        // of the errors given, and those errors under 10 %.
        let err = (c.slope_dn.value / (2.0 * USER.k) - 1.0).abs();
        let tol = if what == "particles at 4 e⁻" {
            assert!(
                c.slope_dn.se < 0.1 * c.slope_dn.value,
                "{what}: {:?}",
                c.slope_dn
            );
            3.0 * c.slope_dn.se / c.slope_dn.value
        } else {
            0.05
        };
        assert!(
            err < tol,
            "{what}: slope {} ± {} ({:?})",
            c.slope_dn.value,
            c.slope_dn.se,
            c.slope_from
        );
    }
}
