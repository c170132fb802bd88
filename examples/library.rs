//! The libraries without the CLI, end to end: record a calibration acquisition with the virtual
//! camera (`emccd-camera`), calibrate it (`emccd-calib`), synthesize
//! training pairs from the calibrated profile and fine-tune the bundled network a few steps
//! (`emccd-train`), then denoise a low-light frame (`emccd-denoise`) and score it
//! (`emccd-eval`), and adapt the network to a short recording of that scene with no clean image
//! (`emccd_train::adapt`).
//!
//!     cargo run --release --example library
//!
//! Everything it writes goes to a temporary folder that is removed at the end.

use anyhow::Result;
use emccd_calib::manifest::Manifest;
use emccd_camera::acquisition::CalibrationPlan;
use emccd_camera::{PhysicalParams, VirtualCamera};
use emccd_denoise::{Denoiser, Method, Units};
use emccd_nn::{Adaptation, ModelMeta, ModelSource, TrainConfig};
use emccd_profile::CameraProfile;
use emccd_train::adapt::{adapt, AdaptConfig, AdaptData, AdaptRun, Start};
use emccd_train::train::{train, Image, Run, RunPaths, TrainImages};
use emccd_train::{AdaptMethod, FrameSet};

/// A 64×64 sub-array keeps the example to seconds.
const SIZE: usize = 64;

fn main() -> Result<()> {
    let dir = tempfile::tempdir()?;
    // Networks run where the caller says: here the CPU.
    let device = emccd_nn::cpu();
    // 1. The camera: the bundled iXon 897 profile is the truth.
    let truth = CameraProfile::load_arg("default")?.crop(emccd_profile::Roi::corner(SIZE, SIZE))?;
    let cam = VirtualCamera::new(truth.clone(), PhysicalParams::default())?;

    // 2. A calibration acquisition: dark stacks at four exposures, flats at six light levels
    //    (about 1–50 photoelectrons per pixel), as emccd_camera::acquisition designs them.
    let plan = CalibrationPlan {
        frames: 16,
        bias_exposures_s: vec![0.01, 0.03, 0.1, 0.3],
        flat_levels_dn: vec![10.0, 20.0, 50.0, 100.0, 200.0, 500.0],
        blooming_exposures_s: vec![],
        ..Default::default()
    };
    plan.record(&cam, 1, dir.path(), "virtual", "examples/library.rs", || {})?;
    let path = dir.path().join("calibration.toml");

    // 3. Calibrate: the photon-transfer slope comes back.
    let cal = emccd_calib::calibrate(
        &Manifest::load(&path)?,
        &Default::default(),
        &emccd_calib::Silent,
    )?;
    let profile = cal.profile()?;
    println!(
        "calibrated slope {:.2} DN (truth {:.2})",
        profile.slope()?,
        truth.slope()?
    );

    // 4. Train a small U-Net a few steps on pairs synthesized on the fly from that profile.
    let scene = |w: usize, h: usize, k: usize| Image {
        width: w,
        height: h,
        data: (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                0.5 + 0.5 * ((x + 3.0 * k as f32) / 5.0).sin() * (y / 7.0).cos()
            })
            .collect(),
    };
    // Fine-tuned from the bundled default model: its architecture, new metadata for this camera.
    let init = emccd_denoise::bundled::source("default")?;
    let cfg = TrainConfig {
        steps: 12,
        batch: 2,
        crop: 32,
        lr: 5e-5,
        warmup: 2,
        val_every: 4,
        checkpoint_every: 4,
        ..Default::default()
    };
    let meta = ModelMeta {
        profile_fingerprint: profile.fingerprint_hex(),
        recipe: "examples/library.rs: 12 steps on synthetic scenes".into(),
        ..init.read_meta()?
    };
    let paths = RunPaths {
        out: dir.path().join("model.safetensors"),
        checkpoint: dir.path().join("model.ckpt"),
    };
    let images: Vec<Image> = (0..4).map(|k| scene(48, 48, k)).collect();
    let model = train(
        TrainImages {
            train: images,
            val: vec![scene(48, 48, 9)],
        },
        Run::new(&profile, cfg, meta, &paths, &device).with_init(Some(&init)),
        &mut |r| {
            if let (Some(p), 0) = (r.val_psnr, r.step % 4) {
                println!(
                    "step {}/{}: loss {:.4}, validation {:.2} dB (input {:.2} dB)",
                    r.step, r.steps, r.loss, p.denoised_db, p.noisy_db
                );
            }
            true
        },
    )?;

    // 5. Denoise a frame at 4 photoelectrons per pixel with the calibrated profile.
    let clean = scene(SIZE, SIZE, 5).data;
    let mean: f32 = clean.iter().sum::<f32>() / clean.len() as f32;
    let photons: Vec<f32> = clean
        .iter()
        .map(|v| v * 4.0 / (mean * cam.physics.qe as f32))
        .collect();
    let e = cam.exposure(0.01);
    let (gt, mut raw) = (e.ground_truth(&photons), vec![0f32; SIZE * SIZE]);
    e.frame(&photons, 7, &mut raw);
    let peak = gt.iter().copied().fold(0f32, f32::max) as f64;
    for method in [Method::None, Method::Bm3d, Method::Net] {
        let d = Denoiser {
            profile: &profile,
            method,
            model: method.uses_model().then_some(&model),
            tiling: Default::default(),
            ensemble: 1,
            units: Units::Dn,
            window: 0,
        };
        let out = d.run(&raw, 0.01)?;
        println!(
            "{:>5}: {:.2} dB",
            method.name(),
            emccd_eval::psnr(&out, &gt, peak)
        );
    }

    // 6. Adapt the network to an 8-frame recording of the scene, self-supervised (Noise2Noise
    //    between its frames), and denoise the same frame again.
    let mut set = FrameSet::new(SIZE, SIZE, 8);
    let mut frame = vec![0f32; SIZE * SIZE];
    for k in 0..8 {
        e.frame(&photons, 100 + k, &mut frame);
        set.add(
            &emccd_classical::frame::preprocess(&profile, &frame, 0.01)?,
            0.01,
        )?;
    }
    let (kept, level) = (set.len(), set.mean_electrons(&profile)?);
    let adapted = adapt(
        AdaptData::Frames(set),
        AdaptRun {
            profile: &profile,
            start: Start::Model(&ModelSource::File(paths.out.clone())),
            cfg: &AdaptConfig {
                method: AdaptMethod::Noise2noise,
                steps: 10,
                batch: 2,
                crop: 32,
                lr: 5e-5,
                ..Default::default()
            },
            provenance: Adaptation {
                method: AdaptMethod::Noise2noise.name().into(),
                from: "model.safetensors".into(),
                files: vec!["(8 frames in memory)".into()],
                frames: kept,
                mean_electrons: level,
            },
            paths: &RunPaths {
                out: dir.path().join("adapted.safetensors"),
                checkpoint: dir.path().join("adapted.ckpt"),
            },
            resume: false,
            device: device.clone(),
        },
        &mut |_| true,
    )?;
    let d = Denoiser {
        profile: &profile,
        method: Method::Net,
        model: Some(&adapted),
        tiling: Default::default(),
        ensemble: 1,
        units: Units::Dn,
        window: 0,
    };
    println!(
        "adapted net: {:.2} dB",
        emccd_eval::psnr(&d.run(&raw, 0.01)?, &gt, peak)
    );
    Ok(())
}
