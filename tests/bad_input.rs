//! Bad input at the command line: each case exits 2 with a message naming what is wrong, leaves
//! no output, and never touches an input. Regression tests for what a hostile but fair user
//! found (issue 12): inputs overwritten, outputs shared, exposures that are not exposures,
//! profiles that cannot denoise, absurd tiling, closed pipes.

mod common;

use std::path::Path;
use std::process::Command;

use common::{emccd, ok};

/// A 512² u16 raw frame of the default profile's sensor (bias + a little signal), with an
/// exposure in its description, at `d/name`.
fn raw_frame(d: &Path, name: &str, exposure_s: Option<f64>) {
    if let Some(parent) = d.join(name).parent() {
        std::fs::create_dir_all(parent).unwrap();
    }
    let mut w =
        emccd_io::StackWriter::create(d.join(name), 512, 512, emccd_io::SampleFormat::U16, Some(1))
            .unwrap();
    w.set_metadata(&emccd_io::Metadata {
        exposure_s,
        ..Default::default()
    });
    w.write_frame(
        &(0..512 * 512)
            .map(|i| 500.0 + (i % 13) as f32 * 30.0)
            .collect::<Vec<f32>>(),
    )
    .unwrap();
    w.finish().unwrap();
}

fn fails_with(o: &std::process::Output, want: &str) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains(want), "wanted {want:?} in: {err}");
    assert!(!err.contains("panicked"), "{err}");
}

/// Two uniform `n`×`n` frames of 600 DN with an exposure of 0.01 s in the header.
fn flat_stack(d: &Path, name: &str, n: usize) {
    let mut w =
        emccd_io::StackWriter::create(d.join(name), n, n, emccd_io::SampleFormat::U16, Some(2))
            .unwrap();
    w.set_metadata(&emccd_io::Metadata {
        exposure_s: Some(0.01),
        ..Default::default()
    });
    for _ in 0..2 {
        w.write_frame(&vec![600.0; n * n]).unwrap();
    }
    w.finish().unwrap();
}

/// The bundled profile cropped to its top-left `w`×`h`, saved as `d/name`.
fn cropped_profile(d: &Path, name: &str, w: usize, h: usize) {
    emccd_profile::default_profile()
        .crop(emccd_profile::Roi::corner(w, h))
        .unwrap()
        .save(d.join(name))
        .unwrap();
}

/// `frames` of `w`×`h` written as `d/name` in `format`, with no exposure in the header.
fn write_stack(
    d: &Path,
    name: &str,
    (w, h): (usize, usize),
    format: emccd_io::SampleFormat,
    frames: &[Vec<f32>],
) {
    let mut wr =
        emccd_io::StackWriter::create(d.join(name), w, h, format, Some(frames.len())).unwrap();
    for f in frames {
        wr.write_frame(f).unwrap();
    }
    wr.finish().unwrap();
}

/// A small virtual-camera acquisition in `cal/`: 64×48, 4 frames per stack, three bias
/// exposures and flats at `flat_levels` (DN, comma-separated).
fn small_acquisition(d: &Path, flat_levels: &str) {
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
            flat_levels,
        ],
        d,
    ));
}

fn files(d: &Path) -> Vec<String> {
    let mut v: Vec<String> = walk(d)
        .into_iter()
        .map(|p| p.strip_prefix(d).unwrap().display().to_string())
        .collect();
    v.sort();
    v
}

fn walk(d: &Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(d).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(walk(&p));
        } else {
            out.push(p);
        }
    }
    out
}

#[test]
fn inputs_are_never_overwritten_and_outputs_never_shared() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    raw_frame(d, "x.tif", Some(0.01));
    raw_frame(d, "a/x.tif", Some(0.01));
    raw_frame(d, "b/x.tif", Some(0.01));
    raw_frame(d, "out/y_denoised.tif", Some(0.01));
    raw_frame(d, "y.tif", Some(0.01));
    raw_frame(d, "sim/clean/y_p20.tif", Some(0.01));
    std::fs::copy(
        common::repo("models/default-unet.safetensors"),
        d.join("m.safetensors"),
    )
    .unwrap();
    #[cfg(unix)]
    std::os::unix::fs::symlink("x.tif", d.join("link.tif")).unwrap();
    std::fs::hard_link(d.join("y.tif"), d.join("hard.tif")).unwrap();
    let before: Vec<(String, Vec<u8>)> = files(d)
        .into_iter()
        .map(|f| (f.clone(), std::fs::read(d.join(&f)).unwrap()))
        .collect();
    // The output is the input itself, spelled the same or differently.
    fails_with(
        &emccd(
            &["denoise", "--profile", "default", "x.tif", "-o", "x.tif"],
            d,
        ),
        "is the input",
    );
    fails_with(
        &emccd(
            &[
                "denoise",
                "--profile",
                "default",
                "x.tif",
                "-o",
                "./a/../x.tif",
            ],
            d,
        ),
        "is the input",
    );
    // An input reached through a symbolic link is the same file.
    #[cfg(unix)]
    {
        fails_with(
            &emccd(
                &[
                    "denoise",
                    "--profile",
                    "default",
                    "link.tif",
                    "-o",
                    "x.tif",
                    "--exposure-s",
                    "0.01",
                ],
                d,
            ),
            "is the input",
        );
        fails_with(
            &emccd(&["synthesize", "link.tif", "-o", "x.tif"], d),
            "is the input",
        );
    }
    // A hard link to an input is the input too.
    fails_with(
        &emccd(
            &[
                "denoise",
                "--profile",
                "default",
                "hard.tif",
                "-o",
                "y.tif",
                "--exposure-s",
                "0.01",
            ],
            d,
        ),
        "is the input",
    );
    // Two inputs with one file name from different folders.
    fails_with(
        &emccd(
            &[
                "denoise",
                "--profile",
                "default",
                "a/x.tif",
                "b/x.tif",
                "-o",
                "out",
            ],
            d,
        ),
        "would both be written",
    );
    // An input that is another input's output, in the output folder.
    fails_with(
        &emccd(
            &[
                "denoise",
                "--profile",
                "default",
                "y.tif",
                "out/y_denoised.tif",
                "-o",
                "out",
            ],
            d,
        ),
        "is the input",
    );
    // `synthesize` writes noise onto an image: never over that image.
    fails_with(
        &emccd(
            &["synthesize", "x.tif", "-o", "./x.tif", "--model", "ours"],
            d,
        ),
        "is the input",
    );
    // `simulate pairs`: two scenes with one name would write the same pairs, and a scene where
    // another scene's pair goes would be replaced before it is read.
    fails_with(
        &emccd(
            &[
                "simulate", "pairs", "--clean", "a/x.tif", "b/x.tif", "-o", "sim2",
            ],
            d,
        ),
        "have the same name",
    );
    fails_with(
        &emccd(
            &[
                "simulate",
                "pairs",
                "--photons",
                "20",
                "--clean",
                "y.tif",
                "sim/clean/y_p20.tif",
                "-o",
                "sim",
            ],
            d,
        ),
        "is an input scene",
    );
    // `train` never writes over the model it starts from.
    fails_with(
        &emccd(
            &[
                "train",
                "--clean",
                "x.tif",
                "--init",
                "m.safetensors",
                "--steps",
                "1",
                "-o",
                "./m.safetensors",
            ],
            d,
        ),
        "is the --init model",
    );
    let after: Vec<(String, Vec<u8>)> = files(d)
        .into_iter()
        .map(|f| (f.clone(), std::fs::read(d.join(&f)).unwrap()))
        .collect();
    assert_eq!(before, after, "a file was written or changed");
}

