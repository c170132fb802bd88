//! End-to-end tests: the built `emccd` binary in a fresh temporary directory.

mod common;

use common::{data, emccd, ok};

#[test]
fn profile_show_json_has_the_documented_keys() {
    let dir = tempfile::tempdir().unwrap();
    let v: serde_json::Value = serde_json::from_str(&ok(&emccd(
        &["profile", "show", "default", "--json"],
        dir.path(),
    )))
    .unwrap();
    assert_eq!(v["ptc_slope_dn"], 20.14);
    assert_eq!(v["width"], 512);
    assert_eq!(v["height"], 512);
    let bias = v["bias_dn"].as_f64().unwrap();
    assert!((160.0..195.0).contains(&bias), "{bias}");
    let rn = v["read_noise_dn"].as_f64().unwrap();
    assert!((2.8..3.2).contains(&rn), "{rn}");
    assert_eq!(v["exposures_s"].as_array().unwrap().len(), 20);
}

/// `profile init-default` writes the bundled profile as the repository shipped it (and the
/// bundled models were trained for): the same numbers, and maps whose bytes have the checksum
/// of the files it held until they were dropped for the generator they came from.
#[test]
fn the_bundled_profile_is_written_as_it_always_was() {
    let dir = tempfile::tempdir().unwrap();
    ok(&emccd(&["profile", "init-default", "p"], dir.path()));
    let text = std::fs::read_to_string(dir.path().join("p/profile.toml")).unwrap();
    assert!(
        text.contains("maps_fnv1a64 = \"1be1b03484642dd8\""),
        "{text}"
    );
    let loaded = emccd_profile::CameraProfile::load(dir.path().join("p")).unwrap();
    assert_eq!(loaded.fingerprint_hex(), "ecdca5badda28228");
    let maps = std::fs::read(dir.path().join("p/maps.safetensors")).unwrap();
    assert!(emccd_io::safetensors_sorted(maps.clone()) == maps);
}

#[test]
fn simulate_calibration_writes_manifest_stacks_and_truth() {
    let dir = tempfile::tempdir().unwrap();
    ok(&emccd(
        &[
            "simulate",
            "calibration",
            "-o",
            "cal",
            "--crop",
            "64x48",
            "--frames",
            "4",
            "--bias-exposures",
            "1e-5,0.01,0.1",
            "--flat-levels",
            "100,1000",
            "--blooming-exposures",
            "0.001,0.01",
        ],
        dir.path(),
    ));
    let cal = dir.path().join("cal");
    let m: toml::Value =
        toml::from_str(&std::fs::read_to_string(cal.join("calibration.toml")).unwrap()).unwrap();
    assert_eq!(m["camera"].as_str(), Some("virtual-897"));
    assert_eq!(m["bias"].as_array().unwrap().len(), 3);
    assert_eq!(m["flat"].as_array().unwrap().len(), 2);
    assert_eq!(m["blooming"].as_array().unwrap().len(), 2);
    for kind in ["bias", "flat", "blooming"] {
        for e in m[kind].as_array().unwrap() {
            let f = cal.join(e["file"].as_str().unwrap());
            let info = emccd_io::open(&f).unwrap().info().clone();
            assert_eq!(
                (info.width, info.height, info.frames),
                (64, 48, 4),
                "{}",
                f.display()
            );
            assert_eq!(info.metadata.exposure_s, e["exposure_s"].as_float());
        }
    }
    let truth: toml::Value =
        toml::from_str(&std::fs::read_to_string(cal.join("truth.toml")).unwrap()).unwrap();
    assert_eq!(truth["ptc_slope_dn"].as_float(), Some(20.14));
    let p = emccd_profile::CameraProfile::load(cal.join("truth")).unwrap();
    assert_eq!((p.width, p.height), (64, 48));
    // Flat at 1000 DN: temporal mean of the stack minus the bias stack ≈ 1000 (+ blooming share).
    let (_, flat) = emccd_io::read_all(cal.join("flat/flat_02.tif")).unwrap();
    let (_, bias) = emccd_io::read_all(cal.join("bias/bias_0.01s.tif")).unwrap();
    let mean = |fs: &Vec<Vec<f32>>| {
        fs.iter().flatten().map(|&v| v as f64).sum::<f64>() / (fs.len() * fs[0].len()) as f64
    };
    let x = p.blooming_factor(0.01);
    let signal = mean(&flat) - mean(&bias);
    // Blooming adds x·colmean to every pixel: signal·(1+x). Tolerance: shot noise of 4·64·48
    // samples at s·S variance (σ_mean ≈ sqrt(20·1000/12288) ≈ 1.3 DN) → 5σ ≈ 7 DN.
    assert!(
        (signal - 1000.0 * (1.0 + x)).abs() < 7.0,
        "flat signal {signal}"
    );
}

