//! OME-Zarr output and sharded denoising end to end: shards together equal one process bit for
//! bit, a killed shard resumes, a store made for other work is refused, and the stores open in
//! zarr-python and ome-zarr (installed by `.ci/run`; `EMCCD_REQUIRE_PYTHON=1` turns a missing
//! reader into a failure).

mod common;

use std::path::Path;
use std::process::Command;

use common::{age, emccd, ok};

const N: usize = 64;

/// A 64×64 region of the default camera and a 12-frame raw stack of it in two files (5 + 7
/// frames), values as the camera records them.
fn setup(d: &Path) {
    let p = emccd_profile::default_profile()
        .crop(emccd_profile::Roi::corner(N, N))
        .unwrap();
    p.save(d.join("prof")).unwrap();
    let slope = p.slope().unwrap() as f32;
    let mut fpn = vec![0f32; p.len()];
    p.fpn_at(0.01, &mut fpn);
    let model = emccd_camera::PgnModel::from_profile(&p, 0.01).unwrap();
    let mut k = 0u64;
    for (name, frames) in [("a.tif", 5), ("b.tif", 7)] {
        let mut w =
            emccd_io::StackWriter::create(d.join(name), N, N, emccd_io::SampleFormat::U16, None)
                .unwrap();
        for _ in 0..frames {
            let clean: Vec<f32> = (0..N * N)
                .map(|i| (2.0 + 1.5 * ((i % N) as f32 / 7.0 + k as f32).sin()) * slope / 2.0)
                .collect();
            let mut noisy = vec![0f32; clean.len()];
            emccd_camera::NoiseModel::synthesize(&model, &clean, N, &mut noisy, 100 + k);
            let raw: Vec<f32> = noisy
                .iter()
                .zip(&fpn)
                .map(|(n, f)| (n + f).round())
                .collect();
            w.write_frame(&raw).unwrap();
            k += 1;
        }
        w.finish().unwrap();
    }
}

/// `emccd denoise a.tif b.tif` with `--method bm3d` unless `extra` names another.
fn denoise(d: &Path, out: &str, extra: &[&str]) -> std::process::Output {
    let method = if extra.contains(&"--method") {
        &[][..]
    } else {
        &["--method", "bm3d"][..]
    };
    let mut args = vec![
        "denoise",
        "a.tif",
        "b.tif",
        "--profile",
        "prof",
        "--exposure-s",
        "0.01",
        "-o",
        out,
    ];
    args.extend_from_slice(method);
    args.extend_from_slice(extra);
    emccd(&args, d)
}

fn frames(path: &Path) -> Vec<Vec<f32>> {
    emccd_io::read_all(path).unwrap().1
}

fn bits(f: &[Vec<f32>]) -> Vec<u32> {
    f.iter().flatten().map(|v| v.to_bits()).collect()
}