#[test]
fn exposures_must_be_positive_seconds_and_near_the_calibration() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    raw_frame(d, "x.tif", Some(0.01));
    raw_frame(d, "neg.tif", Some(-1.0));
    for t in ["-1", "0", "NaN", "inf"] {
        fails_with(
            &emccd(
                &[
                    "denoise",
                    "--profile",
                    "default",
                    "x.tif",
                    "-o",
                    "o.tif",
                    "--exposure-s",
                    t,
                ],
                d,
            ),
            "must be a positive number of seconds",
        );
    }
    // `synthesize` checks its exposure and its signal the same way.
    for (flag, v, want) in [
        ("--exposure-s", "-1", "must be a positive number of seconds"),
        (
            "--exposure-s",
            "NaN",
            "must be a positive number of seconds",
        ),
        ("--signal-dn", "inf", "must be a positive number of DN"),
        ("--signal-dn", "1e30", "must be a positive number of DN"),
    ] {
        for model in ["ours", "pgn"] {
            let arg = format!("{flag}={v}");
            fails_with(
                &emccd(
                    &["synthesize", "x.tif", "-o", "o.tif", &arg, "--model", model],
                    d,
                ),
                want,
            );
        }
    }
    // An output folder that does not exist is named, not a random temporary path in it.
    let o = emccd(
        &[
            "denoise",
            "--profile",
            "default",
            "x.tif",
            "-o",
            "nodir/o.tif",
            "--exposure-s",
            "0.01",
        ],
        d,
    );
    fails_with(&o, "the folder nodir does not exist");
    assert!(!String::from_utf8_lossy(&o.stderr).contains(".tmp"));
    // From a header it is the same error, saying where the number came from.
    fails_with(
        &emccd(
            &["denoise", "--profile", "default", "neg.tif", "-o", "o.tif"],
            d,
        ),
        "from the file header",
    );
    // Far outside the calibrated range the fixed pattern is a guess: an error unless asked for.
    fails_with(
        &emccd(
            &[
                "denoise",
                "--profile",
                "default",
                "x.tif",
                "-o",
                "o.tif",
                "--exposure-s",
                "10",
            ],
            d,
        ),
        "--extrapolate",
    );
    assert!(!d.join("o.tif").exists());
    // Bad tiling and self-ensembles are usage errors.
    for args in [
        ["--tile", "0"],
        ["--tile", "32"],
        ["--ensemble", "3"],
        ["--ensemble", "0"],
    ] {
        let o = emccd(
            &[
                "denoise",
                "--profile",
                "default",
                "x.tif",
                "-o",
                "o.tif",
                args[0],
                args[1],
            ],
            d,
        );
        assert_eq!(o.status.code(), Some(2), "{args:?}");
    }
    assert!(!d.join("o.tif").exists());
    assert_eq!(files(d).len(), 2, "{:?}", files(d));
}

/// An exposure in pairs.toml is checked like one on the command line, and the error names the
/// manifest and the pair.
#[test]
fn a_pairs_manifest_with_a_bad_exposure_names_itself() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    raw_frame(d, "scene.tif", None);
    ok(&emccd(
        &[
            "simulate",
            "pairs",
            "--clean",
            "scene.tif",
            "--photons",
            "20",
            "-o",
            "p",
        ],
        d,
    ));
    let m = d.join("p/pairs.toml");
    let text = std::fs::read_to_string(&m).unwrap();
    let bad: String = text
        .lines()
        .map(|l| {
            if l.starts_with("exposure_s") {
                "exposure_s = nan"
            } else {
                l
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    std::fs::write(&m, bad).unwrap();
    fails_with(
        &emccd(&["evaluate", "p", "--method", "input"], d),
        "pairs.toml: the pair noisy/scene_p20.tif: exposure_s = NaN must be a positive number of seconds",
    );
}

/// A profile without bias maps (what a gain-series calibration writes) cannot preprocess a
/// frame: a clear error, not an index out of bounds.
#[test]
fn a_profile_without_bias_maps_cannot_denoise() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    raw_frame(d, "x.tif", Some(0.01));
    let mut p = emccd_profile::default_profile();
    p.exposures_s.clear();
    p.maps.read_noise.clear();
    p.maps.fpn_base.clear();
    p.maps.fpn_theta.clear();
    p.save(d.join("gain-only")).unwrap();
    for method in ["bm3d", "net", "hybrid"] {
        fails_with(
            &emccd(
                &[
                    "denoise",
                    "x.tif",
                    "-o",
                    "o.tif",
                    "--profile",
                    "gain-only",
                    "--method",
                    method,
                ],
                d,
            ),
            "cannot denoise",
        );
    }
    assert!(!d.join("o.tif").exists());
}

/// Frames smaller than a block (BM3D's 11×11, the temporal method's 8×8), a tiny frame and a
/// strip narrower than a block, are denoised by every method, not a panic (`temporal-net`
/// overflowed its block positions below 8 px and left an empty store behind).
#[test]
fn every_method_denoises_tiny_frames() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (w, h, n) in [(8usize, 6usize, 2usize), (6, 64, 3)] {
        let name = format!("{w}x{h}");
        cropped_profile(d, &name, w, h);
        let input = format!("{name}.tif");
        let frames: Vec<Vec<f32>> = (0..n)
            .map(|k| {
                (0..w * h)
                    .map(|i| 500.0 + ((i * 7 + k) % 5) as f32 * 40.0)
                    .collect()
            })
            .collect();
        write_stack(d, &input, (w, h), emccd_io::SampleFormat::U16, &frames);
        // ivst bins this dim frame 4×4 (2×2 blocks) before BM3D.
        for method in [
            "bm3d",
            "ivst",
            "net",
            "blend",
            "hybrid",
            "temporal",
            "temporal-net",
        ] {
            for ext in ["tif", "zarr"] {
                let out = format!("o-{name}-{method}.{ext}");
                ok(&emccd(
                    &[
                        "denoise",
                        &input,
                        "-o",
                        &out,
                        "--profile",
                        &name,
                        "--method",
                        method,
                        "--exposure-s",
                        "0.01",
                    ],
                    d,
                ));
                let (info, frames) = emccd_io::read_all(d.join(&out)).unwrap();
                assert_eq!((info.width, info.height, info.frames), (w, h, n), "{out}");
                assert!(frames.iter().flatten().all(|v| v.is_finite()), "{out}");
            }
        }
    }
}

/// A reader that went away: stdout closed ends the program quietly (exit 0, no panic); stderr
/// closed loses only messages, and every file of the batch is still written.
#[cfg(unix)]
#[test]
fn closed_pipes_are_no_panic_and_lose_no_work() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    raw_frame(d, "a.tif", Some(0.01));
    raw_frame(d, "b.tif", Some(0.01));
    let bin = env!("CARGO_BIN_EXE_emccd");
    // `true` exits at once, so the pipe is closed by the time emccd writes.
    let run = |script: &str| {
        Command::new("sh")
            .arg("-c")
            .arg(script)
            .arg(bin)
            .current_dir(d)
            .output()
            .unwrap()
    };
    let o = run(r#"(sleep 0.5; "$0" info --json a.tif; echo "rc=$?" >&2) | true"#);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("rc=0") && !err.contains("panicked"), "{err}");
    let o = run(
        r#"(sleep 0.5; "$0" denoise a.tif b.tif -o out --profile default --method bm3d 2>&1; echo "rc=$?" > rc.txt) | true"#,
    );
    let rc = std::fs::read_to_string(d.join("rc.txt")).unwrap();
    assert_eq!(rc.trim(), "rc=0", "{}", String::from_utf8_lossy(&o.stderr));
    for f in ["out/a_denoised.tif", "out/b_denoised.tif"] {
        assert!(d.join(f).is_file(), "{f} missing");
    }
}

