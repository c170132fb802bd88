//! Helpers shared by the network tests.
#![allow(dead_code)] // each test binary uses its own subset

use emccd_nn::tile::{run, Tiling};
use emccd_nn::{ModelMeta, Net, UNetConfig};

/// Metadata of a small U-Net.
pub fn meta(base: usize, levels: usize) -> ModelMeta {
    ModelMeta {
        arch: "unet".into(),
        unet: Some(UNetConfig {
            base,
            levels,
            in_channels: 2,
            residual: 0,
        }),
        uformer: None,
        inputs: Default::default(),
        base: Default::default(),
        noise_model: "ours".into(),
        ablate: vec![],
        profile_fingerprint: "0".into(),
        steps: 0,
        recipe: "test".into(),
    }
}

/// A smooth test pattern in [0.1, 0.9].
pub fn scene(w: usize, h: usize) -> Vec<f32> {
    (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f32, (i / w) as f32);
            0.5 + 0.4 * ((x / 9.0).sin() * (y / 13.0).cos())
        })
        .collect()
}

/// Runs `net` on the test scene (with a noise-level channel) whole and in overlapping `tiles`;
/// returns the whole output and the relative rms difference of the network's correction
/// (output − noisy input) between the two, `margin` px away from the frame border, where both
/// runs see the same surroundings up to the tiles' own context.
pub fn tiling_mismatch(
    net: &Net,
    w: usize,
    h: usize,
    multiple: usize,
    tiles: Tiling,
    margin: usize,
) -> (Vec<f32>, f64) {
    let dev = emccd_nn::cpu();
    let img = scene(w, h);
    let mut input = img.clone();
    input.extend(img.iter().map(|v| v.sqrt() * 0.1));
    let whole = run(
        net,
        &input,
        2,
        w,
        h,
        multiple,
        Tiling {
            tile: w.max(h).next_multiple_of(multiple),
            overlap: 0,
        },
        &dev,
    );
    let tiled = run(net, &input, 2, w, h, multiple, tiles, &dev);
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for y in margin..h - margin {
        for x in margin..w - margin {
            let i = y * w + x;
            let (a, b) = ((whole[i] - img[i]) as f64, (tiled[i] - img[i]) as f64);
            num += (a - b).powi(2);
            den += a * a;
        }
    }
    (whole, (num / den).sqrt())
}