#[test]
fn shards_equal_one_process_and_a_killed_shard_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    setup(d);
    // One process, to a Zarr store and (per input) to TIFF: the same numbers.
    ok(&denoise(d, "one.zarr", &[]));
    let one = frames(&d.join("one.zarr"));
    assert_eq!(one.len(), 12);
    ok(&emccd(
        &[
            "denoise",
            "a.tif",
            "--profile",
            "prof",
            "--exposure-s",
            "0.01",
            "--method",
            "bm3d",
            "-o",
            "a.tif.out.tif",
        ],
        d,
    ));
    assert_eq!(bits(&frames(&d.join("a.tif.out.tif"))), bits(&one[..5]));

    // Three shards, the last run first; until all have run the store says so and the missing
    // frames are refused by name, not read as data.
    for s in ["2/3", "0/3"] {
        let o = denoise(d, "sh.zarr", &["--shard", s]);
        ok(&o);
        assert!(
            String::from_utf8_lossy(&o.stderr).contains("the other shards write the rest"),
            "{}",
            String::from_utf8_lossy(&o.stderr)
        );
    }
    let info = ok(&emccd(&["info", "sh.zarr"], d));
    assert!(info.contains("8 of 12 frames written"), "{info}");
    let e = emccd_io::read_all(d.join("sh.zarr"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("frame 5 is not written yet"), "{e}");
    ok(&denoise(d, "sh.zarr", &["--shard", "1/3"]));
    assert_eq!(bits(&frames(&d.join("sh.zarr"))), bits(&one));

    // A shard killed mid-frame leaves a chunk without its marker (here: a truncated chunk, the
    // marker gone); running it again rewrites just that frame.
    let chunk = d.join("sh.zarr/0/c/5/0/0");
    std::fs::write(&chunk, b"half").unwrap();
    std::fs::remove_file(d.join("sh.zarr/0/.emccd-done/5")).unwrap();
    let o = denoise(d, "sh.zarr", &["--shard", "1/3"]);
    ok(&o);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("frames 5–8 (1 denoised now, 3 were already done)"),
        "{err}"
    );
    assert_eq!(bits(&frames(&d.join("sh.zarr"))), bits(&one));

    // A marker is not trusted alone: a chunk deleted, or cut short, under its marker is
    // written again, and files in the marker folder that name no frame are not counted (these
    // said "12 of 12 frames complete" and "14 of 12" and left the frames unwritten).
    std::fs::remove_file(d.join("sh.zarr/0/c/6/0/0")).unwrap();
    // Read meanwhile, the frame is said to be missing, not "a non-finite value at (0, 0)".
    let e = emccd_io::read_all(d.join("sh.zarr"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("frame 7: its data is missing from the store (no chunk 0/c/6/0/0)"),
        "{e}"
    );
    std::fs::write(d.join("sh.zarr/0/c/7/0/0"), b"half").unwrap();
    for stray in ["12", "x"] {
        std::fs::write(d.join("sh.zarr/0/.emccd-done").join(stray), b"").unwrap();
    }
    let o = denoise(d, "sh.zarr", &["--shard", "1/3"]);
    ok(&o);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("frames 5–8 (2 denoised now, 2 were already done); 12 of 12 frames"),
        "{err}"
    );
    let info = ok(&emccd(&["info", "sh.zarr"], d));
    assert!(!info.contains("frames written"), "{info}");
    assert_eq!(bits(&frames(&d.join("sh.zarr"))), bits(&one));

    // A store made for other work is refused, saying what differs, and left as it was.
    let before = std::fs::read(d.join("sh.zarr/zarr.json")).unwrap();
    let o = denoise(d, "sh.zarr", &["--method", "none"]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("a store made for other work")
            && err.contains("method: \"bm3d\" in the store, \"none\" asked"),
        "{err}"
    );
    assert_eq!(std::fs::read(d.join("sh.zarr/zarr.json")).unwrap(), before);
    assert_eq!(bits(&frames(&d.join("sh.zarr"))), bits(&one));

    // The same input spelled another way is the same input; an input rewritten between two
    // shards is another one, and its store is refused rather than mixed.
    ok(&emccd(
        &[
            "denoise",
            "./a.tif",
            "b.tif",
            "--profile",
            "./prof",
            "--exposure-s",
            "0.01",
            "--method",
            "bm3d",
            "-o",
            "sh.zarr",
            "--shard",
            "0/3",
        ],
        d,
    ));
    let bytes = std::fs::read(d.join("a.tif")).unwrap();
    std::thread::sleep(std::time::Duration::from_millis(20));
    std::fs::write(d.join("a.tif"), &bytes).unwrap();
    let o = denoise(d, "sh.zarr", &["--shard", "1/3"]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("inputs[0].modified_ns"), "{err}");

    // --method none: the preprocessed photo-signal, the same as what BM3D starts from.
    ok(&denoise(d, "pre.zarr", &["--method", "none"]));
    let pre = frames(&d.join("pre.zarr"));
    let raw = frames(&d.join("a.tif"));
    let p = emccd_profile::CameraProfile::load(d.join("prof")).unwrap();
    let want = emccd_classical::frame::preprocess(&p, &raw[0], 0.01).unwrap();
    assert_eq!(bits(&pre[..1]), bits(&[want]));
}