/// A `simulate pairs` that fails (a scene that is no image) leaves no folders behind, except
/// those that existed before; the reason is said once, with the file named.
#[test]
fn a_failed_simulation_leaves_nothing_and_says_why_once() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("bad.png"), "not an image").unwrap();
    std::fs::create_dir(d.join("kept")).unwrap();
    for out in ["fresh", "kept"] {
        let o = emccd(&["simulate", "pairs", "--clean", "bad.png", "-o", out], d);
        fails_with(&o, "bad.png");
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(err.matches("unrecognized first bytes").count(), 1, "{err}");
    }
    assert!(
        !d.join("fresh").exists(),
        "a folder this run created was left"
    );
    assert!(d.join("kept").is_dir() && files(&d.join("kept")).is_empty());
}

/// `--hybrid-base` names the estimate a refinement network corrects: a plain denoiser has none,
/// and saying one is an error rather than a base recorded in its model file.
#[test]
fn a_plain_denoiser_has_no_base_estimate() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let img = common::data("clean/natural/Kodak24/kodim01.png");
    let o = emccd(
        &[
            "train",
            "--clean",
            img.to_str().unwrap(),
            "--hybrid-base",
            "ivst",
            "--steps",
            "2",
            "-o",
            "m.safetensors",
        ],
        d,
    );
    fails_with(&o, "only a refinement network");
    assert!(files(d).is_empty(), "{:?}", files(d));
}

/// Stopped by Ctrl-C or SIGTERM in the middle of writing, a run leaves no hidden temporary file
/// (their destructors do not run when a signal ends the process).
#[cfg(unix)]
#[test]
fn an_interrupted_run_leaves_no_temporary_files() {
    let img = common::data("clean/natural/Kodak24/kodim01.png");
    for signal in ["-INT", "-TERM"] {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let child = Command::new(env!("CARGO_BIN_EXE_emccd"))
            .args(["simulate", "pairs", "--clean", img.to_str().unwrap()])
            // Long enough to be stopped (2.6 GB, checked against free space first, written
            // at most a little of).
            .args([
                "--photons",
                "20",
                "--frames",
                "20000",
                "--crop",
                "256x256",
                "-o",
                "p",
            ])
            .current_dir(d)
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let tmp_exists = || files(d).iter().any(|f| f.ends_with(".tmp"));
        let t0 = std::time::Instant::now();
        while !tmp_exists() && t0.elapsed().as_secs() < 60 {
            std::thread::sleep(std::time::Duration::from_millis(50));
        }
        assert!(tmp_exists(), "the run never started writing");
        let k = Command::new("kill")
            .args([signal, &child.id().to_string()])
            .status()
            .unwrap();
        assert!(k.success());
        let out = child.wait_with_output().unwrap();
        assert_eq!(out.status.code(), Some(130), "{signal}");
        assert!(
            String::from_utf8_lossy(&out.stderr).contains("interrupted"),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let left: Vec<String> = files(d)
            .into_iter()
            .filter(|f| f.ends_with(".tmp"))
            .collect();
        assert!(left.is_empty(), "{signal}: left {left:?}");
        // The folders the run made held nothing finished: they went too.
        assert!(
            !d.join("p").exists(),
            "{signal}: the run's empty folders were left"
        );
    }
}

/// Copies a directory tree.
fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let p = e.unwrap().path();
        let q = to.join(p.file_name().unwrap());
        if p.is_dir() {
            copy_tree(&p, &q);
        } else {
            std::fs::copy(&p, &q).unwrap();
        }
    }
}

/// The committed corpus of damaged files (`tests/corpus/bad`, written by
/// `tools/make_bad_corpus.py`) through every command that reads each kind: exit 2, a message
/// naming the file at fault, no panic, and nothing left behind — no output, no temporary file.
#[test]
fn the_bad_input_corpus_is_refused_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    copy_tree(&common::repo("tests/corpus/bad"), d);
    raw_frame(d, "good.tif", Some(0.01));
    let before = files(d);
    let mut names: Vec<String> = std::fs::read_dir(d)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n != "good.tif")
        .collect();
    names.sort();
    let mut cases = 0;
    for name in &names {
        // The file a message must name: the corpus file, or for a manifest the stack it names.
        let at_fault = match name.as_str() {
            "manifest-missing-file.toml" => "no-such-stack.tif",
            "manifest-damaged-stack.toml" => "frames-truncated-strip.tif",
            n => n,
        };
        let runs: Vec<Vec<&str>> = if name.starts_with("frames-") {
            let mut v = vec![vec![
                "denoise",
                "--profile",
                "default",
                name,
                "-o",
                "out.tif",
                "--method",
                "net",
            ]];
            // `info` describes a header (it marks a bad exposure, tested below; it reads no
            // frame), and an explicit exposure overrides the header's: the bad-exposure file is
            // only wrong without one.
            if !name.contains("exposure") {
                if !name.contains("nan") {
                    v.push(vec!["info", name]);
                }
                let e = ["--exposure-s", "0.01"];
                for (cmd, out, extra) in [
                    ("denoise", "out.tif", &[][..]),
                    ("denoise", "out.tif", &["--method", "temporal"][..]),
                    ("denoise", "out.zarr", &[][..]),
                    ("count", "out.tif", &[][..]),
                ] {
                    v.push([&[cmd, name, "-o", out][..], &e, extra].concat());
                }
            }
            v
        } else if name.starts_with("manifest-") {
            vec![vec!["calibrate", name, "-o", "prof"]]
        } else if let Some(flag) = [("model-", "--model"), ("profile-", "--profile")]
            .into_iter()
            .find_map(|(prefix, flag)| name.starts_with(prefix).then_some(flag))
        {
            // A good frame denoised (and, with a damaged profile, counted) with the damaged
            // model or profile.
            let mut denoise = vec![
                "denoise",
                "good.tif",
                "-o",
                "out.tif",
                "--exposure-s",
                "0.01",
                flag,
                name,
            ];
            // A damaged model through the bundled profile (good.tif holds no EMCCD data to
            // characterize a camera from).
            if flag == "--model" {
                denoise.extend(["--profile", "default"]);
            }
            let mut v = vec![denoise];
            if flag == "--profile" {
                v.push(vec![
                    "count",
                    "good.tif",
                    "-o",
                    "out.tif",
                    "--exposure-s",
                    "0.01",
                    flag,
                    name,
                ]);
            }
            v
        } else {
            panic!("corpus file {name} has no known prefix");
        };
        for args in runs {
            let o = emccd(&args, d);
            let err = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
            assert!(
                err.contains(at_fault),
                "{args:?} does not name {at_fault}: {err}"
            );
            assert!(!err.contains("panicked"), "{args:?}: {err}");
            assert_eq!(files(d), before, "{args:?} left files behind");
            cases += 1;
        }
    }
    assert!(cases >= 70, "only {cases} cases ran");
    let o = emccd(&["info", "frames-negative-exposure.fits"], d);
    assert!(ok(&o).contains("-1 s  (not a positive number of seconds"));
}

