//! Uformer (Wang et al., CVPR 2022), the paper's network: a U-shaped transformer of LeWin
//! blocks — window self-attention (8×8 windows, every second block on windows shifted by half
//! a window, a learned relative-position bias) and a locally-enhanced feed-forward (linear,
//! 3×3 depthwise convolution, linear) — with 4×4 stride-2 convolutions down, 2×2 transposed
//! convolutions up, skip concatenation, a learnable modulator added to every decoder window,
//! and a global residual on the noisy channel.
//!
//! Tokens are kept channels-last, `[N, H, W, C]`, so linear layers and layer norms act on the
//! last axis and only the convolutions need a transpose.

use burn::module::Param;
use burn::nn::conv::{Conv2d, Conv2dConfig, ConvTranspose2d, ConvTranspose2dConfig};
use burn::nn::{Initializer, LayerNorm, LayerNormConfig, Linear, LinearConfig, PaddingConfig2d};
use burn::prelude::*;
use burn::tensor::activation::{gelu, leaky_relu, softmax};
use burn::tensor::{Int, TensorData};
use serde::{Deserialize, Serialize};

/// Attention heads per stage: four encoder stages, the bottleneck, four decoder stages.
const HEADS: [usize; 9] = [1, 2, 4, 8, 16, 16, 8, 4, 2];

/// Size of a Uformer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct UformerConfig {
    /// Token channels at full resolution, C (doubled at every stage down).
    pub embed: usize,
    /// LeWin blocks per stage: encoder 0–3, bottleneck, decoder 0–3.
    pub depths: [usize; 9],
    /// Attention window side.
    pub win: usize,
    /// Input channels (the noisy frame and its noise-level map).
    pub in_channels: usize,
    /// Learnable modulator in the decoder blocks.
    pub modulator: bool,
}

impl UformerConfig {
    /// Uformer-T: C = 16, two blocks per stage (≈ 5.3 M parameters).
    pub const T: UformerConfig = UformerConfig {
        embed: 16,
        depths: [2; 9],
        win: 8,
        in_channels: 2,
        modulator: true,
    };
    /// Uformer-S: C = 32, two blocks per stage (≈ 20.7 M).
    pub const S: UformerConfig = UformerConfig {
        embed: 32,
        depths: [2; 9],
        win: 8,
        in_channels: 2,
        modulator: true,
    };
    /// Uformer-B: C = 32, depths 1,2,8,8,2,8,8,2,1 (≈ 50.9 M).
    pub const B: UformerConfig = UformerConfig {
        embed: 32,
        depths: [1, 2, 8, 8, 2, 8, 8, 2, 1],
        win: 8,
        in_channels: 2,
        modulator: true,
    };

    /// The configuration an architecture name stands for (`uformer-t`, `uformer-s`, `uformer-b`).
    pub fn by_name(name: &str) -> Option<UformerConfig> {
        match name {
            "uformer-t" => Some(Self::T),
            "uformer-s" => Some(Self::S),
            "uformer-b" => Some(Self::B),
            _ => None,
        }
    }

    /// Frame sides must be multiples of this: four halvings, then whole windows.
    pub fn multiple(&self) -> usize {
        16 * self.win
    }

    /// Builds the network with freshly initialized weights.
    pub fn init(&self, device: &Device) -> Uformer {
        let c = self.embed;
        let dims = [c, 2 * c, 4 * c, 8 * c, 16 * c, 16 * c, 8 * c, 4 * c, 2 * c];
        let stage = |i: usize| -> Vec<LeWin> {
            (0..self.depths[i])
                .map(|k| {
                    LeWin::new(
                        dims[i],
                        HEADS[i],
                        self.win,
                        k % 2 == 1,
                        self.modulator && i >= 5,
                        device,
                    )
                })
                .collect()
        };
        let down = |a: usize| {
            Conv2dConfig::new([a, 2 * a], [4, 4])
                .with_stride([2, 2])
                .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                .init(device)
        };
        let up = |a: usize, b: usize| {
            ConvTranspose2dConfig::new([a, b], [2, 2])
                .with_stride([2, 2])
                .init(device)
        };
        let conv3 = |a: usize, b: usize| {
            Conv2dConfig::new([a, b], [3, 3])
                .with_padding(PaddingConfig2d::Same)
                .init(device)
        };
        Uformer {
            input: conv3(self.in_channels, c),
            enc: (0..4).map(stage).collect(),
            down: (0..4).map(|i| down(dims[i])).collect(),
            bottleneck: stage(4),
            up: vec![
                up(16 * c, 8 * c),
                up(16 * c, 4 * c),
                up(8 * c, 2 * c),
                up(4 * c, c),
            ],
            dec: (5..9).map(stage).collect(),
            output: conv3(2 * c, 1),
        }
    }
}

