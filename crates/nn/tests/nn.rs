//! Network layer: tiling without seams, model files, and resumable, deterministic training.

use burn::prelude::*;
use emccd_nn::tile::Tiling;
mod common;

use common::{meta, scene, tiling_mismatch};
use emccd_nn::Denoiser;

#[test]
fn tiled_and_untiled_outputs_agree_in_the_interior() {
    let m = Denoiser::new(meta(8, 3), &emccd_nn::cpu()).unwrap();
    let (_, rel) = tiling_mismatch(&m.net, 200, 168, 8, Tiling { tile: 96, overlap: 48 }, 24);
    assert!(rel < 0.1, "tiled vs untiled correction differs by {rel:.3} (relative rms)");
}

#[test]
fn model_files_round_trip_and_foreign_files_are_refused() {
    let dev = emccd_nn::cpu();
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("m.safetensors");
    let m = Denoiser::new(meta(4, 2), &dev).unwrap();
    m.save(&p).unwrap();
    let back = Denoiser::load(&p, &dev).unwrap();
    assert_eq!(back.meta, m.meta);
    let x = Tensor::<4>::from_data(TensorData::new(scene(32, 32).into_iter().chain(vec![0.1; 1024]).collect::<Vec<f32>>(), [1, 2, 32, 32]), &dev);
    let a: Vec<f32> = m.net.forward(x.clone()).into_data().try_into_vec::<f32>().unwrap();
    let b: Vec<f32> = back.net.forward(x).into_data().try_into_vec::<f32>().unwrap();
    assert_eq!(a, b);
    // A safetensors file without emccd metadata, and a file that is not safetensors at all.
    let foreign = dir.path().join("f.safetensors");
    let t = safetensors::tensor::TensorView::new(safetensors::Dtype::F32, vec![1], &[0u8; 4]).unwrap();
    std::fs::write(&foreign, safetensors::serialize(vec![("w", t)], None).unwrap()).unwrap();
    let e = Denoiser::load(&foreign, &dev).unwrap_err().to_string();
    assert!(e.contains("without emccd model metadata"), "{e}");
    std::fs::write(dir.path().join("junk.safetensors"), b"not a model").unwrap();
    let e = Denoiser::load(&dir.path().join("junk.safetensors"), &dev).unwrap_err().to_string();
    assert!(e.contains("not a safetensors model file"), "{e}");
}