/// `adapt` refuses, before training and writing nothing: recordings of a size other than the
/// profile's sensor (also a second recording after a good first one), a profile of another
/// size, an output that is an input, and a recording without an exposure.
#[test]
fn adapt_refuses_mismatched_recordings_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    raw_frame(d, "good.tif", Some(0.01));
    raw_frame(d, "no-exposure.tif", None);
    flat_stack(d, "small.tif", 256);
    cropped_profile(d, "p64", 64, 64);
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("models/default-unet.safetensors"),
        d.join("init.safetensors"),
    )
    .unwrap();
    let before = files(d);
    let adapt = |args: &[&str]| {
        let mut a = vec!["adapt", "--steps", "2"];
        a.extend_from_slice(args);
        emccd(&a, d)
    };
    fails_with(
        &adapt(&[
            "good.tif",
            "small.tif",
            "--profile",
            "default",
            "-o",
            "m.safetensors",
        ]),
        "small.tif: frames are 256×256, the profile's sensor is 512×512",
    );
    fails_with(
        &adapt(&["good.tif", "--profile", "p64", "-o", "m.safetensors"]),
        "good.tif: frames are 512×512, the profile's sensor is 64×64",
    );
    fails_with(
        &adapt(&["good.tif", "--profile", "default", "-o", "good.tif"]),
        "the output is an input",
    );
    fails_with(
        &adapt(&[
            "no-exposure.tif",
            "--profile",
            "default",
            "-o",
            "m.safetensors",
        ]),
        "no-exposure.tif: the header records no exposure; pass --exposure-s",
    );
    fails_with(
        &adapt(&[
            "good.tif",
            "--profile",
            "default",
            "--method",
            "noise2noise",
            "-o",
            "m.safetensors",
        ]),
        "1 frame(s) in all: --method noise2noise needs 2 or more frames",
    );
    fails_with(
        &adapt(&[
            "good.tif",
            "--profile",
            "default",
            "--init",
            "init.safetensors",
            "--from-scratch",
            "-o",
            "init.safetensors",
        ]),
        "the output is the --init model",
    );
    // An earlier file that is no input (a recording, a manifest, a model) is not written over
    // without --force, a folder is no model's name, and a missing folder is said before any
    // training (which left a checkpoint folder of 40 MB behind).
    std::fs::write(d.join("notes.toml"), "kept = true\n").unwrap();
    std::fs::create_dir(d.join("models")).unwrap();
    let before = files(d);
    for (out, want) in [
        ("notes.toml", "notes.toml: exists; pass --force"),
        ("models", "models: is a folder"),
        ("nowhere/m.safetensors", "the folder nowhere does not exist"),
    ] {
        fails_with(
            &adapt(&["good.tif", "--profile", "default", "-o", out]),
            want,
        );
    }
    assert_eq!(
        std::fs::read_to_string(d.join("notes.toml")).unwrap(),
        "kept = true\n"
    );
    assert!(std::fs::read_dir(d.join("models"))
        .unwrap()
        .next()
        .is_none());
    assert_eq!(files(d), before, "adapt wrote or removed files");
    // Bias frames hold no scene to adapt to (they trained without a word).
    small_acquisition(d, "100");
    cropped_profile(d, "p64x48", 64, 48);
    let before = files(d);
    fails_with(
        &adapt(&[
            "cal/bias/bias_0.01s.tif",
            "--profile",
            "p64x48",
            "-o",
            "m.safetensors",
        ]),
        "no scene to adapt to",
    );
    assert_eq!(files(d), before, "adapt wrote or removed files");
}

/// A profile, an acquisition or a set of pairs already in the output folder is not replaced
/// without `--force`, and what is there stays as it was (these replaced them silently, exit 0);
/// with `--force` it is replaced.
#[test]
fn earlier_results_are_replaced_only_with_force() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // A calibrated profile stands for any earlier one: a small crop of the default.
    ok(&emccd(
        &["profile", "crop", "default", "cam", "--roi", "16x12"],
        d,
    ));
    let snapshot = |sub: &str| -> Vec<(String, Vec<u8>)> {
        files(&d.join(sub))
            .into_iter()
            .map(|f| (f.clone(), std::fs::read(d.join(sub).join(&f)).unwrap()))
            .collect()
    };
    let profile = snapshot("cam");
    for args in [
        vec!["profile", "init-default", "cam"],
        vec!["profile", "crop", "default", "cam", "--roi", "8x8"],
        vec!["calibrate", "missing.toml", "-o", "cam"],
    ] {
        fails_with(&emccd(&args, d), "already holds a camera profile");
        assert_eq!(snapshot("cam"), profile, "{args:?} changed the profile");
    }
    let acquisition = [
        "simulate",
        "calibration",
        "-o",
        "acq",
        "--crop",
        "16x12",
        "--frames",
        "2",
        "--bias-exposures",
        "0.01",
        "--flat-levels",
        "100",
        "--blooming-exposures",
        "0.01",
    ];
    ok(&emccd(&acquisition, d));
    let before = snapshot("acq");
    fails_with(
        &emccd(&acquisition, d),
        "already holds a calibration acquisition",
    );
    assert_eq!(snapshot("acq"), before);
    raw_frame(d, "scene.tif", None);
    let pairs = [
        "simulate",
        "pairs",
        "--clean",
        "scene.tif",
        "--crop",
        "16x12",
        "-o",
        "p",
    ];
    ok(&emccd(&pairs, d));
    let before = snapshot("p");
    fails_with(&emccd(&pairs, d), "already holds test pairs");
    assert_eq!(snapshot("p"), before);
    // --force replaces.
    ok(&emccd(&["profile", "init-default", "cam", "--force"], d));
    let v: serde_json::Value =
        serde_json::from_str(&ok(&emccd(&["profile", "show", "cam", "--json"], d))).unwrap();
    assert_eq!(v["width"], 512);
}

/// Numbers no camera or scene has are refused by name before anything is written (these
/// panicked in the virtual camera's sampler and left half an acquisition behind).
#[test]
fn simulations_refuse_numbers_no_camera_has() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    raw_frame(d, "scene.tif", None);
    let cal = |extra: &[&str]| {
        let mut a = vec!["simulate", "calibration", "-o", "acq", "--crop", "16x12"];
        a.extend_from_slice(extra);
        emccd(&a, d)
    };
    for (extra, want) in [
        (&["--dark", "inf"][..], "dark"),
        (&["--dark", "1e20"][..], "dark"),
        (&["--cic", "1e30"][..], "cic"),
        (&["--bias-exposures", "1e30"][..], "bias-exposures"),
    ] {
        fails_with(&cal(extra), want);
    }
    let pairs = |extra: &[&str]| {
        let mut a = vec![
            "simulate",
            "pairs",
            "--clean",
            "scene.tif",
            "--crop",
            "16x12",
            "-o",
            "p",
        ];
        a.extend_from_slice(extra);
        emccd(&a, d)
    };
    for (extra, want) in [
        (&["--photons", "1e30"][..], "photons"),
        (
            &["--exposure-ratio", "10", "--reference-photons", "1e30"][..],
            "reference-photons",
        ),
        (
            &["--exposure-ratio", "10", "--reference-exposure-s", "1e30"][..],
            "reference-exposure-s",
        ),
    ] {
        fails_with(&pairs(extra), want);
    }
    assert_eq!(files(d), ["scene.tif"], "something was left behind");
}

