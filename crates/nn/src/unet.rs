//! A plain U-Net: two 3×3 convolutions per level, stride-2 convolutions down, 2×2 transposed
//! convolutions up, skip concatenation, and a global residual on one input channel (the noisy
//! frame, or for a refinement network the estimate it refines). Optionally the U-Net runs on the
//! pixel-unshuffled input (FFDNet's down-sampling: each 2×2 block's pixels become channels) and
//! its output is shuffled back, which costs about a quarter of the operations per pixel for a
//! receptive field one level deeper — more crops per CPU-hour.

use burn::nn::conv::{Conv2d, Conv2dConfig, ConvTranspose2d, ConvTranspose2dConfig};
use burn::nn::{Initializer, LeakyRelu, LeakyReluConfig, PaddingConfig2d};
use burn::prelude::*;
use serde::{Deserialize, Serialize};

mod cpu;
pub use cpu::CpuUNet;

/// The leaky ReLU's slope for negative inputs, after every 3×3 convolution.
const LEAK: f64 = 0.2;

/// Size of a U-Net (with the `clap` feature, `emccd train`'s U-Net flags; defaults
/// [`UNetConfig::DEFAULT`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct UNetConfig {
    /// U-Net channels at full resolution (doubled at every level down).
    #[serde(rename = "base")]
    #[cfg_attr(feature = "clap", arg(long, alias = "base", default_value_t = UNetConfig::DEFAULT.channels))]
    pub channels: usize,
    /// U-Net levels of down-sampling; frames are padded to a multiple of 2^levels.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = UNetConfig::DEFAULT.levels))]
    pub levels: usize,
    /// Input channels (the noisy frame and its noise-level map; a refinement network also
    /// gets the estimate it refines; a temporal network the frames around the frame).
    #[cfg_attr(feature = "clap", arg(skip = UNetConfig::DEFAULT.in_channels))]
    pub in_channels: usize,
    /// The input channel the output is added to (the global residual): 0, the noisy frame, for
    /// a denoiser; the estimate's channel for a refinement network, whose output layer then
    /// starts at zero so that an untrained network returns the estimate unchanged.
    #[serde(default)]
    #[cfg_attr(feature = "clap", arg(skip = UNetConfig::DEFAULT.residual))]
    pub residual: usize,
    /// No global residual: the output is the clean frame itself rather than a correction to
    /// the residual channel. At a few photoelectrons the noisy frame is mostly single-electron
    /// EM spikes, which a correction has to cancel exactly; a direct output need not.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    #[cfg_attr(
        feature = "clap",
        arg(
            long,
            help = "U-Net denoiser: output the clean frame directly instead of a correction added to the noisy frame (which, at a few photoelectrons, has to cancel every EM spike exactly)"
        )
    )]
    pub direct: bool,
    /// U-Net: fold each N×N pixel block into channels before the first layer and unfold the
    /// output (FFDNet's down-sampling; 2 costs about a quarter of the operations per pixel, so
    /// about 3× the crops per CPU-hour, for a receptive field one level deeper). 1: none.
    #[serde(default = "one", skip_serializing_if = "is_one")]
    #[cfg_attr(feature = "clap", arg(long, default_value_t = UNetConfig::DEFAULT.unshuffle, value_name = "1|2|4"))]
    pub unshuffle: usize,
}

fn one() -> usize {
    1
}

fn is_one(v: &usize) -> bool {
    *v == 1
}

impl UNetConfig {
    /// The CPU default: 16 channels, 4 levels (≈ 2.5 M parameters).
    pub const DEFAULT: UNetConfig = UNetConfig {
        channels: 16,
        levels: 4,
        in_channels: 2,
        residual: 0,
        direct: false,
        unshuffle: 1,
    };

    /// Frame sides the network accepts are multiples of this.
    pub fn multiple(&self) -> usize {
        self.unshuffle << self.levels
    }

    /// Builds the network with freshly initialized weights.
    pub fn init(&self, device: &Device) -> UNet {
        let mut enc = Vec::new();
        let mut down = Vec::new();
        let mut up = Vec::new();
        let mut dec = Vec::new();
        let u = self.unshuffle.max(1);
        let (mut ch, mut inp) = (self.channels, self.in_channels * u * u);
        for _ in 0..self.levels {
            enc.push(Block::new(inp, ch, device));
            down.push(
                Conv2dConfig::new([ch, ch * 2], [2, 2])
                    .with_stride([2, 2])
                    .init(device),
            );
            inp = ch * 2;
            ch *= 2;
        }
        let bottom = Block::new(ch, ch, device);
        for _ in 0..self.levels {
            up.push(
                ConvTranspose2dConfig::new([ch, ch / 2], [2, 2])
                    .with_stride([2, 2])
                    .init(device),
            );
            dec.push(Block::new(ch, ch / 2, device));
            ch /= 2;
        }
        let out = if self.residual == 0 || self.direct {
            Conv2dConfig::new([ch, u * u], [1, 1]).init(device)
        } else {
            Conv2dConfig::new([ch, u * u], [1, 1])
                .with_initializer(Initializer::Zeros)
                .init(device)
        };
        UNet {
            enc,
            down,
            bottom,
            up,
            dec,
            out,
            residual: (!self.direct).then_some(self.residual),
            unshuffle: u,
        }
    }
}