#[test]
fn simulate_pairs_and_info() {
    let dir = tempfile::tempdir().unwrap();
    let scene = data("clean/microscopy/fmd-confocal-bpae/field2-avg50.png");
    let out = ok(&emccd(
        &[
            "simulate",
            "pairs",
            "--clean",
            scene.to_str().unwrap(),
            "--photons",
            "50",
            "--crop",
            "128x96",
            "-o",
            "pairs",
        ],
        dir.path(),
    ));
    // The PSNR it prints is the one `evaluate` computes from the files it wrote (two code
    // paths: the simulator's own scoring, and a reader of pairs.toml and the stacks).
    let printed: f64 = out
        .lines()
        .find(|l| l.starts_with("noisy/field2-avg50_p50.tif"))
        .and_then(|l| l.split_whitespace().nth(2))
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no PSNR row in {out}"));
    let table = ok(&emccd(
        &["evaluate", "pairs", "--method", "input"],
        dir.path(),
    ));
    let scored: f64 = table
        .lines()
        .find(|l| l.starts_with("| all | input | all |"))
        .and_then(|l| l.split('|').nth(5))
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or_else(|| panic!("no input row in {table}"));
    assert!(
        (printed - scored).abs() < 0.011,
        "simulate printed {printed} dB, evaluate scored {scored} dB"
    );
    let p = dir.path().join("pairs");
    let m: toml::Value =
        toml::from_str(&std::fs::read_to_string(p.join("pairs.toml")).unwrap()).unwrap();
    let pair = &m["pair"].as_array().unwrap()[0];
    assert_eq!(pair["photons"].as_float(), Some(50.0));
    let noisy = p.join(pair["noisy"].as_str().unwrap());
    let v: serde_json::Value = serde_json::from_str(&ok(&emccd(
        &["info", noisy.to_str().unwrap(), "--json"],
        dir.path(),
    )))
    .unwrap();
    assert_eq!(
        (
            v["width"].as_u64(),
            v["height"].as_u64(),
            v["frames"].as_u64()
        ),
        (Some(128), Some(96), Some(1))
    );
    assert_eq!(v["exposure_s"], 0.01);
    assert_eq!(v["em_gain"], 300.0);
    let (ci, clean) = emccd_io::read_all(p.join(pair["clean"].as_str().unwrap())).unwrap();
    assert_eq!(ci.pixel_type, emccd_io::PixelType::F32);
    assert!(clean[0].iter().all(|&v| v >= 0.0));
    assert!(p.join(pair["preview"].as_str().unwrap()).exists());
}

#[test]
fn exposure_ratio_pairs_and_their_evaluation() {
    let dir = tempfile::tempdir().unwrap();
    let scene = data("clean/microscopy/fmd-confocal-bpae/field3-avg50.png");
    ok(&emccd(
        &[
            "simulate",
            "pairs",
            "--clean",
            scene.to_str().unwrap(),
            "--exposure-ratio",
            "30,1600",
            "--crop",
            "64x64",
            "-o",
            "r",
        ],
        dir.path(),
    ));
    let m: toml::Value =
        toml::from_str(&std::fs::read_to_string(dir.path().join("r/pairs.toml")).unwrap()).unwrap();
    let pairs = m["pair"].as_array().unwrap();
    assert_eq!(pairs.len(), 2);
    // Exposure = 1.6 s / ratio, photons = 16000 / ratio.
    for (p, r) in pairs.iter().zip([30.0, 1600.0]) {
        assert_eq!(p["exposure_ratio"].as_float(), Some(r));
        assert!((p["exposure_s"].as_float().unwrap() - 1.6 / r).abs() < 1e-12);
        assert!((p["photons"].as_float().unwrap() - 16000.0 / r).abs() < 1e-9);
    }
    let out = ok(&emccd(
        &[
            "evaluate", "r", "--method", "input", "--method", "bm3d", "--json",
        ],
        dir.path(),
    ));
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let rows = v["summary"].as_array().unwrap();
    let get = |m: &str, r: f64| {
        rows.iter()
            .find(|x| x["method"] == m && x["exposure_ratio"].as_f64() == Some(r))
            .unwrap()["psnr_db"]
            .as_f64()
            .unwrap()
    };
    // A 53× longer exposure collects 53× the light: the input is far cleaner, and BM3D helps at both.
    assert!(get("input", 30.0) > get("input", 1600.0) + 10.0);
    assert!(get("bm3d", 1600.0) > get("input", 1600.0) && get("bm3d", 30.0) > get("input", 30.0));
}