/// `denoise A B C -o out/` is all or nothing: an input that is missing, or that fails halfway
/// (truncated, a non-finite value), after good ones leaves no output written, earlier results
/// in `out/` as they were, no temporary files, and no `out/` where there was none (the earlier
/// inputs' outputs used to be written, and earlier results replaced, before the bad one failed).
#[test]
fn denoising_several_inputs_is_all_or_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    raw_frame(d, "a.tif", Some(0.01));
    raw_frame(d, "b.tif", Some(0.01));
    // Two frames, cut in the second.
    flat_stack(d, "cut.tif", 512);
    let len = std::fs::metadata(d.join("cut.tif")).unwrap().len();
    let f = std::fs::OpenOptions::new()
        .write(true)
        .open(d.join("cut.tif"))
        .unwrap();
    f.set_len(len * 3 / 4).unwrap();
    drop(f);
    // A float frame with a NaN in it.
    let mut w = emccd_io::StackWriter::create(
        d.join("nan.fits"),
        512,
        512,
        emccd_io::SampleFormat::F32,
        Some(1),
    )
    .unwrap();
    w.write_frame(&vec![600.0; 512 * 512]).unwrap();
    w.finish().unwrap();
    let mut bytes = std::fs::read(d.join("nan.fits")).unwrap();
    // FITS data start at 2880 bytes; big-endian float32 NaN.
    bytes[2880 + 4000..2880 + 4004].copy_from_slice(&f32::NAN.to_be_bytes());
    std::fs::write(d.join("nan.fits"), bytes).unwrap();
    let denoise = |inputs: &[&str], out: &str| {
        let mut args = vec!["denoise", "--profile", "default"];
        args.extend_from_slice(inputs);
        args.extend_from_slice(&["-o", out, "--method", "none", "--exposure-s", "0.01"]);
        emccd(&args, d)
    };
    // A missing input: refused before anything, no folder made.
    let o = denoise(&["a.tif", "missing.tif"], "new");
    assert_eq!(o.status.code(), Some(2));
    assert!(!d.join("new").exists(), "an empty output folder was left");
    // Inputs failing halfway, after a good one: earlier results stay, nothing else appears.
    raw_frame(d, "out/a_denoised.tif", Some(0.5));
    let earlier = std::fs::read(d.join("out/a_denoised.tif")).unwrap();
    for bad in ["cut.tif", "nan.fits"] {
        let o = denoise(&["a.tif", "b.tif", bad], "out");
        assert_eq!(
            o.status.code(),
            Some(2),
            "{bad}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        assert_eq!(files(&d.join("out")), ["a_denoised.tif"], "{bad}");
        assert!(
            std::fs::read(d.join("out/a_denoised.tif")).unwrap() == earlier,
            "{bad}"
        );
        let o = denoise(&["a.tif", bad], "fresh");
        assert_eq!(o.status.code(), Some(2));
        assert!(
            !d.join("fresh").exists(),
            "{bad}: an output folder was left"
        );
    }
    // The good inputs alone are written.
    ok(&denoise(&["a.tif", "b.tif"], "out"));
    assert_eq!(files(&d.join("out")), ["a_denoised.tif", "b_denoised.tif"]);
}

/// Messages say what is wrong: a folder or device given as a model or as a manifest's stack is
/// not "not found", a file given as the output folder of several inputs is named as such, a
/// repeated simulation setting is refused (it wrote two stacks into one file), and huge or tiny
/// exposures print short.
#[test]
fn messages_name_what_is_wrong() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    raw_frame(d, "a.tif", Some(0.01));
    raw_frame(d, "b.tif", Some(0.01));
    std::fs::create_dir(d.join("folder")).unwrap();
    let run = |args: &[&str]| emccd(args, d);
    for model in ["folder", "/dev/null"] {
        let o = run(&[
            "denoise",
            "--profile",
            "default",
            "a.tif",
            "-o",
            "x.tif",
            "--model",
            model,
        ]);
        fails_with(&o, "not a model file");
    }
    std::fs::write(
        d.join("m.toml"),
        "em_gain = 300\n[[bias]]\nfile = \"folder\"\nexposure_s = 0.01\n",
    )
    .unwrap();
    fails_with(
        &run(&["calibrate", "m.toml", "-o", "p"]),
        "a folder, not a stack",
    );
    fails_with(
        &run(&[
            "denoise",
            "--profile",
            "default",
            "a.tif",
            "b.tif",
            "-o",
            "a.tif",
            "--method",
            "none",
        ]),
        "is a file; several inputs",
    );
    fails_with(
        &run(&[
            "simulate",
            "calibration",
            "-o",
            "acq",
            "--crop",
            "16x12",
            "--bias-exposures",
            "0.01,0.01",
        ]),
        "0.01 is given twice",
    );
    let o = run(&[
        "denoise",
        "--profile",
        "default",
        "a.tif",
        "-o",
        "x.tif",
        "--exposure-s",
        "1e-300",
    ]);
    fails_with(&o, "exposure 1e-300 s");
    assert!(String::from_utf8_lossy(&o.stderr).len() < 400);
    assert!(!d.join("acq").exists() && !d.join("p").exists() && !d.join("x.tif").exists());
}

/// A calibration whose profile cannot be written (its folder's parent is a file) leaves no
/// report folder behind either.
#[test]
fn a_failed_calibration_leaves_no_report() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    small_acquisition(d, "100,300,1000");
    std::fs::write(d.join("file"), b"not a folder").unwrap();
    let o = emccd(
        &[
            "calibrate",
            "cal/calibration.toml",
            "-o",
            "file/profile",
            "--report",
            "rep",
        ],
        d,
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("the profile to file/profile"), "{err}");
    assert!(!d.join("rep").exists(), "the report folder was left");
}

/// Eight copies of one flat (eight files) as eight levels: refused naming the flats and what
/// is wrong with them (they were fitted to a slope with r² = 1 here; the report that found it
/// got "ptc_slope_dn must be positive, got -16" from the profile's checks). One file listed
/// eight times is refused before (`a_stack_listed_twice_or_a_flat_listed_as_a_bias_is_refused`).
#[test]
fn identical_flats_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    small_acquisition(d, "300");
    let manifest = std::fs::read_to_string(d.join("cal/calibration.toml")).unwrap();
    let flat = manifest
        .split("[[flat]]")
        .nth(1)
        .expect("a flat")
        .split("[[")
        .next()
        .unwrap()
        .to_string();
    let head = manifest.split("[[flat]]").next().unwrap().to_string();
    let eight: String = (0..8)
        .map(|i| {
            let copy = format!("flat/copy_{i}.tif");
            std::fs::copy(d.join("cal/flat/flat_01.tif"), d.join("cal").join(&copy)).unwrap();
            format!("[[flat]]{}", flat.replace("flat/flat_01.tif", &copy))
        })
        .collect();
    std::fs::write(d.join("cal/eight.toml"), format!("{head}{eight}")).unwrap();
    let o = emccd(&["calibrate", "cal/eight.toml", "-o", "p"], d);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("all hold one light level") && err.contains("copy_0.tif"),
        "{err}"
    );
    assert!(!d.join("p").exists());
}

/// A float64 FITS frame with a finite 1e300 in it (beyond float32) is refused with the value
/// and why it is not a number here, not as a bare "non-finite value".
#[test]
fn a_value_beyond_float32_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let card = |s: String| format!("{s:<80}");
    let mut head: String = [
        "SIMPLE  =                    T".to_string(),
        "BITPIX  =                  -64".to_string(),
        "NAXIS   =                    2".to_string(),
        "NAXIS1  =                  512".to_string(),
        "NAXIS2  =                  512".to_string(),
        "EXPTIME =                 0.01".to_string(),
        "END".to_string(),
    ]
    .into_iter()
    .map(card)
    .collect();
    head.push_str(&" ".repeat((2880 - head.len() % 2880) % 2880));
    let mut bytes = head.into_bytes();
    for i in 0..512 * 512 {
        let v: f64 = if i == 7 { 1e300 } else { 600.0 };
        bytes.extend_from_slice(&v.to_be_bytes());
    }
    bytes.resize(bytes.len().div_ceil(2880) * 2880, 0);
    std::fs::write(d.join("big.fits"), bytes).unwrap();
    let o = emccd(
        &[
            "denoise",
            "--profile",
            "default",
            "big.fits",
            "-o",
            "x.tif",
            "--method",
            "none",
        ],
        d,
    );
    fails_with(&o, "pixel (7, 0) (inf; a float64 beyond float32");
    assert!(!d.join("x.tif").exists());
}