/// The names in folder `path`, sorted.
fn names(path: &Path) -> Vec<String> {
    let mut n: Vec<String> = std::fs::read_dir(path)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    n.sort();
    n
}

/// The writer's bookkeeping (completion markers, staging) lives in the array's folder, where
/// Zarr readers do not list it (in the group's folder zarr-python warns of it on every
/// listing); a finished store holds nothing else; what killed processes left (a staging
/// folder, a store's temporary folder beside it) is removed by a later run once stale, and a
/// store of the earlier layout is resumed.
#[test]
fn bookkeeping_stays_out_of_readers_way() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    setup(d);
    ok(&denoise(
        d,
        "s.zarr",
        &["--method", "none", "--shard", "0/2"],
    ));
    assert_eq!(names(&d.join("s.zarr")), ["0", "zarr.json"]);
    assert_eq!(
        names(&d.join("s.zarr/0")),
        [".emccd-done", "c", "zarr.json"]
    );

    // A writer killed long ago left its staging folder; a live one is staging now; a process
    // killed while it built another store left that store's temporary folder.
    let staging = d.join("s.zarr/0/.emccd-staging");
    for w in ["wkilled", "wlive"] {
        std::fs::create_dir_all(staging.join(w).join("0/c/3/0")).unwrap();
        std::fs::write(staging.join(w).join("0/c/3/0/0"), b"part").unwrap();
    }
    age(&staging.join("wkilled"));
    std::fs::create_dir_all(d.join(".t.zarr.x1y2z3.tmp/0")).unwrap();
    age(&d.join(".t.zarr.x1y2z3.tmp"));
    ok(&denoise(
        d,
        "s.zarr",
        &["--method", "none", "--shard", "1/2"],
    ));
    assert_eq!(names(&staging), ["wlive"]);
    std::fs::remove_dir_all(&staging).unwrap();
    ok(&denoise(d, "t.zarr", &["--method", "none"]));
    assert!(!d.join(".t.zarr.x1y2z3.tmp").exists());

    // A store whose markers are at its top (written before they moved): resumed, and moved.
    let want = bits(&frames(&d.join("s.zarr")));
    std::fs::rename(d.join("s.zarr/0/.emccd-done"), d.join("s.zarr/.emccd-done")).unwrap();
    std::fs::remove_file(d.join("s.zarr/.emccd-done/2")).unwrap();
    let o = denoise(d, "s.zarr", &["--method", "none"]);
    ok(&o);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("1 denoised now, 11 were already done"),
        "{err}"
    );
    assert_eq!(names(&d.join("s.zarr")), ["0", "zarr.json"]);
    assert_eq!(bits(&frames(&d.join("s.zarr"))), want);
}

#[test]
fn shard_and_zarr_mistakes_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    setup(d);
    let fails = |o: std::process::Output, what: &str| {
        assert!(!o.status.success());
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(what), "{err}");
    };
    fails(
        denoise(d, "x.tif", &["--shard", "0/2"]),
        "--shard needs a .zarr output",
    );
    fails(denoise(d, "x.zarr", &["--shard", "2/2"]), "0 ≤ I < N");
    fails(denoise(d, "x.zarr", &["--shard", "1"]), "a shard is I/N");
    assert!(!d.join("x.zarr").exists() && !d.join("x.tif").exists());
    // An existing folder that is not a store is not written into.
    std::fs::create_dir(d.join("plain.zarr")).unwrap();
    std::fs::write(d.join("plain.zarr/notes.txt"), "mine").unwrap();
    fails(denoise(d, "plain.zarr", &[]), "is not a Zarr store");
    assert_eq!(std::fs::read_dir(d.join("plain.zarr")).unwrap().count(), 1);
    // A store as input: the input is never the output.
    ok(&denoise(d, "in.zarr", &["--method", "none"]));
    fails(
        emccd(
            &[
                "denoise",
                "in.zarr",
                "--profile",
                "prof",
                "--exposure-s",
                "0.01",
                "-o",
                "in.zarr",
            ],
            d,
        ),
        "the output is the input",
    );
    // A folder that is not a store, as input.
    fails(emccd(&["info", "plain.zarr"], d), "not a Zarr store");
}

