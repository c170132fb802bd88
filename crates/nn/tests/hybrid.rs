//! The hybrid (BM3D-refining) network and the normalization invariants the networks rely on.

use burn::prelude::*;
use emccd_camera::{NoiseModel, PgnModel};
use emccd_classical::frame::bm3d_estimate;
use emccd_nn::norm::{prepare, prepare_hybrid, signal_scale, HYBRID_SCALE_FLOOR};
use emccd_nn::Inference;
use emccd_nn::{Arch, Inputs, Model, ModelMeta, UNetConfig};
mod common;

use common::{meta, scene};

fn hybrid_meta() -> ModelMeta {
    ModelMeta {
        arch: Arch::UNet(UNetConfig {
            channels: 4,
            levels: 2,
            in_channels: 3,
            residual: Inputs::Hybrid.residual(),
            direct: false,
            unshuffle: 1,
        }),
        inputs: Inputs::Hybrid,
        ..meta(4, 2)
    }
}

/// A 32×32 hybrid input: frame, noise level, and an estimate (the frame × 0.7).
fn three_channels() -> Vec<f32> {
    scene(32, 32)
        .into_iter()
        .chain(vec![0.2; 32 * 32])
        .chain(scene(32, 32).iter().map(|v| v * 0.7))
        .collect()
}

#[test]
fn an_untrained_hybrid_network_returns_the_bm3d_estimate() {
    let dev = emccd_nn::cpu();
    let m = Model::new(hybrid_meta(), &dev).unwrap();
    // Straight through the network: the output is the third channel, exactly.
    let n = 32 * 32;
    let input = three_channels();
    let x = Tensor::<4>::from_data(TensorData::new(input.clone(), [1, 3, 32, 32]), &dev);
    let out: Vec<f32> = m.net.forward(x).into_data().try_into_vec::<f32>().unwrap();
    assert_eq!(out, input[2 * n..].to_vec());
    // Through the pipeline (normalization and back): the BM3D + GAT estimate of the frame.
    let p = emccd_profile::default_profile()
        .crop(emccd_profile::Roi::corner(64, 64))
        .unwrap();
    let slope = p.slope().unwrap();
    let clean: Vec<f32> = scene(64, 64)
        .iter()
        .map(|v| v * 4.0 * slope as f32 / 2.0)
        .collect();
    let mut noisy = vec![0f32; clean.len()];
    PgnModel::from_profile(&p, 0.01)
        .unwrap()
        .synthesize(&clean, 64, &mut noisy, 3);
    let pipe = Inference {
        model: &m,
        profile: &p,
        tiling: Default::default(),
        ensemble: 1,
    };
    let got = pipe.denoise_preprocessed(&noisy, 0.01).unwrap();
    let want = bm3d_estimate(&p, &noisy, 0.01).unwrap();
    let worst = got
        .iter()
        .zip(&want)
        .map(|(a, b)| (a - b).abs())
        .fold(0f32, f32::max);
    assert!(
        worst < 1e-3 * slope as f32,
        "hybrid at initialization differs from BM3D by {worst} DN"
    );
}

#[test]
fn a_hybrid_needs_three_channels_and_a_unet() {
    let bad = ModelMeta {
        arch: Arch::UNet(UNetConfig {
            channels: 4,
            levels: 2,
            in_channels: 2,
            residual: 0,
            direct: false,
            unshuffle: 1,
        }),
        ..hybrid_meta()
    };
    let e = Model::new(bad, &emccd_nn::cpu()).unwrap_err().to_string();
    assert!(e.contains("3 input channels"), "{e}");
}

/// Camera independence: the same photoelectrons recorded by two cameras of different gain
/// (photon-transfer slope) and the same read noise in electrons give the same network input.
#[test]
fn inputs_are_the_same_for_the_same_electrons_on_any_camera() {
    let electrons: Vec<f32> = scene(40, 30).iter().map(|v| v * 12.0).collect();
    let read_e = vec![0.4f32; electrons.len()];
    let inputs = |slope: f32| {
        // DN per electron is s/2; read noise in DN is its electron value times that.
        let dn: Vec<f32> = electrons.iter().map(|e| e * slope / 2.0).collect();
        let rn: Vec<f32> = read_e.iter().map(|r| r * slope / 2.0).collect();
        let est = dn.clone();
        let x: Vec<f32> = est.iter().map(|v| v / slope).collect();
        (
            prepare(&dn, 40, slope as f64, &rn, Default::default()).input,
            prepare_hybrid(&dn, &est, slope as f64, &rn, signal_scale(&x)).input,
        )
    };
    let (a, b) = (inputs(20.14), inputs(150.0));
    for (u, v) in a.0.iter().zip(&b.0).chain(a.1.iter().zip(&b.1)) {
        assert!((u - v).abs() <= 1e-5 * u.abs().max(1.0), "{u} vs {v}");
    }
}

