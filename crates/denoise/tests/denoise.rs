//! The product's front door against the libraries under it: every bundled model loads by
//! name, `blend` is the average it says it is, and stacks are denoised in shards with the
//! provenance of what ran.

#[path = "../../nn/tests/common/mod.rs"]
mod common;

use emccd_nn::Model;

/// Every bundled model is in `models/`, loads by name, and is the kind its method runs: the
/// `hybrid` model a refinement network, `movie` a temporal network, the others denoisers.
#[test]
fn every_bundled_model_loads_by_name() {
    for b in emccd_denoise::bundled::BUNDLED {
        let m = emccd_denoise::bundled::load(b.name, &emccd_nn::cpu())
            .unwrap_or_else(|e| panic!("{}: {e}", b.name));
        let want = match b.name {
            "hybrid" => emccd_nn::Inputs::Hybrid,
            "movie" => emccd_nn::Inputs::Movie,
            _ => emccd_nn::Inputs::Noisy,
        };
        assert_eq!(m.meta.inputs, want, "{}", b.name);
        assert!(m.meta.steps > 0, "{}: an untrained model", b.name);
    }
}

/// `blend` is the pixel average of `ivst` and the network on the same frame, and takes the
/// bundled `lowlight` network when no model is named; it is the default method.
#[test]
fn blend_averages_ivst_and_the_network() {
    use emccd_denoise::{resolve, Denoiser, Method, DEFAULT_METHOD};
    assert_eq!(DEFAULT_METHOD, Method::Blend);
    let r = resolve(None, None, |name| {
        assert_eq!(name, "lowlight");
        emccd_denoise::bundled::load(name, &emccd_nn::cpu())
    })
    .unwrap();
    assert_eq!(r.method, Method::Blend);
    assert!(r.model.is_some());
    // What provenance names (and hashes) is the model that ran, not another default.
    assert_eq!(r.model_name.as_deref(), Some("lowlight"));
    let profile = emccd_profile::default_profile()
        .crop(emccd_profile::Roi::corner(48, 40))
        .unwrap();
    let net = Model::new(common::meta(4, 2), &emccd_nn::cpu()).unwrap();
    let raw: Vec<f32> = (0..48 * 40)
        .map(|i| 500.0 + ((i * 7919) % 97) as f32 * 3.0)
        .collect();
    let run = |method, model| {
        Denoiser {
            profile: &profile,
            method,
            model,
            tiling: Default::default(),
            ensemble: 1,
            units: emccd_denoise::Units::Dn,
            window: 0,
        }
        .run(&raw, 0.01)
        .unwrap()
    };
    let b = run(Method::Blend, Some(&net));
    let n = run(Method::Net, Some(&net));
    let i = run(Method::Ivst, None);
    for k in 0..b.len() {
        let want = 0.5 * (n[k] + i[k]);
        assert!(
            (b[k] - want).abs() <= 1e-4 * want.abs().max(1.0),
            "pixel {k}"
        );
    }
}

