//! Helpers shared by the network tests.
#![allow(dead_code)] // each test binary uses its own subset

use emccd_nn::tile::{run, Planes, Tiling};
use emccd_nn::{Arch, ModelMeta, Net, UNetConfig};

/// A bundled model file, `models/NAME-unet.safetensors` at the repository root.
pub fn bundled(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(format!("../../models/{name}-unet.safetensors"))
}

/// Metadata of a small U-Net.
pub fn meta(channels: usize, levels: usize) -> ModelMeta {
    ModelMeta {
        arch: Arch::UNet(UNetConfig {
            channels,
            levels,
            in_channels: 2,
            residual: 0,
            direct: false,
            unshuffle: 1,
        }),
        inputs: Default::default(),
        scale: Default::default(),
        base: Default::default(),
        noise_model: emccd_camera::NoiseModelKind::Ours,
        ablate: Default::default(),
        profile_fingerprint: "0".into(),
        train: None,
        adapted: None,
        steps: 0,
        recipe: "test".into(),
    }
}

/// The test scene as a [1, 2, h, w] denoiser input: the scene and a noise level of 0.1.
pub fn scene_input(w: usize, h: usize, dev: &burn::prelude::Device) -> burn::prelude::Tensor<4> {
    let data: Vec<f32> = scene(w, h).into_iter().chain(vec![0.1; w * h]).collect();
    burn::prelude::Tensor::from_data(burn::prelude::TensorData::new(data, [1, 2, h, w]), dev)
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
    let planes = Planes {
        data: &input,
        channels: 2,
        width: w,
        height: h,
    };
    let whole = run(
        net,
        planes,
        multiple,
        Tiling {
            tile: w.max(h).next_multiple_of(multiple),
            overlap: 0,
        },
        &dev,
    );
    let tiled = run(net, planes, multiple, tiles, &dev);
    // A seam is narrow: over the whole interior its error would be diluted by the pixels that
    // only one tile covers. So the mismatch is measured over the overlap bands alone (where
    // neighbouring tiles meet), and over the whole interior; the worse of the two is returned.
    let l = tiles.layout(w, h, multiple);
    let bands = |starts: &[usize], t: usize| -> Vec<std::ops::Range<usize>> {
        starts.windows(2).map(|p| p[1]..p[0] + t).collect()
    };
    let (bx, by) = (bands(&l.starts.0, l.tile.0), bands(&l.starts.1, l.tile.1));
    assert!(
        !bx.is_empty() || !by.is_empty(),
        "the frame is one tile: no seam to test"
    );
    let in_band =
        |x: usize, y: usize| bx.iter().any(|r| r.contains(&x)) || by.iter().any(|r| r.contains(&y));
    let (mut num, mut den, mut snum, mut sden) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for y in margin..h - margin {
        for x in margin..w - margin {
            let i = y * w + x;
            let (a, b) = ((whole[i] - img[i]) as f64, (tiled[i] - img[i]) as f64);
            num += (a - b).powi(2);
            den += a * a;
            if in_band(x, y) {
                snum += (a - b).powi(2);
                sden += a * a;
            }
        }
    }
    assert!(sden > 0.0, "no seam pixel inside the margin");
    (whole, (num / den).sqrt().max((snum / sden).sqrt()))
}
