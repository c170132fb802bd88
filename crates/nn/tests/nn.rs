//! Network layer: tiling without seams, model files, and resumable, deterministic training.

use emccd_nn::tile::{run, run_ensemble, Planes, Tiling};
mod common;

use common::{meta, scene, tiling_mismatch};
use emccd_nn::{Arch, Model, Net};

#[test]
fn tiled_and_untiled_outputs_agree_in_the_interior() {
    let m = Model::new(meta(8, 3), &emccd_nn::cpu()).unwrap();
    let (_, rel) = tiling_mismatch(
        &m.net,
        200,
        168,
        8,
        Tiling {
            tile: 96,
            overlap: 48,
        },
        24,
    );
    assert!(
        rel < 0.1,
        "tiled vs untiled correction differs by {rel:.3} (relative rms)"
    );
}

#[test]
fn model_files_round_trip_and_foreign_files_are_refused() {
    let dev = emccd_nn::cpu();
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("m.safetensors");
    let m = Model::new(meta(4, 2), &dev).unwrap();
    m.save(&p).unwrap();
    let back = Model::load(&p, &dev).unwrap();
    assert_eq!(back.meta, m.meta);
    // The same model is saved as the same bytes (the metadata map is written in hash order
    // unless sorted; with four keys, seven saves in one order by chance is 1 in 24⁶).
    let bytes = std::fs::read(&p).unwrap();
    for k in 0..7 {
        let q = dir.path().join(format!("m{k}.safetensors"));
        m.save(&q).unwrap();
        assert!(std::fs::read(&q).unwrap() == bytes, "save {k}");
    }
    let x = common::scene_input(32, 32, &dev);
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
    // A safetensors file without emccd metadata, and a file that is not safetensors at all.
    let foreign = dir.path().join("f.safetensors");
    let t =
        safetensors::tensor::TensorView::new(safetensors::Dtype::F32, vec![1], &[0u8; 4]).unwrap();
    std::fs::write(
        &foreign,
        safetensors::serialize(vec![("w", t)], None).unwrap(),
    )
    .unwrap();
    let e = Model::load(&foreign, &dev).unwrap_err().to_string();
    assert!(e.contains("without emccd model metadata"), "{e}");
    std::fs::write(dir.path().join("junk.safetensors"), b"not a model").unwrap();
    let e = Model::load(&dir.path().join("junk.safetensors"), &dev)
        .unwrap_err()
        .to_string();
    assert!(e.contains("not a safetensors model file"), "{e}");
}

#[test]
fn self_ensemble_averages_the_network_over_flips_and_transposes() {
    // A non-square frame, so a transform that mixes up width and height cannot pass.
    let (w, h) = (48, 32);
    let m = meta(4, 2);
    let dev = emccd_nn::cpu();
    let Arch::UNet(c) = m.arch else {
        unreachable!("common::meta is a U-Net")
    };
    let net = Net::UNet(c.init(&dev));
    let img = scene(w, h);
    let mut input = img.clone();
    input.extend(img.iter().map(|v| v.sqrt() * 0.1));
    let tiles = Tiling::default();
    fn planes(data: &[f32], width: usize, height: usize) -> Planes<'_> {
        Planes {
            data,
            channels: 2,
            width,
            height,
        }
    }
    let got = run_ensemble(&net, planes(&input, w, h), 4, tiles, 8, &dev);
    // The expectation, written independently: each orientation as a coordinate map from the
    // original frame, applied to the input and undone on the output.
    let maps: [fn(usize, usize, usize, usize) -> (usize, usize); 8] = [
        |x, y, _, _| (x, y),
        |x, y, w, _| (w - 1 - x, y),
        |x, y, _, h| (x, h - 1 - y),
        |x, y, w, h| (w - 1 - x, h - 1 - y),
        |x, y, _, _| (y, x),
        |x, y, _, h| (h - 1 - y, x),
        |x, y, w, _| (y, w - 1 - x),
        |x, y, w, h| (h - 1 - y, w - 1 - x),
    ];
    let mut want = vec![0f32; w * h];
    for (t, map) in maps.iter().enumerate() {
        let (tw, th) = if t >= 4 { (h, w) } else { (w, h) };
        let mut moved = vec![0f32; 2 * w * h];
        for c in 0..2 {
            for y in 0..h {
                for x in 0..w {
                    let (tx, ty) = map(x, y, w, h);
                    moved[c * w * h + ty * tw + tx] = input[c * w * h + y * w + x];
                }
            }
        }
        let out = run(&net, planes(&moved, tw, th), 4, tiles, &dev);
        for y in 0..h {
            for x in 0..w {
                let (tx, ty) = map(x, y, w, h);
                want[y * w + x] += out[ty * tw + tx] / 8.0;
            }
        }
    }
    let worst = got
        .iter()
        .zip(&want)
        .map(|(a, b)| (a - b).abs())
        .fold(0f32, f32::max);
    assert!(
        worst < 1e-5,
        "self-ensemble differs from the average of the eight orientations by {worst}"
    );
    // The network is not flip-equivariant, so the average differs from the plain output.
    let plain = run(&net, planes(&input, w, h), 4, tiles, &dev);
    assert!(got.iter().zip(&plain).any(|(a, b)| (a - b).abs() > 1e-4));
}

