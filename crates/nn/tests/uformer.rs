//! The Uformer: parameter counts of the paper's three sizes, any frame size through padding
//! and tiling, and model files that carry its configuration.

use burn::module::Module;
use emccd_nn::tile::Tiling;
use emccd_nn::{Arch, Model, ModelMeta, UformerConfig};
mod common;

fn meta(cfg: UformerConfig) -> ModelMeta {
    ModelMeta {
        arch: Arch::Uformer(cfg),
        ..common::meta(8, 2)
    }
}

#[test]
fn parameter_counts_match_the_paper() {
    let dev = emccd_nn::cpu();
    // Exact counts follow from the reference implementation's layer shapes with a 2-channel
    // input (frame, noise level) and a 1-channel output; the paper quotes 5.3 / 20.7 / 50.9 M.
    for (cfg, exact, paper) in [
        (UformerConfig::T, 5_291_131usize, 5.3e6),
        (UformerConfig::S, 20_749_755, 20.7e6),
        (UformerConfig::B, 50_879_504, 50.9e6),
    ] {
        let n = cfg.init(&dev).num_params();
        assert_eq!(n, exact, "{cfg:?}");
        // The paper rounds to 0.1 M: within half of that.
        assert!((n as f64 - paper).abs() <= 0.05e6, "{n} vs {paper}");
    }
}

#[test]
fn any_frame_size_runs_and_tiles_without_seams() {
    let dev = emccd_nn::cpu();
    let cfg = UformerConfig {
        embed: 8,
        depths: [1, 1, 1, 1, 2, 1, 1, 1, 1],
        ..UformerConfig::T
    };
    let m = Model::new(meta(cfg), &dev).unwrap();
    assert_eq!(m.meta.multiple(), 128);
    let (w, h) = (300, 200);
    let (whole, rel) = common::tiling_mismatch(
        &m.net,
        w,
        h,
        128,
        Tiling {
            tile: 256,
            overlap: 96,
        },
        32,
    );
    assert_eq!(whole.len(), w * h);
    assert!(whole.iter().all(|v| v.is_finite()));
    assert!(
        rel < 0.1,
        "tiled vs untiled correction differs by {rel:.3} (relative rms)"
    );
}

#[test]
fn uformer_model_files_round_trip() {
    let dev = emccd_nn::cpu();
    let cfg = UformerConfig {
        embed: 8,
        depths: [1; 9],
        ..UformerConfig::T
    };
    let m = Model::new(meta(cfg), &dev).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("u.safetensors");
    m.save(&p).unwrap();
    let back = Model::load(&p, &dev).unwrap();
    assert_eq!(back.meta, m.meta);
    let x = common::scene_input(128, 128, &dev);
    let a: Vec<f32> = m
        .net
        .forward(x.clone())
        .into_data()
        .try_into_vec::<f32>()
        .unwrap();
    let b: Vec<f32> = back
        .net
        .forward(x)
        .into_data()
        .try_into_vec::<f32>()
        .unwrap();
    assert_eq!(a, b);
    // Metadata that names an architecture without its configuration is refused, not guessed.
    let mut json = serde_json::to_value(&m.meta).unwrap();
    assert_eq!(json["arch"], "uformer"); // a Uformer of no preset size
    json.as_object_mut().unwrap().remove("uformer");
    let e = serde_json::from_value::<ModelMeta>(json)
        .unwrap_err()
        .to_string();
    assert!(e.contains("not its configuration"), "{e}");
}