/// Several processes that start at once: exactly one creates the store, all write into it.
#[test]
fn concurrent_writers_share_one_store() {
    use emccd_io::zarr::{ZarrStackSpec, ZarrStackWriter};
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("race.zarr");
    let spec = ZarrStackSpec {
        width: 16,
        height: 8,
        frames: 8,
        name: "race".into(),
        provenance: serde_json::json!({"run": 1}),
        notes: serde_json::json!(null),
    };
    let created: Vec<bool> = std::thread::scope(|s| {
        let hs: Vec<_> = (0..8)
            .map(|k| {
                let (path, spec) = (&path, &spec);
                s.spawn(move || {
                    let (w, created) = ZarrStackWriter::create_or_open(path, spec).unwrap();
                    w.write_frame(k, &vec![k as f32; 16 * 8]).unwrap();
                    created
                })
            })
            .collect();
        hs.into_iter().map(|h| h.join().unwrap()).collect()
    });
    assert_eq!(created.iter().filter(|&&c| c).count(), 1, "{created:?}");
    let f = frames(&path);
    assert!(f
        .iter()
        .enumerate()
        .all(|(k, v)| v.iter().all(|&x| x == k as f32)));
    // No temporary folder is left beside the store.
    let names: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, ["race.zarr"]);
    let other = ZarrStackSpec {
        provenance: serde_json::json!({"run": 2}),
        ..spec
    };
    let e = ZarrStackWriter::create_or_open(&path, &other)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("run: 1 in the store, 2 asked"), "{e}");
}