/// One finite value no camera reads (1e20, −1e20, 3e38 in a float file) is refused naming the
/// pixel, by every method (the networks normalized the whole frame by it: one value ruined it,
/// and four frames of `temporal-net`); nothing is written.
#[test]
fn a_value_no_camera_reads_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    cropped_profile(d, "p32", 32, 32);
    for (k, bad) in [1e20f32, -1e20, 3e38].into_iter().enumerate() {
        let name = format!("f{k}.tif");
        let frames: Vec<Vec<f32>> = (0..3)
            .map(|f| {
                (0..32 * 32)
                    .map(|i| {
                        if f == 1 && i == 40 {
                            bad
                        } else {
                            500.0 + (i % 7) as f32 * 20.0
                        }
                    })
                    .collect()
            })
            .collect();
        write_stack(d, &name, (32, 32), emccd_io::SampleFormat::F32, &frames);
        for method in ["net", "blend", "hybrid", "temporal-net", "bm3d"] {
            let o = emccd(
                &[
                    "denoise",
                    &name,
                    "--profile",
                    "p32",
                    "--exposure-s",
                    "0.01",
                    "--method",
                    method,
                    "-o",
                    "x.tif",
                ],
                d,
            );
            fails_with(&o, "at pixel (8, 1) is no camera reading");
            assert!(!d.join("x.tif").exists(), "{method}");
        }
    }
}

/// Runs `emccd ARGS` in `cwd`, killed after 60 s (a run waiting on a FIFO would wait forever).
fn emccd_or_kill(args: &[&str], cwd: &Path) -> std::process::Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_emccd"))
        .args(args)
        .current_dir(cwd)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    for _ in 0..600 {
        if child.try_wait().unwrap().is_some() {
            return child.wait_with_output().unwrap();
        }
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    child.kill().unwrap();
    panic!("emccd {args:?} still ran after 60 s");
}

/// A FIFO or a device given as an image is refused by name before it is opened (opening a
/// FIFO with no writer waited forever; /dev/zero read on), and nothing is written.
#[test]
fn special_files_are_refused_not_waited_on() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let made = Command::new("mkfifo").arg(d.join("f.tif")).status();
    let mut inputs = vec!["/dev/zero"];
    if made.is_ok_and(|s| s.success()) {
        inputs.push("f.tif");
    }
    for input in inputs {
        for args in [
            &["info", input][..],
            &[
                "denoise",
                "--profile",
                "default",
                input,
                "-o",
                "o.tif",
                "--exposure-s",
                "0.01",
            ][..],
            &[
                "count",
                "--profile",
                "default",
                input,
                "-o",
                "o.tif",
                "--exposure-s",
                "0.01",
            ][..],
        ] {
            fails_with(
                &emccd_or_kill(args, d),
                "a device or other special file, not an image file",
            );
        }
    }
    assert!(!d.join("o.tif").exists());
}

/// `simulate calibration` checks the room its stacks need before writing one (it wrote on until
/// the disk was full), and a run that fails part way moves nothing into its folder (it left
/// half an acquisition without a manifest); what was there before stays.
#[test]
fn a_simulated_acquisition_is_whole_or_absent() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let o = emccd(
        &[
            "simulate",
            "calibration",
            "-o",
            "huge",
            "--crop",
            "64x48",
            "--frames",
            "1000000000000",
        ],
        d,
    );
    fails_with(&o, "GB free; make room, write elsewhere or ask for less");
    assert!(!d.join("huge").exists());

    // The flats' folder cannot be made (a file holds its name): the whole acquisition is
    // written beside `cal` first, so the clash moves nothing into it (the bias stacks were
    // written and left).
    std::fs::create_dir(d.join("cal")).unwrap();
    std::fs::write(d.join("cal/flat"), b"mine").unwrap();
    let o = emccd(
        &[
            "simulate",
            "calibration",
            "-o",
            "cal",
            "--crop",
            "64x48",
            "--frames",
            "4",
        ],
        d,
    );
    fails_with(
        &o,
        "a file is in the way of what this run writes there; nothing was placed",
    );
    assert_eq!(files(d), ["cal/flat"]);
    assert_eq!(std::fs::read(d.join("cal/flat")).unwrap(), b"mine");
}

/// `evaluate --out` checks every pair before any work and writes its panels and tables only
/// when every pair is scored: a later pair at fault (a missing truth, a truth of another
/// size) leaves no folder, and an earlier `--out` folder as it was (the first pairs' panels
/// were written before the error).
#[test]
fn evaluate_writes_all_or_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    raw_frame(d, "scene.tif", None);
    ok(&emccd(
        &[
            "simulate",
            "pairs",
            "--clean",
            "scene.tif",
            "--photons",
            "20",
            "--photons",
            "40",
            "--photons",
            "80",
            "-o",
            "p",
        ],
        d,
    ));
    let truth = d.join("p/clean/scene_p80.tif");
    let good = std::fs::read(&truth).unwrap();
    std::fs::create_dir(d.join("earlier")).unwrap();
    std::fs::write(d.join("earlier/results.csv"), b"mine").unwrap();
    std::fs::remove_file(&truth).unwrap();
    for out in ["ev", "earlier"] {
        let o = emccd(&["evaluate", "p", "--method", "input", "--out", out], d);
        fails_with(&o, "scene_p80.tif");
    }
    // A truth of another size is named with the pairs folder.
    let mut w =
        emccd_io::StackWriter::create(&truth, 8, 8, emccd_io::SampleFormat::U16, Some(1)).unwrap();
    w.write_frame(&[1.0; 64]).unwrap();
    w.finish().unwrap();
    let o = emccd(&["evaluate", "p", "--method", "input", "--out", "ev"], d);
    fails_with(&o, "noisy/scene_p80.tif: noisy 512×512 and clean 8×8");
    assert!(String::from_utf8_lossy(&o.stderr)
        .contains(&format!("p{}noisy", std::path::MAIN_SEPARATOR)));
    assert!(!d.join("ev").exists());
    assert_eq!(files(&d.join("earlier")), ["results.csv"]);
    assert_eq!(
        std::fs::read(d.join("earlier/results.csv")).unwrap(),
        b"mine"
    );
    std::fs::write(&truth, good).unwrap();
    ok(&emccd(
        &["evaluate", "p", "--method", "input", "--out", "ev"],
        d,
    ));
    assert_eq!(files(&d.join("ev")).len(), 5);
}

/// A recording binned on the chip (a real 2×2-binned iXon 897 SIF) given with an unbinned
/// profile is told to calibrate a profile at that binning (it was told to crop the profile
/// for a sub-array readout, which would not make one).
#[test]
fn a_binned_recording_asks_for_a_binned_calibration() {
    let dir = tempfile::tempdir().unwrap();
    let sif = common::data("emccd-real/andor-sif/ixon897_binned_gain56.sif");
    for cmd in ["denoise", "count"] {
        // A given profile (without one, the binned frames are characterized as they are).
        let o = emccd(
            &[
                cmd,
                sif.to_str().unwrap(),
                "-o",
                "o.tif",
                "--profile",
                "default",
            ],
            dir.path(),
        );
        fails_with(&o, "binned 2×2 on the chip");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            err.contains("taken with the same binning") && !err.contains("cropped"),
            "{err}"
        );
    }
    assert!(files(dir.path()).is_empty());
}

