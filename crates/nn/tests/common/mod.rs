//! Helpers shared by the network tests.
#![allow(dead_code)] // each test binary uses its own subset

use emccd_nn::{ModelMeta, UNetConfig};

/// Metadata of a small U-Net.
pub fn meta(base: usize, levels: usize) -> ModelMeta {
    ModelMeta {
        arch: "unet".into(),
        unet: Some(UNetConfig { base, levels, in_channels: 2 }),
        uformer: None,
        noise_model: "ours".into(),
        ablate: vec![],
        profile_fingerprint: "0".into(),
        steps: 0,
        recipe: "test".into(),
    }
}

/// A smooth test pattern in [0.1, 0.9].
pub fn scene(w: usize, h: usize) -> Vec<f32> {
    (0..w * h).map(|i| {
        let (x, y) = ((i % w) as f32, (i / w) as f32);
        0.5 + 0.4 * ((x / 9.0).sin() * (y / 13.0).cos())
    }).collect()
}