#[test]
fn info_json_on_real_sif_and_nulls_for_unknowns() {
    let dir = tempfile::tempdir().unwrap();
    let sif = data("emccd-real/andor-sif/ixon897_binned_gain56.sif");
    let v: serde_json::Value = serde_json::from_str(&ok(&emccd(
        &["info", sif.to_str().unwrap(), "--json"],
        dir.path(),
    )))
    .unwrap();
    assert_eq!(v["width"], 256);
    assert_eq!(v["frames"], 1);
    assert_eq!(v["em_gain"], 56.0);
    assert_eq!(v["exposure_s"], 0.01457);
    let png = data("clean/natural/Kodak24/kodim03.png");
    let v: serde_json::Value = serde_json::from_str(&ok(&emccd(
        &["info", png.to_str().unwrap(), "--json"],
        dir.path(),
    )))
    .unwrap();
    assert!(v["exposure_s"].is_null() && v["em_gain"].is_null());
}

#[test]
fn bad_input_fails_clearly_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("junk.tif"), b"II*\0garbage").unwrap();
    let o = emccd(&["info", "junk.tif"], dir.path());
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("junk.tif"), "{err}");

    let o = emccd(&["synthesize", "junk.tif", "-o", "out.tif"], dir.path());
    assert!(!o.status.success());
    assert!(!dir.path().join("out.tif").exists());

    let o = emccd(&["profile", "show", "no-such-profile"], dir.path());
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("no-such-profile"));

    let o = emccd(
        &["simulate", "calibration", "-o", "c", "--frames", "1"],
        dir.path(),
    );
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("at least 2"));
    // Nothing but the junk file (no temporaries, no partial outputs).
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 1, "{names:?}");
}

#[test]
fn synthesize_each_model() {
    let dir = tempfile::tempdir().unwrap();
    let scene = data("clean/natural/BSD68/test001.png");
    for m in ["ours", "eld", "pgn"] {
        let out = format!("{m}.tif");
        ok(&emccd(
            &[
                "synthesize",
                scene.to_str().unwrap(),
                "-o",
                &out,
                "--model",
                m,
                "--frames",
                "2",
            ],
            dir.path(),
        ));
        let (info, f) = emccd_io::read_all(dir.path().join(&out)).unwrap();
        assert_eq!(info.frames, 2);
        assert_ne!(f[0], f[1]);
    }
}

/// `bench --archive`, tiny: both stacks go through the three commands as child processes, every
/// row is reported, and nothing is left behind.
#[test]
fn archive_bench_measures_each_command_and_cleans_up() {
    let dir = tempfile::tempdir().unwrap();
    let out = ok(&emccd(
        &[
            "bench",
            "--archive",
            "0.002",
            "--net-frames",
            "1",
            "--archive-dir",
            ".",
        ],
        dir.path(),
    ));
    let rows: Vec<&str> = out
        .lines()
        .filter(|l| l.starts_with("info") || l.starts_with("denoise"))
        .collect();
    assert_eq!(rows.len(), 6, "{out}");
    for r in &rows {
        // command, stack, frames, seconds, frames/s, peak MiB: the last three are numbers.
        let v: Vec<f64> = r
            .split_whitespace()
            .rev()
            .take(3)
            .map(|x| x.parse().unwrap())
            .collect();
        // (peak MiB, frames/s, seconds): a short command's seconds may print as 0.0.
        assert!(
            v[0] > 0.0 && v[1] > 0.0 && v[1].is_finite() && v[2] >= 0.0,
            "{r}"
        );
    }
    assert!(
        out.contains("(first frames)") && out.contains("long"),
        "{out}"
    );
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    // A size that is not a positive number of GB is refused.
    let e = emccd(
        &["bench", "--archive", "0", "--archive-dir", "."],
        dir.path(),
    );
    assert!(!e.status.success());
}

