//! `emccd count` end to end on the virtual camera: the counted rate is the truth's at three
//! light levels, beats the analog mean where light is faint, streams the same as one pass, and
//! bad requests are refused before anything is written.

mod common;

use std::path::Path;

use common::{emccd, ok};

/// A uniform scene (`value` everywhere, 0–1) as a float TIFF.
fn flat_scene(path: &Path, n: usize) {
    let mut w =
        emccd_io::StackWriter::create(path, n, n, emccd_io::SampleFormat::F32, Some(1)).unwrap();
    w.write_frame(&vec![0.5; n * n]).unwrap();
    w.finish().unwrap();
}

/// The bundled profile cut to `n`×`n` (`cam/`) and a uniform scene of that size (`flat.tif`).
fn camera(d: &Path, n: usize) {
    let roi = format!("{n}x{n}");
    ok(&emccd(
        &["profile", "crop", "default", "cam", "--roi", &roi],
        d,
    ));
    flat_scene(&d.join("flat.tif"), n);
}

/// `frames` frames of the uniform scene at `photons` (its brightest, so every pixel's) from the
/// virtual camera into `out/`; returns the noisy stack's path and the truth's.
fn stack(d: &Path, photons: &str, frames: usize, seed: &str, out: &str) -> (String, String) {
    ok(&emccd(
        &[
            "simulate",
            "pairs",
            "--profile",
            "cam",
            "--clean",
            "flat.tif",
            "--photons",
            photons,
            "--frames",
            &frames.to_string(),
            "--seed",
            seed,
            "-o",
            out,
        ],
        d,
    ));
    (
        format!("{out}/noisy/flat_p{photons}.tif"),
        format!("{out}/clean/flat_p{photons}.tif"),
    )
}

fn read(path: &Path) -> Vec<Vec<f32>> {
    emccd_io::read_all(path).unwrap().1
}

fn mean(v: &[f32]) -> f64 {
    v.iter().map(|&x| x as f64).sum::<f64>() / v.len() as f64
}

/// 300 frames of 64² at 0.05, 0.2 and 1 photo-electrons per pixel per frame: the counted mean
/// is the truth's within 2 % (its standard error is under 0.8 % at each level), and at 0.05 the
/// counted frame is closer to the truth than the analog mean (the model predicts a 25 % smaller
/// error there: the register's excess noise is gone).
#[test]
fn counting_recovers_the_rate_of_the_virtual_camera() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    camera(d, 64);
    // The default profile's DN per photo-electron; photons at the (uniform) brightest pixel, 90 %
    // of which become photo-electrons.
    let k_dn = 20.14 / 2.0;
    for (photons, seed) in [(0.0556, "1"), (0.2222, "2"), (1.1111, "3")] {
        let out = format!("p{photons}");
        let (noisy, truth) = stack(d, &photons.to_string(), 300, seed, &out);
        let truth = mean(&read(&d.join(truth))[0]) / k_dn;
        ok(&emccd(
            &[
                "count",
                &noisy,
                "-o",
                &format!("{out}/n.tif"),
                "--profile",
                "cam",
            ],
            d,
        ));
        ok(&emccd(
            &[
                "count",
                &noisy,
                "-o",
                &format!("{out}/a.tif"),
                "--profile",
                "cam",
                "--analog",
            ],
            d,
        ));
        let counted = read(&d.join(format!("{out}/n.tif")));
        let analog = read(&d.join(format!("{out}/a.tif")));
        let m = mean(&counted[0]);
        let rms = |f: &[f32]| {
            (f.iter().map(|&x| (x as f64 - truth).powi(2)).sum::<f64>() / f.len() as f64).sqrt()
        };
        println!(
            "truth {truth:.4}: counted {m:.4} (rms {:.4}), analog {:.4} (rms {:.4})",
            rms(&counted[0]),
            mean(&analog[0]),
            rms(&analog[0])
        );
        assert!((m / truth - 1.0).abs() < 0.02, "{truth}: {m}");
        if truth < 0.1 {
            assert!(rms(&counted[0]) < rms(&analog[0]));
        }
    }
}