/// Window attention with a relative-position bias.
#[derive(Module, Debug)]
pub struct WindowAttention {
    q: Linear,
    kv: Linear,
    proj: Linear,
    /// One bias per head for every relative offset, [(2w−1)², heads].
    bias_table: Param<Tensor<2>>,
    heads: usize,
    win: usize,
}

impl WindowAttention {
    fn new(dim: usize, heads: usize, win: usize, device: &Device) -> WindowAttention {
        let lin = |a, b| {
            LinearConfig::new(a, b)
                .with_initializer(Initializer::Normal {
                    mean: 0.0,
                    std: 0.02,
                })
                .init(device)
        };
        let table = Initializer::Normal {
            mean: 0.0,
            std: 0.02,
        }
        .init([(2 * win - 1) * (2 * win - 1), heads], device);
        WindowAttention {
            q: lin(dim, dim),
            kv: lin(dim, 2 * dim),
            proj: lin(dim, dim),
            bias_table: table,
            heads,
            win,
        }
    }

    /// `x`: [B·nW, N, C] tokens of whole windows; `mask`: [nW, N, N] additive, for shifted windows.
    fn forward(&self, x: Tensor<3>, mask: Option<Tensor<3>>) -> Tensor<3> {
        let [bw, n, c] = x.dims();
        let (h, d) = (self.heads, c / self.heads);
        let split = |t: Tensor<3>| t.reshape([bw, n, h, d]).swap_dims(1, 2);
        let q = split(self.q.forward(x.clone())) * (d as f64).powf(-0.5);
        let kv = self.kv.forward(x);
        let k = split(kv.clone().narrow(2, 0, c));
        let v = split(kv.narrow(2, c, c));
        let device = q.device();
        let index = Tensor::<1, Int>::from_data(
            TensorData::new(relative_index(self.win), [n * n]),
            &device,
        );
        let bias = self
            .bias_table
            .val()
            .select(0, index)
            .reshape([n, n, h])
            .permute([2, 0, 1])
            .unsqueeze::<4>();
        let mut attn = q.matmul(k.swap_dims(2, 3)) + bias;
        if let Some(m) = mask {
            let nw = m.dims()[0];
            let b = bw / nw;
            attn = (attn.reshape([b, nw, h, n, n]) + m.unsqueeze_dim::<4>(1).unsqueeze::<5>())
                .reshape([bw, h, n, n]);
        }
        let out = softmax(attn, 3)
            .matmul(v)
            .swap_dims(1, 2)
            .reshape([bw, n, c]);
        self.proj.forward(out)
    }
}

/// Index into the bias table for every (query, key) pair of a window, row-major.
fn relative_index(win: usize) -> Vec<i64> {
    let n = win * win;
    let span = 2 * win as i64 - 1;
    let mut v = Vec::with_capacity(n * n);
    for i in 0..n {
        for j in 0..n {
            let dy = (i / win) as i64 - (j / win) as i64 + win as i64 - 1;
            let dx = (i % win) as i64 - (j % win) as i64 + win as i64 - 1;
            v.push(dy * span + dx);
        }
    }
    v
}

/// Region label of every token of every shifted window, [nW, N]: after a cyclic shift by
/// `shift`, the last window row and column hold pixels from up to three regions per axis that
/// were not neighbours before the shift. Only this small table is built on the host; the
/// [nW, N, N] mask is expanded from it on the device ([`shift_mask`]).
fn shift_labels(h: usize, w: usize, win: usize, shift: usize) -> Vec<f32> {
    let region = |p: usize, len: usize| {
        if p < len - win {
            0
        } else if p < len - shift {
            1
        } else {
            2
        }
    };
    let (nh, nw, n) = (h / win, w / win, win * win);
    let mut out = Vec::with_capacity(nh * nw * n);
    for wy in 0..nh {
        for wx in 0..nw {
            out.extend((0..n).map(|i| {
                (region(wy * win + i / win, h) * 3 + region(wx * win + i % win, w)) as f32
            }));
        }
    }
    out
}

