//! Learning: a small fixed-seed run in the low-light recipe lowers its loss. In its own test
//! binary because burn's seeded initialization draws from a process-wide generator.

use emccd_nn::train::{train, Image, Run, RunPaths, TrainConfig, TrainImages};
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
        loss: emccd_nn::train::Loss::L2,
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
    let saved = emccd_nn::Denoiser::read_meta(&paths.out).unwrap();
    let run = saved.train.as_ref().expect("the run is recorded");
    assert_eq!(saved.noise_model, emccd_camera::NoiseModelKind::Pgn);
    assert_eq!(
        (run.noise, run.ablate, run.scale, run.base),
        (saved.noise_model, saved.ablate, saved.scale, saved.base)
    );
}