/// The bundled default model's output on a fixed input is pinned: a change to the architecture
/// code, the weight loading or the backend that alters what the shipped model computes fails
/// here. Tolerance 10⁻⁴ relative to the output's range: the flex backend may sum in another
/// order on another CPU (differences near 10⁻⁶), while a real change moves outputs by far more.
#[test]
fn the_bundled_default_model_output_is_pinned() {
    let dev = emccd_nn::cpu();
    let path = common::bundled("default");
    let m = Model::load(&path, &dev).unwrap();
    let (w, h) = (64, 48);
    let img = scene(w, h);
    let mut input = img.clone();
    input.extend(img.iter().map(|v| (v.max(0.0) + 0.01).sqrt() * 0.1));
    let planes = Planes {
        data: &input,
        channels: 2,
        width: w,
        height: h,
    };
    let out = run(&m.net, planes, m.meta.multiple(), Tiling::default(), &dev);
    let n = out.len() as f64;
    let mean = out.iter().map(|&v| v as f64).sum::<f64>() / n;
    let sd = (out.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / n).sqrt();
    let mut got: Vec<f64> = [0, 1, 700, 1500, 2000, w * h - 1]
        .iter()
        .map(|&i| out[i] as f64)
        .collect();
    got.extend([mean, sd]);
    println!("default model: {got:?}");
    let range = out.iter().copied().fold(f32::MIN, f32::max) as f64
        - out.iter().copied().fold(f32::MAX, f32::min) as f64;
    for (k, (g, p)) in got.iter().zip(PINNED_DEFAULT).enumerate() {
        assert!(
            (g - p).abs() <= 1e-4 * range,
            "value {k}: {g} vs pinned {p} (all {got:?})"
        );
    }
}

// Pinned 2026-11-24: six pixels, then the mean and standard deviation.
const PINNED_DEFAULT: [f64; 8] = [
    0.5655593872070313,
    0.5752136707305908,
    0.6192550659179688,
    0.4959999620914459,
    0.21416346728801727,
    0.30742761492729187,
    0.49846835787563276,
    0.20267293108121018,
];

/// A model file whose weights disagree with its metadata's network is an error of a few lines
/// (burn lists every tensor), and sizes no emccd model has are refused before anything is built.
#[test]
fn model_metadata_that_disagrees_or_is_absurd_is_a_short_error() {
    let dev = emccd_nn::cpu();
    let dir = tempfile::tempdir().unwrap();
    let bytes = std::fs::read(common::bundled("default")).unwrap();
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header = std::str::from_utf8(&bytes[8..8 + n]).unwrap();
    for (name, from, to, want) in [
        (
            "wide.safetensors",
            "\\\"base\\\":16",
            "\\\"base\\\":32",
            "weights have other shapes",
        ),
        (
            "deep.safetensors",
            "\\\"levels\\\":4",
            "\\\"levels\\\":70",
            "outside what emccd builds",
        ),
    ] {
        assert!(header.contains(from), "{from} not in the header");
        let mut h = header.replacen(from, to, 1).into_bytes();
        h.resize(h.len().next_multiple_of(8), b' ');
        let mut file = (h.len() as u64).to_le_bytes().to_vec();
        file.extend(&h);
        file.extend(&bytes[8 + n..]);
        let p = dir.path().join(name);
        std::fs::write(&p, file).unwrap();
        let e = Model::load(&p, &dev).unwrap_err().to_string();
        assert!(e.contains(want) && e.contains(name), "{e}");
        assert!(e.len() < 600, "{} characters: {e}", e.len());
    }
}

/// A direct U-Net (`--direct`) outputs its prediction alone, where a denoiser adds its
/// correction to the noisy channel: with the output layer zeroed, one returns zeros and the
/// other the noisy frame. The flag survives a model file, and files without it are residual.
#[test]
fn a_direct_unet_has_no_global_residual() {
    let dev = emccd_nn::cpu();
    let x = common::scene_input(16, 16, &dev);
    for direct in [false, true] {
        let Arch::UNet(mut cfg) = meta(4, 2).arch else {
            unreachable!("common::meta is a U-Net")
        };
        cfg.direct = direct;
        let y: Vec<f32> = cfg
            .init(&dev)
            .with_zero_output()
            .forward(x.clone())
            .into_data()
            .try_into_vec::<f32>()
            .unwrap();
        let want = if direct {
            vec![0.0; 256]
        } else {
            scene(16, 16)
        };
        assert_eq!(y, want, "direct = {direct}");
    }
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("d.safetensors");
    let mut m = meta(4, 2);
    if let Arch::UNet(c) = &mut m.arch {
        c.direct = true;
    }
    Model::new(m.clone(), &dev).unwrap().save(&p).unwrap();
    assert_eq!(Model::load(&p, &dev).unwrap().meta, m);
    let old: emccd_nn::UNetConfig =
        serde_json::from_str(r#"{"base":4,"levels":2,"in_channels":2}"#).unwrap();
    assert!(!old.direct);
}