/// Additive attention mask for shifted windows, [nW, N, N]: −100 between tokens of different
/// regions (they must not attend to each other), 0 elsewhere.
fn shift_mask(h: usize, w: usize, win: usize, shift: usize, device: &Device) -> Tensor<3> {
    let (nwin, n) = ((h / win) * (w / win), win * win);
    let labels = Tensor::<2>::from_data(
        TensorData::new(shift_labels(h, w, win, shift), [nwin, n]),
        device,
    );
    let rows = labels.clone().unsqueeze_dim::<3>(2).expand([nwin, n, n]);
    let differ = rows.not_equal(labels.unsqueeze_dim::<3>(1).expand([nwin, n, n]));
    differ.float() * -100.0
}

/// Locally-enhanced feed-forward: linear ×4, GELU, 3×3 depthwise conv, GELU, linear.
#[derive(Module, Debug)]
pub struct LeFF {
    up: Linear,
    dw: Conv2d,
    down: Linear,
}

impl LeFF {
    fn new(dim: usize, device: &Device) -> LeFF {
        let hidden = 4 * dim;
        let lin = |a, b| {
            LinearConfig::new(a, b)
                .with_initializer(Initializer::Normal {
                    mean: 0.0,
                    std: 0.02,
                })
                .init(device)
        };
        let dw = Conv2dConfig::new([hidden, hidden], [3, 3])
            .with_groups(hidden)
            .with_padding(PaddingConfig2d::Same)
            .init(device);
        LeFF {
            up: lin(dim, hidden),
            dw,
            down: lin(hidden, dim),
        }
    }

    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let h = gelu(self.up.forward(x)).permute([0, 3, 1, 2]);
        let h = gelu(self.dw.forward(h)).permute([0, 2, 3, 1]);
        self.down.forward(h)
    }
}

/// One LeWin transformer block.
#[derive(Module, Debug)]
pub struct LeWin {
    norm1: LayerNorm,
    attn: WindowAttention,
    norm2: LayerNorm,
    ff: LeFF,
    /// Added to every window's tokens before attention (decoder only), [N, C].
    modulator: Option<Param<Tensor<2>>>,
    win: usize,
    shifted: bool,
}

impl LeWin {
    fn new(
        dim: usize,
        heads: usize,
        win: usize,
        shifted: bool,
        modulator: bool,
        device: &Device,
    ) -> LeWin {
        LeWin {
            norm1: LayerNormConfig::new(dim).init(device),
            attn: WindowAttention::new(dim, heads, win, device),
            norm2: LayerNormConfig::new(dim).init(device),
            ff: LeFF::new(dim, device),
            // Like an embedding table: unit-normal start.
            modulator: modulator.then(|| {
                Initializer::Normal {
                    mean: 0.0,
                    std: 1.0,
                }
                .init([win * win, dim], device)
            }),
            win,
            shifted,
        }
    }

    /// The cyclic shift of this block's windows on an `h`×`w` stage: half a window for a
    /// shifted block, none for the others or where the stage is no larger than one window
    /// (nothing to shift across).
    fn shift(&self, h: usize, w: usize) -> usize {
        if self.shifted && h > self.win && w > self.win {
            self.win / 2
        } else {
            0
        }
    }