/// Two 3×3 convolutions with leaky ReLU.
#[derive(Module, Debug)]
pub struct Block {
    c1: Conv2d,
    c2: Conv2d,
    act: LeakyRelu,
}

impl Block {
    fn new(i: usize, o: usize, d: &Device) -> Block {
        let conv = |a, b| {
            Conv2dConfig::new([a, b], [3, 3])
                .with_padding(PaddingConfig2d::Same)
                .init(d)
        };
        Block {
            c1: conv(i, o),
            c2: conv(o, o),
            act: LeakyReluConfig::new().with_negative_slope(LEAK).init(),
        }
    }

    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let x = self.act.forward(self.c1.forward(x));
        self.act.forward(self.c2.forward(x))
    }
}

/// The U-Net.
#[derive(Module, Debug)]
pub struct UNet {
    enc: Vec<Block>,
    down: Vec<Conv2d>,
    bottom: Block,
    up: Vec<ConvTranspose2d>,
    dec: Vec<Block>,
    out: Conv2d,
    /// The input channel the output is added to; none for a direct output.
    residual: Option<usize>,
    /// Pixel-block side folded into channels (1: none).
    unshuffle: usize,
}

/// `[N, C, H, W]` → `[N, C·u², H/u, W/u]`: each u×u block's pixels become channels
/// (channel-major: input channel c's block pixel (i, j) lands on channel `(c·u + i)·u + j`).
fn fold(x: Tensor<4>, u: usize) -> Tensor<4> {
    let [n, c, h, w] = x.dims();
    x.reshape([n, c, h / u, u, w / u, u])
        .permute([0, 1, 3, 5, 2, 4])
        .reshape([n, c * u * u, h / u, w / u])
}

/// The inverse of [`fold`].
fn unfold(x: Tensor<4>, u: usize) -> Tensor<4> {
    let [n, cu, h, w] = x.dims();
    let c = cu / (u * u);
    x.reshape([n, c, u, u, h, w])
        .permute([0, 1, 4, 2, 5, 3])
        .reshape([n, c, h * u, w * u])
}

impl UNet {
    /// `x`: [N, C, H, W]; H and W multiples of unshuffle·2^levels. Returns [N, 1, H, W]: the residual
    /// channel (the noisy frame, or the estimate refined) plus the predicted correction, or for
    /// a direct network the prediction itself.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let base = self.residual.map(|r| x.clone().narrow(1, r, 1));
        let mut skips = Vec::with_capacity(self.enc.len());
        let mut h = if self.unshuffle > 1 {
            fold(x, self.unshuffle)
        } else {
            x
        };
        for (e, d) in self.enc.iter().zip(&self.down) {
            let s = e.forward(h);
            h = d.forward(s.clone());
            skips.push(s);
        }
        h = self.bottom.forward(h);
        for (u, d) in self.up.iter().zip(&self.dec) {
            let s = skips.pop().expect("one skip per level");
            h = d.forward(Tensor::cat(vec![u.forward(h), s], 1));
        }
        let mut y = self.out.forward(h);
        if self.unshuffle > 1 {
            y = unfold(y, self.unshuffle);
        }
        match base {
            Some(b) => b + y,
            None => y,
        }
    }

    /// The same network with its output layer zeroed: it then returns its residual channel
    /// unchanged. A refinement network moved onto another base estimate starts from that
    /// estimate's quality this way, keeping the features it learned.
    pub fn with_zero_output(mut self) -> UNet {
        // A fresh tensor does not keep gradients: mark the zeros as trainable again, or the
        // layer would stay zero (and the network the identity) through any training.
        let zero = |t: Tensor<4>| burn::module::Parameter::set_require_grad(t.zeros_like(), true);
        self.out.weight = self.out.weight.map(zero);
        self.out.bias = self
            .out
            .bias
            .map(|b| b.map(|b| burn::module::Parameter::set_require_grad(b.zeros_like(), true)));
        self
    }
}