/// The hybrid scale follows the scene: a frame k times brighter is scaled k times more, so its
/// frame and estimate channels are unchanged; an empty frame is not blown up.
#[test]
fn hybrid_scale_follows_the_signal_and_has_a_floor() {
    let s = 20.0;
    let dn: Vec<f32> = scene(32, 32).iter().map(|v| v * 200.0).collect();
    let rn = vec![3.0f32; dn.len()];
    let prep = |k: f32| {
        let d: Vec<f32> = dn.iter().map(|v| v * k).collect();
        let x: Vec<f32> = d.iter().map(|v| v / s as f32).collect();
        prepare_hybrid(&d, &d, s, &rn, signal_scale(&x))
    };
    let (p1, p4) = (prep(1.0), prep(4.0));
    assert!((p4.to_dn / p1.to_dn - 4.0).abs() < 1e-4);
    let n = dn.len();
    for c in [0, 2] {
        for i in 0..n {
            assert!((p1.input[c * n + i] - p4.input[c * n + i]).abs() < 1e-5);
        }
    }
    assert_eq!(signal_scale(&vec![0.0; 100]), HYBRID_SCALE_FLOOR);
    assert_eq!(signal_scale(&[f32::NAN; 10]), HYBRID_SCALE_FLOOR);
}

/// The noise-level channel is the standard deviation of the frame channel: for the exact EMCCD
/// chain at 4 and 20 photoelectrons, Var(frame channel) over 4·10⁵ pixels equals the mean square
/// of the noise channel. The sample variance of such skewed data has a relative standard error
/// of about √((κ − 1)/n) ≤ 0.6 % (kurtosis κ ≤ 15 here); the tolerance is 4.5 of them plus the
/// channel's 0.1 % bias from clamping negative frames at zero.
#[test]
fn the_noise_channel_is_the_frame_channels_standard_deviation() {
    let (g, s) = (300.0, 20.14);
    let n = 400 * 1000;
    let rn = vec![3.0f32; n];
    for (k, electrons) in [4.0f32, 20.0].into_iter().enumerate() {
        let m = PgnModel::new(g, 2.0 * g / s, 0.0, 0.0, 0.0, 3.0, 0.0).unwrap();
        let clean = vec![electrons * s as f32 / 2.0; n];
        let mut noisy = vec![0f32; n];
        m.synthesize(&clean, 1000, &mut noisy, 40 + k as u64);
        let p = prepare_hybrid(&noisy, &clean, s, &rn, 1.0);
        let f = &p.input[..n];
        let mean = f.iter().map(|&v| v as f64).sum::<f64>() / n as f64;
        let var = f.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
        let ms = p.input[n..2 * n]
            .iter()
            .map(|&v| (v as f64).powi(2))
            .sum::<f64>()
            / n as f64;
        let tol = 4.5 * (14.0f64 / n as f64).sqrt() + 1e-3;
        assert!(
            (var / ms - 1.0).abs() < tol,
            "{electrons} e⁻: Var {var:.5} vs mean square noise level {ms:.5}"
        );
    }
}

/// A trained refinement network moved onto another base estimate (`train --init` with another
/// `--hybrid-base`) restarts as the identity on it: with its output layer zeroed it returns the
/// estimate channel exactly, whatever its other layers learned.
#[test]
fn a_zeroed_output_layer_makes_a_trained_hybrid_the_identity() {
    let dev = emccd_nn::cpu();
    let path = common::bundled("hybrid");
    let m = Model::load(&path, &dev).unwrap();
    assert_eq!(m.meta.inputs, Inputs::Hybrid);
    let n = 32 * 32;
    let input = three_channels();
    let run = |net: &emccd_nn::Net| -> Vec<f32> {
        let x = Tensor::<4>::from_data(TensorData::new(input.clone(), [1, 3, 32, 32]), &dev);
        net.forward(x).into_data().try_into_vec::<f32>().unwrap()
    };
    // The trained network corrects its estimate…
    assert_ne!(run(&m.net), input[2 * n..].to_vec());
    // …and with the output layer zeroed it passes it through.
    let zeroed = match m.net {
        emccd_nn::Net::UNet(u) => emccd_nn::Net::UNet(u.with_zero_output()),
        other => panic!("the bundled hybrid is a U-Net, not {other:?}"),
    };
    assert_eq!(run(&zeroed), input[2 * n..].to_vec());
}

/// Metadata that contradicts itself is refused when the model is built: a U-Net whose residual
/// is not the channel its inputs say it corrects (a temporal network adding the first frame
/// instead of the centre one), and a Uformer given a temporal network's inputs.
#[test]
fn a_network_must_correct_the_channel_its_inputs_name() {
    let dev = emccd_nn::cpu();
    let mut movie = ModelMeta {
        arch: Arch::UNet(UNetConfig {
            channels: 4,
            levels: 2,
            in_channels: Inputs::Movie.channels(),
            residual: Inputs::Movie.residual(),
            direct: false,
            unshuffle: 1,
        }),
        inputs: Inputs::Movie,
        ..meta(4, 2)
    };
    assert!(Model::new(movie.clone(), &dev).is_ok());
    if let Arch::UNet(c) = &mut movie.arch {
        c.residual = 0;
    }
    let e = Model::new(movie.clone(), &dev).unwrap_err().to_string();
    assert!(e.contains("corrects input channel 2"), "{e}");
    let uformer = ModelMeta {
        arch: Arch::for_training("uformer-t", Inputs::Noisy, UNetConfig::DEFAULT).unwrap(),
        ..movie
    };
    assert!(Model::new(uformer, &dev).is_err());
}