    /// `x`: [B, H, W, C] with H and W multiples of the window; `mask`: the stage's
    /// [`shift_mask`], required when this block shifts.
    fn forward(&self, x: Tensor<4>, mask: Option<&Tensor<3>>) -> Tensor<4> {
        let [b, h, w, c] = x.dims();
        let win = self.win;
        let shift = self.shift(h, w);
        let mut y = self.norm1.forward(x.clone());
        if shift > 0 {
            y = y.roll(&[-(shift as i64), -(shift as i64)], &[1, 2]);
        }
        let (nh, nw) = (h / win, w / win);
        let mut windows = y
            .reshape([b, nh, win, nw, win, c])
            .permute([0, 1, 3, 2, 4, 5])
            .reshape([b * nh * nw, win * win, c]);
        if let Some(m) = &self.modulator {
            windows = windows + m.val().unsqueeze::<3>();
        }
        let mask = (shift > 0).then(|| {
            mask.expect("blocks() builds the mask for a stage with shifted blocks")
                .clone()
        });
        let a = self.attn.forward(windows, mask);
        let mut y = a
            .reshape([b, nh, nw, win, win, c])
            .permute([0, 1, 3, 2, 4, 5])
            .reshape([b, h, w, c]);
        if shift > 0 {
            y = y.roll(&[shift as i64, shift as i64], &[1, 2]);
        }
        let x = x + y;
        x.clone() + self.ff.forward(self.norm2.forward(x))
    }
}

/// The Uformer.
#[derive(Module, Debug)]
pub struct Uformer {
    input: Conv2d,
    enc: Vec<Vec<LeWin>>,
    down: Vec<Conv2d>,
    bottleneck: Vec<LeWin>,
    up: Vec<ConvTranspose2d>,
    dec: Vec<Vec<LeWin>>,
    output: Conv2d,
}

/// Runs a stage's blocks. The shifted-window mask depends only on the stage's size, so it is
/// built once here for all its shifted blocks.
fn blocks(stage: &[LeWin], mut x: Tensor<4>) -> Tensor<4> {
    let [_, h, w, _] = x.dims();
    let mask = stage
        .iter()
        .find(|b| b.shift(h, w) > 0)
        .map(|b| shift_mask(h, w, b.win, b.shift(h, w), &x.device()));
    for b in stage {
        x = b.forward(x, mask.as_ref());
    }
    x
}

/// Applies an NCHW convolution to channels-last tokens.
fn nhwc(x: Tensor<4>, f: impl FnOnce(Tensor<4>) -> Tensor<4>) -> Tensor<4> {
    f(x.permute([0, 3, 1, 2])).permute([0, 2, 3, 1])
}

impl Uformer {
    /// `x`: [N, C, H, W] with channel 0 the noisy frame; H and W multiples of
    /// [`UformerConfig::multiple`]. Returns [N, 1, H, W]: the noisy frame plus the correction.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let noisy = x.clone().narrow(1, 0, 1);
        let mut h = leaky_relu(self.input.forward(x), 0.01).permute([0, 2, 3, 1]);
        let mut skips = Vec::with_capacity(4);
        for (stage, down) in self.enc.iter().zip(&self.down) {
            let s = blocks(stage, h);
            h = nhwc(s.clone(), |t| down.forward(t));
            skips.push(s);
        }
        h = blocks(&self.bottleneck, h);
        for (stage, up) in self.dec.iter().zip(&self.up) {
            let s = skips.pop().expect("one skip per stage");
            let u = nhwc(h, |t| up.forward(t));
            h = blocks(stage, Tensor::cat(vec![u, s], 3));
        }
        noisy + self.output.forward(h.permute([0, 3, 1, 2]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shift_mask_separates_wrapped_regions() {
        // 16×16 with 8×8 windows shifted by 4: the last window (bottom right) holds four regions.
        let m: Vec<f32> = shift_mask(16, 16, 8, 4, &Device::default())
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        let n = 64;
        assert_eq!(m.len(), 4 * n * n);
        let last = &m[3 * n * n..];
        // Token 0 (region top-left of that window) and token 63 (wrapped corner) must not mix.
        assert_eq!(last[63], -100.0);
        assert_eq!(last[0], 0.0);
        // The first window lies wholly in region 0: no masking.
        assert!(m[..n * n].iter().all(|&v| v == 0.0));
    }

    #[test]
    fn relative_index_spans_the_table() {
        let idx = relative_index(8);
        assert_eq!(idx.len(), 64 * 64);
        assert_eq!(*idx.iter().min().unwrap(), 0);
        assert_eq!(*idx.iter().max().unwrap(), 15 * 15 - 1);
        // The diagonal (zero offset) is the table's centre.
        assert!((0..64).all(|i| idx[i * 64 + i] == 7 * 15 + 7));
    }
}
