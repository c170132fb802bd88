//! Learning: a small fixed-seed run in the low-light recipe lowers its loss. In its own test
//! binary because burn's seeded initialization draws from a process-wide generator.

use emccd_nn::TrainConfig;
use emccd_train::train::{train, Image, Run, RunPaths, TrainImages};
#[path = "../../nn/tests/common/mod.rs"]
mod common;

use common::{meta, scene};

fn images() -> Vec<Image> {
    (0..3)
        .map(|k| Image {
            width: 48,
            height: 40,
            data: scene(48, 40)
                .into_iter()
                .map(|v| (v * (0.6 + 0.2 * k as f32)).min(1.0))
                .collect(),
        })
        .collect()
}

/// A small fixed-seed run in the low-light recipe (exact EMCCD chain, mean 1–16 photoelectrons,
/// L2 loss) learns: its smoothed loss ends well below the first batch's. The untrained network
/// passes the noise through, so the first loss is the noise power; smoothing alone removes
/// much of it.
#[test]
fn a_low_light_training_run_lowers_its_loss() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = TrainConfig {
        steps: 100,
        batch: 4,
        crop: 32,
        lr: 2e-3,
        warmup: 5,
        noise: emccd_camera::NoiseModelKind::Pgn,
        mean_electrons: Some([1.0, 16.0]),
        cic_e: Some([0.0, 0.05]),
        loss: emccd_nn::Loss::L2,
        val_every: 100,
        checkpoint_every: 100,
        seed: 11,
        ..TrainConfig::default()
    };
    let paths = RunPaths {
        out: dir.path().join("l.safetensors"),
        checkpoint: dir.path().join("l.ckpt"),
    };
    let mut losses = Vec::new();
    train(
        TrainImages {
            train: images(),
            val: Vec::new(),
        },
        Run::new(
            &emccd_profile::default_profile()
                .crop(emccd_profile::Roi::corner(64, 64))
                .unwrap(),
            cfg,
            meta(8, 2),
            &paths,
            &emccd_nn::cpu(),
        ),
        &mut |r| {
            losses.push(r.loss);
            true
        },
    )
    .unwrap();
    let (first, last) = (losses[0], *losses.last().unwrap());
    assert!(last < 0.7 * first, "smoothed loss {first:.5} → {last:.5}");
    // The model says what it was trained with (its metadata said `ours`), and its record of
    // the run repeats that instead of contradicting it.
    let saved = emccd_nn::Model::read_meta(&paths.out).unwrap();
    let run = saved.train.as_ref().expect("the run is recorded");
    assert_eq!(saved.noise_model, emccd_camera::NoiseModelKind::Pgn);
    assert_eq!(
        (run.noise, run.ablate, run.scale, run.base),
        (saved.noise_model, saved.ablate, saved.scale, saved.base)
    );
}

/// Moving the bundled hybrid onto the iterative base (`train --init hybrid --hybrid-base ivst`)
/// starts at the identity on that base and then learns: after a few steps its output layer is
/// no longer zero. (A zeroed layer that lost its trainable mark stayed zero for good.)
#[test]
fn a_hybrid_moved_onto_another_base_learns_again() {
    use emccd_nn::{Model, ModelMeta, TrainConfig};
    use emccd_train::train::{train, Image, Run, RunPaths, TrainImages};
    let dir = tempfile::tempdir().unwrap();
    let bundled = common::bundled("hybrid");
    let cfg = TrainConfig {
        steps: 3,
        batch: 2,
        crop: 32,
        lr: 1e-3,
        warmup: 1,
        noise: emccd_camera::NoiseModelKind::Pgn,
        mean_electrons: Some([1.0, 4.0]),
        base: emccd_nn::Classical::Ivst,
        val_every: 100,
        checkpoint_every: 100,
        seed: 5,
        ..TrainConfig::default()
    };
    let start = Model::load(&bundled, &emccd_nn::cpu()).unwrap();
    let meta = ModelMeta {
        base: emccd_nn::Classical::Ivst,
        ..start.meta.clone()
    };
    let paths = RunPaths {
        out: dir.path().join("h.safetensors"),
        checkpoint: dir.path().join("h.ckpt"),
    };
    let images = vec![Image {
        width: 48,
        height: 40,
        data: scene(48, 40),
    }];
    let m = train(
        TrainImages {
            train: images,
            val: Vec::new(),
        },
        Run::new(
            &emccd_profile::default_profile()
                .crop(emccd_profile::Roi::corner(64, 64))
                .unwrap(),
            cfg,
            meta,
            &paths,
            &emccd_nn::cpu(),
        )
        .with_init(Some(&emccd_nn::ModelSource::File(bundled.clone()))),
        &mut |_| true,
    )
    .unwrap();
    assert_eq!(m.meta.base, emccd_nn::Classical::Ivst);
    // The output layer's weights: read back from the saved file.
    let bytes = std::fs::read(&paths.out).unwrap();
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let w = st.tensor("out.weight").unwrap();
    let v: Vec<f32> = w
        .data()
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    assert!(v.iter().any(|&x| x != 0.0), "the output layer stayed zero");
}