impl UNet {
    /// A single-frame denoiser (2 inputs: frame, noise level; residual on the frame) widened to
    /// a temporal one ([`crate::Inputs::Movie`]: `frames` frames, then the centre's noise
    /// level; residual on the centre, channel `frames / 2`) that starts as exactly the
    /// single-frame network: the first layer's weights for the centre and the noise level are
    /// the old frame's and noise level's, those for the neighbours start at zero and learn
    /// what the neighbours add. `None` if this network is not such a denoiser.
    pub fn widened_for_movie(mut self, frames: usize) -> Option<UNet> {
        if self.unshuffle != 1 || self.residual != Some(0) || frames % 2 == 0 {
            return None;
        }
        let first = &mut self.enc.first_mut()?.c1;
        let w = first.weight.val();
        let [o, i, kh, kw] = w.dims();
        if i != 2 {
            return None;
        }
        let center = frames / 2;
        let device = w.device();
        let zeros = |n: usize| Tensor::<4>::zeros([o, n, kh, kw], &device);
        let mut parts = Vec::new();
        if center > 0 {
            parts.push(zeros(center));
        }
        parts.push(w.clone().narrow(1, 0, 1));
        if frames - center - 1 > 0 {
            parts.push(zeros(frames - center - 1));
        }
        parts.push(w.narrow(1, 1, 1));
        let wide = Tensor::cat(parts, 1);
        // Detached: on an autodiff device the concatenation is not a leaf, and a parameter must be.
        first.weight = burn::module::Param::from_tensor(wide.detach());
        self.residual = Some(center);
        Some(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fold_and_unfold_are_inverse_and_keep_blocks_together() {
        let d = crate::cpu();
        // [1, 2, 4, 4]: values 0..32 so every pixel is distinguishable.
        let vals: Vec<f32> = (0..32).map(|v| v as f32).collect();
        let x = Tensor::<4>::from_data(TensorData::new(vals, [1, 2, 4, 4]), &d);
        let f = fold(x.clone(), 2);
        assert_eq!(f.dims(), [1, 8, 2, 2]);
        let v: Vec<f32> = f.clone().into_data().try_into_vec::<f32>().unwrap();
        // Channel (c·2 + i)·2 + j at block (by, bx) holds x[c, 2·by + i, 2·bx + j].
        for c in 0..2 {
            for i in 0..2 {
                for j in 0..2 {
                    for by in 0..2 {
                        for bx in 0..2 {
                            let ch = (c * 2 + i) * 2 + j;
                            let got = v[(ch * 2 + by) * 2 + bx];
                            let want = (c * 16 + (2 * by + i) * 4 + 2 * bx + j) as f32;
                            assert_eq!(got, want);
                        }
                    }
                }
            }
        }
        let back: Vec<f32> = unfold(f, 2).into_data().try_into_vec::<f32>().unwrap();
        let orig: Vec<f32> = x.into_data().try_into_vec::<f32>().unwrap();
        assert_eq!(back, orig);
    }

    #[test]
    fn a_widened_unet_starts_as_the_single_frame_network() {
        let d = crate::cpu();
        let cfg = UNetConfig {
            levels: 2,
            channels: 4,
            ..UNetConfig::DEFAULT
        };
        let net = cfg.init(&d);
        let n = 16 * 16;
        let frame: Vec<f32> = (0..n).map(|i| ((i * 37) % 11) as f32 / 10.0).collect();
        let level: Vec<f32> = frame.iter().map(|v| v.sqrt() + 0.1).collect();
        let single = net
            .forward(Tensor::<4>::from_data(
                TensorData::new([frame.clone(), level.clone()].concat(), [1, 2, 16, 16]),
                &d,
            ))
            .into_data()
            .try_into_vec::<f32>()
            .unwrap();
        let wide = net
            .widened_for_movie(5)
            .expect("a residual denoiser widens");
        // Neighbours unlike the frame change nothing at the start.
        let other: Vec<f32> = frame.iter().map(|v| 3.0 - v).collect();
        let input = [&other, &other, &frame, &other, &other, &level]
            .map(|v| v.as_slice())
            .concat();
        let y = wide
            .forward(Tensor::<4>::from_data(
                TensorData::new(input, [1, 6, 16, 16]),
                &d,
            ))
            .into_data()
            .try_into_vec::<f32>()
            .unwrap();
        for (a, b) in y.iter().zip(&single) {
            assert!((a - b).abs() < 1e-5, "{a} vs {b}");
        }
        let direct = UNetConfig {
            direct: true,
            ..cfg
        }
        .init(&d);
        assert!(direct.widened_for_movie(5).is_none());
    }

    #[test]
    fn an_unshuffled_unet_keeps_the_frame_size() {
        let d = crate::cpu();
        let cfg = UNetConfig {
            unshuffle: 2,
            levels: 2,
            channels: 4,
            ..UNetConfig::DEFAULT
        };
        assert_eq!(cfg.multiple(), 8);
        let net = cfg.init(&d);
        let y = net.forward(Tensor::zeros([2, 2, 16, 24], &d));
        assert_eq!(y.dims(), [2, 1, 16, 24]);
    }
}