/// A stack of two files denoised into a Zarr store in shares: a share across the files' boundary
/// writes only its frames, a later run skips what is done and writes the rest, and the frames
/// are what `Denoiser::run` gives; a share past the end, a store of another size and a file
/// shorter than its header are errors naming what is wrong; the provenance hashes the model
/// that runs (`blend` without a model: `lowlight`).
#[test]
fn a_stack_is_denoised_in_shards_with_the_model_it_ran_in_its_provenance() {
    use emccd_denoise::{resolve, Denoiser, Method, Units};
    use emccd_io::zarr::{ZarrStackSpec, ZarrStackWriter};
    let load = |m: &str| emccd_denoise::bundled::load(m, &emccd_nn::cpu());
    use emccd_denoise::stack::{denoise_shard, provenance, ShardRun};
    use emccd_profile::Recording;

    let (w, h) = (48, 40);
    let profile = emccd_profile::default_profile()
        .crop(emccd_profile::Roi::corner(w, h))
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let raws: Vec<Vec<f32>> = (0..5)
        .map(|k| {
            (0..w * h)
                .map(|i| (500 + (i * 7919 + k * 104729) % 97 * 3) as f32)
                .collect()
        })
        .collect();
    // a.tif holds frames 0–1 of the stack, b.tif frames 2–4.
    let files = [("a.tif", &raws[..2]), ("b.tif", &raws[2..])];
    for (name, frames) in files {
        let mut wr = emccd_io::StackWriter::create(
            dir.path().join(name),
            w,
            h,
            emccd_io::SampleFormat::U16,
            Some(frames.len()),
        )
        .unwrap();
        wr.set_metadata(&emccd_io::Metadata {
            exposure_s: Some(0.01),
            ..Default::default()
        });
        for f in frames {
            wr.write_frame(f).unwrap();
        }
        wr.finish().unwrap();
    }
    let open = |name: &str| {
        Recording::open(
            &dir.path().join(name),
            &profile,
            None,
            "--exposure-s",
            false,
        )
        .unwrap()
    };
    let both = || vec![open("a.tif"), open("b.tif")];

    let r = resolve(None, None, load).unwrap();
    let blend = Denoiser {
        profile: &profile,
        method: r.method,
        model: r.model.as_ref(),
        tiling: Default::default(),
        ensemble: 1,
        units: Units::Dn,
        window: 0,
    };
    let p = provenance(&blend, r.model_name.as_deref(), &both(), "emccd test").unwrap();
    // The built-in model's hash is its file's in the repository.
    let lowlight = emccd_io::content_hash(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../models/lowlight-unet.safetensors"),
    )
    .unwrap();
    assert_eq!(p["model_hash"], format!("{lowlight:016x}"));
    assert_eq!(p["method"], "blend");
    assert_eq!(
        (
            p["inputs"][0]["frames"].as_u64(),
            p["inputs"][1]["frames"].as_u64()
        ),
        (Some(2), Some(3))
    );

    let fd = Denoiser {
        method: Method::None,
        model: None,
        ..blend
    };
    let spec = ZarrStackSpec {
        width: w,
        height: h,
        frames: 5,
        name: "t".into(),
        provenance: provenance(&fd, None, &both(), "emccd test").unwrap(),
        notes: serde_json::Value::Null,
    };
    let out = dir.path().join("out.zarr");
    let (store, created) = ZarrStackWriter::create_or_open(&out, &spec).unwrap();
    assert!(created);
    let mut calls = 0;
    let first = denoise_shard(&fd, both(), &store, 1..4, &mut || calls += 1).unwrap();
    assert_eq!(
        (first, calls),
        (
            ShardRun {
                written: 3,
                skipped: 0
            },
            3
        )
    );
    assert_eq!(store.done_count(), 3);
    let e = denoise_shard(&fd, both(), &store, 3..6, &mut || ())
        .unwrap_err()
        .to_string();
    assert!(e.contains("frames 4–6 asked of a stack of 5"), "{e}");
    let e = denoise_shard(&fd, vec![open("b.tif")], &store, 0..3, &mut || ())
        .unwrap_err()
        .to_string();
    assert!(e.contains("the store holds 5 frames"), "{e}");
    let rest = denoise_shard(&fd, both(), &store, 0..5, &mut || ()).unwrap();
    assert_eq!(
        rest,
        ShardRun {
            written: 2,
            skipped: 3
        }
    );
    drop(store);
    let (_, frames) = emccd_io::read_all(&out).unwrap();
    for (k, (got, raw)) in frames.iter().zip(&raws).enumerate() {
        assert_eq!(got, &fd.run(raw, 0.01).unwrap(), "frame {k}");
    }

    // b.tif ends after 3 frames although its header (here: its StackInfo) promises 4.
    let mut short = open("b.tif");
    short.info.frames = 4;
    let spec = ZarrStackSpec { frames: 6, ..spec };
    let (store, _) =
        ZarrStackWriter::create_or_open(&dir.path().join("short.zarr"), &spec).unwrap();
    let e = denoise_shard(&fd, vec![open("a.tif"), short], &store, 0..6, &mut || ())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("b.tif: frame 4: the file ended before it"),
        "{e}"
    );
    assert_eq!(store.done_count(), 5);
}