/// `--per N` gives one frame per N input frames whose mean is the whole stack's, the
/// uncertainty file has the rate's shape, and the chosen threshold and predicted rates are in
/// the output's description.
#[test]
fn per_and_uncertainty_and_metadata() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    camera(d, 32);
    let (noisy, _) = stack(d, "0.3", 50, "1", "s");
    let noisy = noisy.as_str();
    ok(&emccd(
        &[
            "count",
            noisy,
            "-o",
            "all.tif",
            "--profile",
            "cam",
            "--threshold",
            "3sigma",
        ],
        d,
    ));
    ok(&emccd(
        &[
            "count",
            noisy,
            "-o",
            "per.fits",
            "--profile",
            "cam",
            "--threshold",
            "3sigma",
            "--per",
            "20",
            "--uncertainty",
            "se.fits",
        ],
        d,
    ));
    let per = read(&d.join("per.fits"));
    assert_eq!(per.len(), 3, "50 frames by 20: 20, 20 and 10");
    assert_eq!(read(&d.join("se.fits")).len(), 3);
    let all = mean(&read(&d.join("all.tif"))[0]);
    assert!(per.iter().all(|f| f.len() == 32 * 32));
    let weighted = (20.0 * mean(&per[0]) + 20.0 * mean(&per[1]) + 10.0 * mean(&per[2])) / 50.0;
    assert!(
        (weighted - all).abs() < 0.1 * all.abs().max(0.01),
        "{weighted} vs {all}"
    );
    let desc = std::fs::read(d.join("all.tif")).unwrap();
    let text = String::from_utf8_lossy(&desc);
    assert!(
        text.contains("threshold=3.00 sigma") && text.contains("false_events_per_frame="),
        "the output names its threshold"
    );
}

/// The command streams a file frame by frame; Python and `evaluate` count a stack held in
/// memory (`emccd_count::count_stack`): the same rates and errors, bit for bit.
#[test]
fn streaming_equals_in_memory() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    camera(d, 32);
    let (noisy, _) = stack(d, "0.3", 45, "4", "s");
    ok(&emccd(
        &[
            "count",
            &noisy,
            "-o",
            "r.tif",
            "--profile",
            "cam",
            "--per",
            "10",
            "--uncertainty",
            "e.tif",
        ],
        d,
    ));
    let profile = emccd_profile::CameraProfile::load(d.join("cam")).unwrap();
    let (info, frames) = emccd_io::read_all(d.join(&noisy)).unwrap();
    let req = emccd_count::Request {
        per: Some(10),
        ..Default::default()
    };
    let exposure = info.metadata.exposure_s.unwrap();
    let c = emccd_count::count_stack(&profile, &frames.concat(), exposure, &req).unwrap();
    assert_eq!(c.outputs, 5);
    assert_eq!(read(&d.join("r.tif")).concat(), c.rate);
    assert_eq!(read(&d.join("e.tif")).concat(), c.error);
}

/// An OME-Zarr output equals the TIFF one frame for frame, rates and errors; three processes
/// each counting their share (`--shard I/3`, output frames 1–2, 3–4, 5–7 of 7) make the same
/// store as one process, and a shard run again finds its share done and writes nothing. The
/// automatic threshold is the same in every shard: each measures the level on the stack's
/// first frames.
#[test]
fn zarr_output_and_shards_equal_one_process() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    camera(d, 32);
    let (noisy, _) = stack(d, "0.3", 70, "5", "s");
    let noisy = noisy.as_str();
    let count = |out: &str, se: &str, shard: Option<&str>| {
        let mut args = vec![
            "count",
            noisy,
            "-o",
            out,
            "--profile",
            "cam",
            "--per",
            "10",
            "--uncertainty",
            se,
        ];
        if let Some(s) = shard {
            args.extend(["--shard", s]);
        }
        let o = emccd(&args, d);
        ok(&o);
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    count("one.tif", "one_se.tif", None);
    count("one.zarr", "one_se.zarr", None);
    for i in 0..3 {
        count("sh.zarr", "sh_se.zarr", Some(&format!("{i}/3")));
    }
    let again = count("sh.zarr", "sh_se.zarr", Some("1/3"));
    assert!(
        again.contains("0 counted now, 2 were already done"),
        "{again}"
    );
    let tif = read(&d.join("one.tif"));
    assert_eq!(tif.len(), 7);
    for (a, b) in [
        ("one.tif", "one.zarr"),
        ("one.zarr", "sh.zarr"),
        ("one_se.tif", "one_se.zarr"),
        ("one_se.zarr", "sh_se.zarr"),
    ] {
        assert_eq!(read(&d.join(a)), read(&d.join(b)), "{a} vs {b}");
    }
    // An uncertainty store made for other work is refused, and the rate store this run had
    // just made goes with it.
    let o = emccd(
        &[
            "count",
            noisy,
            "-o",
            "fresh.zarr",
            "--profile",
            "cam",
            "--uncertainty",
            "one_se.zarr",
            "--per",
            "7",
        ],
        d,
    );
    assert!(
        !o.status.success(),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(!d.join("fresh.zarr").exists(), "the new store stays");
    // Not a store of another kind: a shard asked of a TIFF, several inputs into one store.
    let out = emccd(
        &[
            "count",
            noisy,
            "-o",
            "x.tif",
            "--profile",
            "cam",
            "--shard",
            "0/2",
        ],
        d,
    );
    assert!(!out.status.success() && !d.join("x.tif").exists());
    let out = emccd(
        &["count", noisy, noisy, "-o", "x.zarr", "--profile", "cam"],
        d,
    );
    assert!(!out.status.success() && !d.join("x.zarr").exists());
}

/// `emccd evaluate` scores counting and the analog mean on a still pair's whole noisy stack
/// (400 frames at 0.1 photons at the peak): counting is closer to the truth, and `count:100`
/// (one estimate per 100 frames, a quarter of the light) is further from it than `count`.
#[test]
fn evaluate_scores_counting_and_the_analog_mean() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    camera(d, 32);
    stack(d, "0.1", 400, "9", "p");
    let out = ok(&emccd(
        &[
            "evaluate",
            "p",
            "--method",
            "analog",
            "count",
            "count:100",
            "--json",
        ],
        d,
    ));
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let psnr = |m: &str| {
        v["summary"]
            .as_array()
            .unwrap()
            .iter()
            .find(|r| r["method"] == m && r["photons"].is_null())
            .unwrap()["psnr_db"]
            .as_f64()
            .unwrap()
    };
    let (analog, count, count100) = (psnr("analog"), psnr("count"), psnr("count:100"));
    assert!(count > analog, "count {count} dB, analog {analog} dB");
    assert!(
        count > count100 + 3.0,
        "count {count} dB, count:100 {count100} dB"
    );
}

