//! A plain U-Net: two 3×3 convolutions per level, stride-2 convolutions down, 2×2 transposed
//! convolutions up, skip concatenation, and a global residual on one input channel (the noisy
//! frame, or for a refinement network the estimate it refines).

use burn::nn::conv::{Conv2d, Conv2dConfig, ConvTranspose2d, ConvTranspose2dConfig};
use burn::nn::{Initializer, LeakyRelu, LeakyReluConfig, PaddingConfig2d};
use burn::prelude::*;
use serde::{Deserialize, Serialize};

/// Size of a U-Net.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct UNetConfig {
    /// Channels at full resolution (doubled at every level down).
    pub base: usize,
    /// Levels of down-sampling; frames are padded to a multiple of 2^levels.
    pub levels: usize,
    /// Input channels (the noisy frame and its noise-level map; a refinement network also
    /// gets the estimate it refines).
    pub in_channels: usize,
    /// The input channel the output is added to (the global residual): 0, the noisy frame, for
    /// a denoiser; the estimate's channel for a refinement network, whose output layer then
    /// starts at zero so that an untrained network returns the estimate unchanged.
    #[serde(default)]
    pub residual: usize,
    /// No global residual: the output is the clean frame itself rather than a correction to
    /// the residual channel. At a few photoelectrons the noisy frame is mostly single-electron
    /// EM spikes, which a correction has to cancel exactly; a direct output need not.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub direct: bool,
}

impl UNetConfig {
    /// The CPU default: 16 channels, 4 levels (≈ 2.5 M parameters).
    pub const DEFAULT: UNetConfig = UNetConfig {
        base: 16,
        levels: 4,
        in_channels: 2,
        residual: 0,
        direct: false,
    };

    /// Builds the network with freshly initialized weights.
    pub fn init(&self, device: &Device) -> UNet {
        let mut enc = Vec::new();
        let mut down = Vec::new();
        let mut up = Vec::new();
        let mut dec = Vec::new();
        let (mut ch, mut inp) = (self.base, self.in_channels);
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
            Conv2dConfig::new([ch, 1], [1, 1]).init(device)
        } else {
            Conv2dConfig::new([ch, 1], [1, 1])
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
            act: LeakyReluConfig::new().with_negative_slope(0.2).init(),
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
}

impl UNet {
    /// `x`: [N, C, H, W]; H and W multiples of 2^levels. Returns [N, 1, H, W]: the residual
    /// channel (the noisy frame, or the estimate refined) plus the predicted correction, or for
    /// a direct network the prediction itself.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let base = self.residual.map(|r| x.clone().narrow(1, r, 1));
        let mut skips = Vec::with_capacity(self.enc.len());
        let mut h = x;
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
        let y = self.out.forward(h);
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
