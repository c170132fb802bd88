//! Resuming: an interrupted and resumed run reaches the same weights as an uninterrupted one.
//! Alone in its own test binary because burn's seeded initialization draws from a process-wide
//! generator that tests running in parallel would also draw from.

use emccd_nn::TrainConfig;
use emccd_train::train::{train, Image, Run, RunPaths, TrainImages};
#[path = "../../nn/tests/common/mod.rs"]
mod common;

use common::{meta, scene};
use emccd_nn::Model;

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

fn small_profile() -> emccd_profile::CameraProfile {
    emccd_profile::default_profile()
        .crop(emccd_profile::Roi::corner(64, 64))
        .unwrap()
}

#[test]
fn a_resumed_run_matches_an_uninterrupted_one() {
    let dir = tempfile::tempdir().unwrap();
    let dev = emccd_nn::cpu();
    let cfg = TrainConfig {
        steps: 4,
        batch: 2,
        crop: 32,
        warmup: 1,
        val_every: 2,
        checkpoint_every: 2,
        noise: emccd_camera::NoiseModelKind::Ours,
        ..TrainConfig::default()
    };
    let prof = small_profile();
    let paths = |name: &str| RunPaths {
        out: dir.path().join(format!("{name}.safetensors")),
        checkpoint: dir.path().join(format!("{name}.ckpt")),
    };
    let mut seen = Vec::new();
    let full = train(
        TrainImages {
            train: images(),
            val: images()[..1].to_vec(),
        },
        Run::new(&prof, cfg.clone(), meta(4, 2), &paths("full"), &dev),
        &mut |r| {
            seen.push((r.step, r.loss, r.val_psnr));
            true
        },
    )
    .unwrap();
    assert_eq!(full.meta.steps, 4);
    // The file records the run's configuration, typed.
    let saved = Model::load(&paths("full").out, &emccd_nn::cpu()).unwrap();
    assert_eq!(saved.meta.train.as_ref(), Some(&cfg));
    assert!(seen.iter().all(|s| s.1.is_finite()) && seen.last().unwrap().2.is_some());
    // Interrupted after 2 steps (the checkpoint at step 2), then resumed to 4.
    let p = paths("split");
    train(
        TrainImages {
            train: images(),
            val: images()[..1].to_vec(),
        },
        Run::new(&prof, cfg.clone(), meta(4, 2), &p, &dev),
        &mut |r| r.step < 2,
    )
    .unwrap();
    assert!(!p.out.exists(), "an interrupted run writes no final model");
    let resumed = train(
        TrainImages {
            train: images(),
            val: images()[..1].to_vec(),
        },
        Run::new(&prof, cfg, meta(4, 2), &p, &dev).resuming(true),
        &mut |_| true,
    )
    .unwrap();
    assert_eq!(resumed.meta.steps, 4);
    let x = common::scene_input(32, 32, &dev);
    let a: Vec<f32> = Model::load(&paths("full").out, &dev)
        .unwrap()
        .net
        .forward(x.clone())
        .into_data()
        .try_into_vec::<f32>()
        .unwrap();
    let b: Vec<f32> = Model::load(&p.out, &dev)
        .unwrap()
        .net
        .forward(x)
        .into_data()
        .try_into_vec::<f32>()
        .unwrap();
    let diff = a
        .iter()
        .zip(&b)
        .map(|(x, y)| (x - y).abs())
        .fold(0f32, f32::max);
    assert!(
        diff < 1e-5,
        "resumed and uninterrupted runs differ by {diff}"
    );
}