/// An output in the way (a folder where a later input's output goes) or a folder of `count`'s
/// outputs that is a Zarr store is found before any work: earlier outputs are not written or replaced
/// (the first input's output replaced an earlier result before the second failed, and `count`
/// put its TIFFs inside a store).
#[test]
fn outputs_in_the_way_are_found_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    raw_frame(d, "a.tif", Some(0.01));
    raw_frame(d, "b.tif", Some(0.01));
    std::fs::create_dir_all(d.join("o/b_denoised.tif")).unwrap();
    std::fs::create_dir_all(d.join("o/b_count.tif")).unwrap();
    for (out, name) in [("o/a_denoised.tif", "denoise"), ("o/a_count.tif", "count")] {
        std::fs::write(d.join(out), b"earlier").unwrap();
        let o = emccd(
            &[
                name,
                "--profile",
                "default",
                "a.tif",
                "b.tif",
                "-o",
                "o",
                "--method",
                "none",
            ][..if name == "count" { 7 } else { 9 }],
            d,
        );
        fails_with(&o, "a folder is in the way of this output");
        assert_eq!(std::fs::read(d.join(out)).unwrap(), b"earlier", "{name}");
    }
    std::fs::create_dir(d.join("s.zarr")).unwrap();
    std::fs::write(
        d.join("s.zarr/zarr.json"),
        br#"{"zarr_format":3,"node_type":"group"}"#,
    )
    .unwrap();
    // (`denoise` writes the inputs into one store there, and refuses one it did not make;
    // `count` writes one counted stack into a store.)
    fails_with(
        &emccd(
            &[
                "count",
                "--profile",
                "default",
                "a.tif",
                "b.tif",
                "-o",
                "s.zarr",
            ],
            d,
        ),
        "a .zarr output holds one counted stack: give one input",
    );
    assert_eq!(files(&d.join("s.zarr")), ["zarr.json"]);
}

/// A manifest, profile file or pairs manifest that is a device or a FIFO is refused at once
/// (`calibrate /dev/zero` filled memory, a FIFO waited forever).
#[test]
fn settings_files_that_are_devices_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let o = emccd_or_kill(&["calibrate", "/dev/zero", "-o", "p"], d);
    fails_with(&o, "a device or other special file, not a regular file");
    ok(&emccd(
        &["profile", "crop", "default", "prof", "--roi", "16x16"],
        d,
    ));
    for file in ["profile.toml", "maps.safetensors"] {
        let bad = d.join(format!("bad-{file}"));
        copy_tree(&d.join("prof"), &bad);
        std::fs::remove_file(bad.join(file)).unwrap();
        std::os::unix::fs::symlink("/dev/zero", bad.join(file)).unwrap();
        let o = emccd_or_kill(&["profile", "show", bad.to_str().unwrap()], d);
        fails_with(&o, "a device or other special file, not a regular file");
    }
    std::fs::create_dir(d.join("pairs")).unwrap();
    std::os::unix::fs::symlink("/dev/zero", d.join("pairs/pairs.toml")).unwrap();
    let o = emccd_or_kill(&["evaluate", "pairs", "--method", "input"], d);
    fails_with(&o, "a device or other special file, not a regular file");
    assert!(!d.join("p").exists());
}

/// pairs.toml names its profile relative to itself, so `evaluate` run from another folder
/// uses that profile, not one of the same name where it runs (it took the other, exit 0).
#[test]
fn pairs_name_their_profile_relative_to_themselves() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    raw_frame(d, "scene.tif", None);
    ok(&emccd(
        &["profile", "crop", "default", "P", "--roi", "32x32"],
        d,
    ));
    ok(&emccd(
        &[
            "simulate",
            "pairs",
            "--clean",
            "scene.tif",
            "--crop",
            "32x32",
            "--profile",
            "P",
            "-o",
            "pp",
        ],
        d,
    ));
    let m = std::fs::read_to_string(d.join("pp/pairs.toml")).unwrap();
    assert!(m.contains("profile = \"../P\""), "{m}");
    // Another folder with another profile called P, of another size.
    std::fs::create_dir(d.join("wd")).unwrap();
    ok(&emccd(
        &["profile", "crop", "default", "wd/P", "--roi", "48x48"],
        d,
    ));
    ok(&emccd(
        &["evaluate", "../pp", "--method", "input"],
        &d.join("wd"),
    ));
}

/// `simulate calibration --force` stopped part way leaves the acquisition it was replacing as
/// it was (half its stacks were new, and the old manifest named them), and nothing of its own.
#[test]
fn a_replacement_stopped_part_way_leaves_the_earlier_acquisition() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    small_acquisition(d, "600,1200");
    let before = files(d);
    let bytes = |f: &str| std::fs::read(d.join(f)).unwrap();
    let was: Vec<Vec<u8>> = before.iter().map(|f| bytes(f)).collect();
    let child = Command::new(env!("CARGO_BIN_EXE_emccd"))
        .args([
            "simulate",
            "calibration",
            "-o",
            "cal",
            "--force",
            "--seed",
            "7",
        ])
        .args(["--crop", "256x256", "--frames", "1000"])
        .current_dir(d)
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let staged = || {
        files(d)
            .iter()
            .any(|f| f.contains("bias_") && f.starts_with(".cal."))
    };
    let t0 = std::time::Instant::now();
    while !staged() && t0.elapsed().as_secs() < 60 {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    assert!(staged(), "the run never started writing");
    assert!(Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap()
        .success());
    let out = child.wait_with_output().unwrap();
    assert_eq!(out.status.code(), Some(130));
    assert_eq!(files(d), before);
    let now: Vec<Vec<u8>> = before.iter().map(|f| bytes(f)).collect();
    assert!(now == was, "the earlier acquisition changed");
}

/// Temporary outputs that a killed process left beside a target (SIGKILL runs no handler) are
/// removed by the next run writing that target once an hour old; a recent one, maybe a live
/// run's, stays.
#[test]
fn stale_temporary_outputs_are_swept() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    raw_frame(d, "a.tif", Some(0.01));
    // Another target's temporary (`o.tif.tif`), old too, is not this one's.
    for name in [
        ".o.tif.old111.tmp",
        ".o.tif.new111.tmp",
        ".o.tif.tif.old333.tmp",
        ".cal.old222.tmp/bias/x.tif",
    ] {
        let p = d.join(name);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(&p, b"left").unwrap();
    }
    for old in [
        ".o.tif.old111.tmp",
        ".o.tif.tif.old333.tmp",
        ".cal.old222.tmp",
    ] {
        common::age(&d.join(old));
    }
    ok(&emccd(
        &[
            "denoise",
            "--profile",
            "default",
            "a.tif",
            "-o",
            "o.tif",
            "--method",
            "none",
        ],
        d,
    ));
    ok(&emccd(
        &[
            "simulate",
            "calibration",
            "-o",
            "cal",
            "--crop",
            "16x12",
            "--frames",
            "2",
        ],
        d,
    ));
    let left: Vec<String> = files(d)
        .into_iter()
        .filter(|f| f.contains(".tmp"))
        .collect();
    assert_eq!(left, [".o.tif.new111.tmp", ".o.tif.tif.old333.tmp"]);
}