/// zarr-python and ome-zarr read what `denoise` wrote (data, axes, provenance), and emccd reads
/// stores they wrote: OME-NGFF 0.4 on Zarr v2 and a bare Zarr v3 array of 4 dimensions.
#[test]
fn python_readers_and_writers_agree() {
    let have = Command::new("python3")
        .args(["-c", "import numpy, zarr, ome_zarr, tifffile"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !have {
        assert!(
            std::env::var_os("EMCCD_REQUIRE_PYTHON").is_none(),
            "python3 with numpy, zarr, ome-zarr and tifffile is required (EMCCD_REQUIRE_PYTHON is set)"
        );
        eprintln!("skipped: python3 with zarr and ome-zarr is not installed");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    setup(d);
    ok(&denoise(d, "out.zarr", &["--method", "none"]));
    ok(&denoise(d, "tifs", &["--method", "none"]));
    const SCRIPT: &str = r#"
import json, warnings, numpy as np, tifffile, zarr
# Listing and consolidating the store warn of nothing (zarr-python warned of every entry of
# the group's folder that is not a Zarr node); only zarr's own note that consolidated metadata
# is not in the v3 specification is let through.
with warnings.catch_warnings():
    warnings.simplefilter("error")
    warnings.filterwarnings("ignore", message="Consolidated metadata")
    g = zarr.open_group("out.zarr", mode="r")
    assert list(g.keys()) == ["0"] and [k for k, _ in g.members()] == ["0"], list(g.keys())
    import shutil; shutil.copytree("out.zarr", "copy.zarr")
    zarr.consolidate_metadata("copy.zarr")
from ome_zarr.io import parse_url
from ome_zarr.reader import Reader
g = zarr.open_group("out.zarr", mode="r")
a = g["0"][:]
want = np.concatenate([tifffile.imread("tifs/a_denoised.tif"), tifffile.imread("tifs/b_denoised.tif")])
assert a.dtype == np.float32 and a.shape == (12, 64, 64), (a.dtype, a.shape)
assert np.array_equal(a, want), "zarr-python reads other values than the TIFF outputs"
prov = dict(g.attrs)["emccd"]
assert prov["method"] == "none" and [i["frames"] for i in prov["inputs"]] == [5, 7], prov
node = list(Reader(parse_url("out.zarr"))())[0]
axes = [x["name"] for x in node.metadata["axes"]]
assert axes == ["t", "y", "x"], axes
assert np.array_equal(np.asarray(node.data[0]), want)
# Stores others write: OME-NGFF 0.4 (Zarr v2) by ome-zarr, and a bare Zarr v3 array (t, c, y, x).
from ome_zarr.writer import write_image
root = zarr.open_group(parse_url("v2.zarr", mode="w").store, mode="w", zarr_format=2)
write_image((np.arange(3 * 20 * 30) % 1000).reshape(3, 20, 30).astype(np.uint16), group=root,
            axes="tyx", scaler=None)
z = zarr.create_array("v3.zarr", shape=(2, 3, 20, 30), chunks=(1, 1, 20, 30), dtype="float64")
z[:] = np.arange(2 * 3 * 20 * 30).reshape(2, 3, 20, 30) * 0.5
print("ok")
"#;
    let o = Command::new("python3")
        .arg("-c")
        .arg(SCRIPT)
        .current_dir(d)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    let (info, f) = emccd_io::read_all(d.join("v2.zarr")).unwrap();
    assert_eq!((info.width, info.height, info.frames), (30, 20, 3));
    assert_eq!(info.pixel_type, emccd_io::PixelType::U16);
    assert!(f
        .concat()
        .iter()
        .enumerate()
        .all(|(i, &v)| v == (i % 1000) as f32));
    let (info, f) = emccd_io::read_all(d.join("v3.zarr")).unwrap();
    assert_eq!((info.width, info.height, info.frames), (30, 20, 6));
    assert!(f
        .concat()
        .iter()
        .enumerate()
        .all(|(i, &v)| v == i as f32 * 0.5));
    let json = ok(&emccd(&["info", "--json", "v2.zarr"], d));
    assert!(json.contains("\"format\": \"zarr\""), "{json}");
}

/// A store that one process began and could not finish because an input frame is at fault (a
/// NaN in the middle of the stack) is removed (it stayed, half written, and a rerun stopped at
/// the same frame); a shard's store, which other processes fill too, stays.
#[test]
fn a_store_begun_alone_and_failed_is_removed() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    setup(d);
    let (_, mut f) = emccd_io::read_all(d.join("b.tif")).unwrap();
    f[1][100] = f32::NAN;
    // Written by the tiff crate: emccd's own writer refuses a NaN.
    let file = std::fs::File::create(d.join("nan.tif")).unwrap();
    let mut enc = tiff::encoder::TiffEncoder::new(file).unwrap();
    for frame in &f {
        enc.write_image::<tiff::encoder::colortype::Gray32Float>(N as u32, N as u32, frame)
            .unwrap();
    }
    for method in ["bm3d", "temporal"] {
        let args = [
            "denoise",
            "nan.tif",
            "--profile",
            "prof",
            "--exposure-s",
            "0.01",
            "--method",
            method,
            "-o",
            "n.zarr",
        ];
        let o = emccd(&args, d);
        assert_eq!(o.status.code(), Some(2));
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("frame 2"), "{err}");
        assert!(!d.join("n.zarr").exists(), "{method}");
        let o = emccd(&[&args[..], &["--shard", "0/1"][..]].concat(), d);
        assert_eq!(o.status.code(), Some(2));
    }
    let o = emccd(
        &[
            "denoise",
            "nan.tif",
            "--profile",
            "prof",
            "--exposure-s",
            "0.01",
            "--method",
            "bm3d",
            "-o",
            "s.zarr",
            "--shard",
            "0/2",
        ],
        d,
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(d.join("s.zarr/zarr.json").is_file());
}
