//! Value stability of the default method: `blend` (iterative BM3D and the bundled `lowlight`
//! network, averaged) on a small fixed raw frame through the bundled profile is pinned, so that
//! a change to the preprocessing, the network's input, its inference or the classical estimate
//! — which would move every figure the README reports — fails here and has to be made on
//! purpose (update the pinned values and say why in the commit).
//!
//! Tolerance: 10⁻³ DN plus 10⁻⁴ relative. The network runs in f32 through burn's flex kernels,
//! whose sums may be ordered differently on another CPU's vector width (about 10⁻⁶ relative);
//! a real change moves pixels by tenths of a DN or more, and the sum of squares (pinned too) by
//! more than its slack. The frame is run whole, and again in overlapping tiles with a
//! two-orientation self-ensemble, so the seams' blending and the ensemble are pinned as well.

use emccd_denoise::{Denoiser, Method, Units};

const SIDE: usize = 48;

fn assert_pinned(label: &str, got: &[f32], want: &[f32]) {
    println!("{label}: {got:?}");
    assert_eq!(got.len(), want.len());
    for (k, (g, w)) in got.iter().zip(want).enumerate() {
        assert!(
            (g - w).abs() <= 1e-3 + 1e-4 * w.abs(),
            "{label}: value {k} is {g}, pinned {w} (all: {got:?})"
        );
    }
}

#[test]
fn blend_is_pinned() {
    let profile = emccd_profile::default_profile()
        .crop(emccd_profile::Roi::corner(SIDE, SIDE))
        .unwrap();
    let model = emccd_denoise::bundled::load("lowlight", &emccd_nn::cpu()).unwrap();
    // A raw frame: bias near 180 DN, bars and a gradient of up to ~60 DN of signal, and a fixed
    // pseudo-random ±15 DN texture standing in for the noise (a 64-bit LCG).
    let mut state = 2024u64;
    let raw: Vec<f32> = (0..SIDE * SIDE)
        .map(|i| {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let u = (state >> 11) as f64 / (1u64 << 53) as f64;
            let (x, y) = (i % SIDE, i / SIDE);
            let signal = if (x / 6) % 2 == 0 { 40.0 } else { 8.0 } + 0.4 * y as f64;
            (180.0 + signal + 30.0 * (u - 0.5)) as f32
        })
        .collect();
    let run = |tiling, ensemble| {
        let out = Denoiser {
            profile: &profile,
            method: Method::Blend,
            model: Some(&model),
            tiling,
            ensemble,
            units: Units::Dn,
            window: 0,
        }
        .run(&raw, 0.01)
        .unwrap();
        let mut got: Vec<f32> = [0, 1, 47, 300, 777, 1000, 1500, 2303]
            .iter()
            .map(|&i| out[i])
            .collect();
        got.push(out.iter().map(|&x| x as f64).sum::<f64>() as f32);
        got.push(out.iter().map(|&x| (x as f64).powi(2)).sum::<f64>() as f32);
        got
    };
    assert_pinned("blend", &run(Default::default(), 1), &BLEND);
    let tiles = emccd_nn::tile::Tiling {
        tile: 32,
        overlap: 8,
    };
    assert_pinned("blend, tiled, ensemble 2", &run(tiles, 2), &BLEND_TILED);
}

const BLEND: [f32; 10] = [
    57.609474, 58.235847, 28.42876, 55.919456, 30.236523, 64.233055, 60.897354, 39.629143,
    115658.11, 6251504.0,
];
const BLEND_TILED: [f32; 10] = [
    57.589603, 57.615692, 28.190264, 55.877018, 31.186646, 63.79033, 60.28408, 39.41028, 115568.62,
    6227736.0,
];