/// Bad requests fail with a message naming the problem, and nothing is written.
#[test]
fn bad_requests_are_refused_and_write_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    camera(d, 32);
    let (noisy, _) = stack(d, "0.3", 10, "1", "s");
    // A profile without CIC and dark current (no [pgn] section).
    let text = std::fs::read_to_string(d.join("cam/profile.toml")).unwrap();
    let i = text.find("\n[pgn]").expect("a [pgn] section");
    let rest = &text[i + 1..];
    let end = rest[1..].find("\n[").map_or(rest.len(), |j| j + 2);
    std::fs::create_dir(d.join("nopgn")).unwrap();
    std::fs::write(
        d.join("nopgn/profile.toml"),
        format!("{}{}", &text[..i + 1], &rest[end..]),
    )
    .unwrap();
    std::fs::copy(
        d.join("cam/maps.safetensors"),
        d.join("nopgn/maps.safetensors"),
    )
    .unwrap();
    let noisy = noisy.as_str();
    let fails = |args: &[&str], want: &str| {
        let o = emccd(args, d);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(want), "{args:?}: wanted {want:?} in {err}");
        assert!(!d.join("x.tif").exists(), "{args:?} wrote its output");
    };
    fails(
        &["count", noisy, "-o", "x.tif", "--profile", "nopgn"],
        "clock-induced charge",
    );
    fails(
        &[
            "count",
            noisy,
            "-o",
            "x.tif",
            "--profile",
            "cam",
            "--per",
            "11",
        ],
        "more than the stack's 10 frames",
    );
    fails(
        &[
            "count",
            noisy,
            "-o",
            "x.tif",
            "--profile",
            "cam",
            "--per",
            "0",
        ],
        "--per",
    );
    fails(
        &[
            "count",
            noisy,
            "-o",
            "x.tif",
            "--profile",
            "cam",
            "--per",
            "2.5",
        ],
        "--per",
    );
    fails(
        &[
            "count",
            noisy,
            "-o",
            "x.tif",
            "--profile",
            "cam",
            "--threshold=-3sigma",
        ],
        "a threshold is",
    );
    // A fixed threshold below 3σ works, with a warning that gives the false-event rate.
    let o = emccd(
        &[
            "count",
            noisy,
            "-o",
            "low.tif",
            "--profile",
            "cam",
            "--threshold",
            "2sigma",
        ],
        d,
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        o.status.success()
            && err.contains("warning")
            && err.contains("false events per pixel per frame"),
        "{err}"
    );
}

/// `emccd info --profile` measures a stack's light level and says when it is in the counting
/// regime; `emccd denoise` notes it too; a brighter stack gets no note.
#[test]
fn info_and_denoise_point_faint_stacks_to_count() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    camera(d, 32);
    for (photons, faint) in [("0.1", true), ("20", false)] {
        let out = format!("s{photons}");
        let (noisy, _) = stack(d, photons, 20, "1", &out);
        let v: serde_json::Value = serde_json::from_str(&ok(&emccd(
            &["info", &noisy, "--profile", "cam", "--json"],
            d,
        )))
        .unwrap();
        let level = v["photo_electrons_per_pixel_per_frame"].as_f64().unwrap();
        let truth = photons.parse::<f64>().unwrap() * 0.9;
        assert!((level / truth - 1.0).abs() < 0.2, "{level} vs {truth}");
        assert_eq!(v["counting_regime"].as_bool(), Some(faint));
        let o = emccd(
            &[
                "denoise",
                &noisy,
                "-o",
                &format!("{out}.tif"),
                "--profile",
                "cam",
                "--method",
                "none",
            ],
            d,
        );
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{err}");
        assert_eq!(err.contains("`emccd count`"), faint, "{err}");
    }
}