/// The built binary copied into an empty folder, run from there, works: the bundled models and
/// the default profile are part of it. It holds no path into the checkout it was built in (a
/// crate's folder, as `env!("CARGO_MANIFEST_DIR")` would put there, or `models/` and `profiles/`
/// relative to one), so it cannot be reading them from there; and no message names one.
#[test]
fn the_binary_works_copied_anywhere() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let exe = d.join("emccd");
    std::fs::copy(env!("CARGO_BIN_EXE_emccd"), &exe).unwrap();
    let checkout = std::fs::canonicalize(env!("CARGO_MANIFEST_DIR")).unwrap();
    let needle = checkout.to_string_lossy().into_owned();
    let bytes = std::fs::read(&exe).unwrap();
    // (A debug build's line tables name the checkout itself as their directory: not a path
    // into it.)
    for path in [
        format!("{needle}/crates"),
        format!("{needle}/models"),
        format!("{needle}/profiles"),
        "../../models".to_string(),
        "../../profiles".to_string(),
    ] {
        assert!(
            !bytes.windows(path.len()).any(|w| w == path.as_bytes()),
            "the binary names {path}"
        );
    }
    let run = |args: &[&str]| {
        std::process::Command::new(&exe)
            .args(args)
            .current_dir(d)
            .env_remove("EMCCD_MODELS")
            .output()
            .unwrap()
    };
    // The default profile, cut to a small sensor so the networks run quickly.
    ok(&run(&[
        "profile", "crop", "default", "cam", "--roi", "64x48",
    ]));
    let mut w = emccd_io::StackWriter::create(
        d.join("rec.tif"),
        64,
        48,
        emccd_io::SampleFormat::U16,
        Some(2),
    )
    .unwrap();
    for k in 0..2 {
        let frame: Vec<f32> = (0..64 * 48)
            .map(|i| (180 + (i * 7919 + k * 104729) % 61) as f32)
            .collect();
        w.write_frame(&frame).unwrap();
    }
    w.finish().unwrap();
    let denoise = |name: &str, extra: &[&str]| {
        let out = format!("{name}.tif");
        let mut args = vec![
            "denoise",
            "rec.tif",
            "-o",
            &out,
            "--profile",
            "cam",
            "--exposure-s",
            "0.01",
        ];
        args.extend_from_slice(extra);
        ok(&run(&args));
        let t = tiff::decoder::Decoder::new(std::fs::File::open(d.join(&out)).unwrap())
            .unwrap()
            .dimensions()
            .unwrap();
        assert_eq!(t, (64, 48), "{name}");
    };
    for model in ["hybrid", "default", "microscopy", "lowlight", "movie"] {
        denoise(model, &["--model", model]);
    }
    denoise("temporal-net", &["--method", "temporal-net"]);
    denoise("net", &["--method", "net"]);
    denoise("blend", &["--method", "blend"]);
    denoise("temporal", &[]);
    let o = run(&[
        "denoise",
        "rec.tif",
        "-o",
        "x.tif",
        "--profile",
        "cam",
        "--model",
        "nosuch",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("nosuch: model not found"), "{err}");
    assert!(!err.contains(&needle), "{err}");
}

/// `profile export`: each tool's block on stdout or into a file (replaced only with `--force`),
/// an unknown tool named with the known ones, and an EM gain the profile lacks asked for.
#[test]
fn profile_export_writes_each_tools_camera_block() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = ok(&emccd(
        &["profile", "export", "default", "--to", "decode"],
        d,
    ));
    assert!(
        out.contains("Camera:") && out.contains("em_gain: 300"),
        "{out}"
    );
    for tool in ["picasso", "thunderstorm", "smap"] {
        let args = [
            "profile", "export", "default", "--to", tool, "-o", "cam.txt", "--force",
        ];
        ok(&emccd(&args, d));
        assert!(std::fs::read_to_string(d.join("cam.txt"))
            .unwrap()
            .is_ascii());
    }
    let o = emccd(
        &[
            "profile", "export", "default", "--to", "smap", "-o", "cam.txt",
        ],
        d,
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--force"));
    let o = emccd(&["profile", "export", "default", "--to", "imagej"], d);
    assert!(String::from_utf8_lossy(&o.stderr).contains("picasso, thunderstorm, decode and smap"));
}