/// `simulate pairs` checks the room its pairs need before writing one (it wrote on until the
/// disk was full).
#[test]
fn simulated_pairs_check_their_room_first() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    raw_frame(d, "scene.tif", None);
    let o = emccd(
        &[
            "simulate",
            "pairs",
            "--clean",
            "scene.tif",
            "--frames",
            "100000000000",
            "-o",
            "p",
        ],
        d,
    );
    fails_with(&o, "GB free; make room, write elsewhere or ask for less");
    assert_eq!(files(d), ["scene.tif"]);
}

/// `calibrate --report` stopped while it saves writes neither the profile's folder nor a
/// report of a profile that was never written (it left an empty profile folder and a whole
/// report).
#[test]
fn a_stopped_calibration_leaves_no_report_and_no_folder() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    small_acquisition(d, "600,1200");
    // Stopped at once, and again a little later: whenever it stops, never a report of a
    // profile that is not there, nor a folder without its profile.
    for wait_ms in [0u64, 150, 400] {
        let child = Command::new(env!("CARGO_BIN_EXE_emccd"))
            .args([
                "calibrate",
                "cal/calibration.toml",
                "-o",
                "prof",
                "--report",
                "rep",
            ])
            .current_dir(d)
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(wait_ms));
        let _ = Command::new("kill")
            .args(["-TERM", &child.id().to_string()])
            .status();
        let out = child.wait_with_output().unwrap();
        let (p, r) = (
            d.join("prof/profile.toml").exists(),
            d.join("rep/index.html").exists(),
        );
        // (The profile is placed just before the report: a stop between them, a matter of
        // microseconds, leaves the profile alone, which is whole.)
        assert!(
            p || !r,
            "a report without its profile after {wait_ms} ms: {out:?}"
        );
        assert_eq!(
            d.join("prof").exists(),
            p,
            "an empty profile folder after {wait_ms} ms"
        );
        let hidden: Vec<String> = files(d)
            .into_iter()
            .filter(|f| f.contains(".tmp"))
            .collect();
        assert!(hidden.is_empty(), "{hidden:?}");
        let _ = std::fs::remove_dir_all(d.join("prof"));
        let _ = std::fs::remove_dir_all(d.join("rep"));
    }
}

/// One stack listed twice (however its path is spelled) would be an extra light level or
/// blooming exposure; a flat listed as a bias would be read noise of its shot noise: both
/// refused, naming the file, and nothing written.
#[test]
fn a_stack_listed_twice_or_a_flat_listed_as_a_bias_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    small_acquisition(d, "100,200,400,800");
    let manifest = std::fs::read_to_string(d.join("cal/calibration.toml")).unwrap();
    let write = |name: &str, from: &str, to: &str| {
        assert!(manifest.contains(from), "{from}");
        std::fs::write(d.join("cal").join(name), manifest.replace(from, to)).unwrap();
    };
    write("flat-twice.toml", "flat/flat_02.tif", "flat/flat_01.tif");
    write(
        "bloom-twice.toml",
        "blooming/bloom_0.002s.tif",
        "./blooming/../blooming/bloom_0.001s.tif",
    );
    write(
        "flat-and-bias.toml",
        "bias/bias_0.01s.tif",
        "flat/flat_01.tif",
    );
    std::fs::copy(d.join("cal/flat/flat_01.tif"), d.join("cal/bias/lit.tif")).unwrap();
    write("flat-as-bias.toml", "bias/bias_0.01s.tif", "bias/lit.tif");
    for (m, want) in [
        ("flat-twice.toml", "listed twice"),
        ("bloom-twice.toml", "listed twice"),
        ("flat-and-bias.toml", "listed twice"),
        ("flat-as-bias.toml", "holds light"),
    ] {
        fails_with(
            &emccd(&["calibrate", &format!("cal/{m}"), "-o", "p"], d),
            want,
        );
        assert!(!d.join("p").exists(), "{m}");
    }
    // The acquisition as written calibrates.
    ok(&emccd(&["calibrate", "cal/calibration.toml", "-o", "p"], d));
}

/// Two `calibrate` runs into one empty profile folder at once: one profile is placed, the other
/// run is refused (at its start or as it places its profile) instead of replacing it with exit
/// 0 (`--from-recording` places its profile the same way, `save_with_report`).
#[test]
fn concurrent_calibrations_never_replace_each_other() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    small_acquisition(d, "100,200,400");
    for (k, args) in [vec!["calibrate", "cal/calibration.toml", "-o"]]
        .into_iter()
        .enumerate()
    {
        let out = format!("p{k}");
        std::fs::create_dir(d.join(&out)).unwrap();
        for trial in 0..3 {
            let _ = std::fs::remove_file(d.join(&out).join("profile.toml"));
            let _ = std::fs::remove_file(d.join(&out).join("maps.safetensors"));
            let runs: Vec<std::process::Child> = (0..2)
                .map(|_| {
                    std::process::Command::new(env!("CARGO_BIN_EXE_emccd"))
                        .args(&args)
                        .arg(&out)
                        .current_dir(d)
                        .stdout(std::process::Stdio::null())
                        .stderr(std::process::Stdio::piped())
                        .spawn()
                        .unwrap()
                })
                .collect();
            let done: Vec<std::process::Output> = runs
                .into_iter()
                .map(|c| c.wait_with_output().unwrap())
                .collect();
            let placed = done.iter().filter(|o| o.status.success()).count();
            assert_eq!(
                placed, 1,
                "{args:?}, trial {trial}: {placed} runs placed a profile"
            );
            let refused = done.iter().find(|o| !o.status.success()).unwrap();
            let err = String::from_utf8_lossy(&refused.stderr);
            assert_eq!(refused.status.code(), Some(2), "{err}");
            assert!(err.contains("already holds"), "{err}");
            emccd_profile::CameraProfile::load(d.join(&out)).expect("the placed profile loads");
        }
    }
}

/// An output format no stack is written in is refused before any frame is denoised, with the
/// formats that are (`.png` said "unsupported: writing Png stacks").
#[test]
fn an_output_format_no_stack_is_written_in_lists_those_that_are() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    raw_frame(d, "x.tif", Some(0.01));
    for out in ["x.png", "x.jpg"] {
        fails_with(
            &emccd(
                &[
                    "denoise",
                    "x.tif",
                    "--profile",
                    "default",
                    "--method",
                    "none",
                    "-o",
                    out,
                ],
                d,
            ),
            "output must end in .tif, .tiff, .btf (BigTIFF) or .fits (or .zarr",
        );
        assert!(!d.join(out).exists());
    }
}

/// `count` on frames far below the profile's bias (an all-zero stack, a denoised float file
/// fed back in) is refused with how far below, and nothing is written (it counted them with
/// exit 0: rates at or below zero, "about −15.352 photo-electrons … the photon-counting regime").
#[test]
fn count_refuses_frames_far_below_the_bias() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    cropped_profile(d, "p32", 32, 32);
    for (name, value) in [("zeros.tif", 0.0f32), ("denoised.tif", -40.0)] {
        let frames: Vec<Vec<f32>> = (0..4)
            .map(|k| vec![value + k as f32 * 0.1; 32 * 32])
            .collect();
        write_stack(d, name, (32, 32), emccd_io::SampleFormat::F32, &frames);
        fails_with(
            &emccd(
                &[
                    "count",
                    name,
                    "--profile",
                    "p32",
                    "--exposure-s",
                    "0.01",
                    "-o",
                    "c.tif",
                ],
                d,
            ),
            "below the profile's bias on average",
        );
        assert!(!d.join("c.tif").exists(), "{name}");
    }
}
