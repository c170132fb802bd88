//! The model-file loader (`denoise --model`) on arbitrary bytes: metadata, then the network it
//! describes built on the CPU and the weights loaded into it.

mod common;

fn main() {
    let path = common::scratch("safetensors");
    let device = emccd_nn::cpu();
    afl::fuzz!(|data: &[u8]| {
        if std::fs::write(&path, data).is_ok() && emccd_nn::Model::read_meta(&path).is_ok() {
            let _ = emccd_nn::Model::load(&path, &device);
        }
    });
}
