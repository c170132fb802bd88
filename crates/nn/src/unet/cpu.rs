//! The U-Net's forward pass on the CPU, for inference: the same network as [`UNet::forward`],
//! with its convolutions computed as matrix products (the `gemm` crate, the kernels burn's flex
//! backend uses) straight from a channels-last layout.
//!
//! Why not burn's flex convolution: it copies its input to channels-last and into an im2col
//! buffer at every layer and packs the buffer for each 512-pixel tile, which at this network's
//! 16–32 full-resolution channels costs more than the products themselves (measured in
//! docs/networks.md, "Backends"). Here every feature map is stored channels-last with a
//! one-pixel border of zeros, so a 3×3 convolution is nine products of a shifted view of its
//! input with one tap's weights — no copy at all — and the encoder writes its skip connection,
//! and the up-sampling its output, straight into the decoder's concatenated input.

use burn::nn::conv::{Conv2d, ConvTranspose2d};
use burn::prelude::*;
use gemm::{gemm, Parallelism};
use rayon::prelude::*;

use super::{Block, UNet, LEAK};

/// Most pixels per strip a 3×3 convolution computes at once (a strip's input and output stay
/// in L2; 1024–4096 measured within 5 % of each other at 512²).
const STRIP_PIXELS: usize = 2048;

/// A feature map: `h`×`w` pixels of `c` channels, channels-last, inside a one-pixel border of
/// zeros (the 3×3 convolutions' padding), followed by two pixels of slack (read, never used, by
/// the last row's shifted products).
struct Map {
    h: usize,
    w: usize,
    c: usize,
    data: Vec<f32>,
}

impl Map {
    fn zeros(h: usize, w: usize, c: usize) -> Map {
        Map {
            h,
            w,
            c,
            data: vec![0.0; ((h + 2) * (w + 2) + 2) * c],
        }
    }

    /// Offset of interior pixel (y, x)'s first channel.
    fn at(&self, y: usize, x: usize) -> usize {
        ((y + 1) * (self.w + 2) + x + 1) * self.c
    }
}

/// A convolution's weights as burn keeps them, `[out, in, kh, kw]` (a transposed convolution's
/// `[in, out, kh, kw]`), read in place as one `in × out` matrix per tap: the products pack the
/// matrix they are given anyway, so reordering the weights would only copy them once more.
struct Layer {
    ci: usize,
    co: usize,
    weights: Vec<f32>,
    bias: Vec<f32>,
    /// Strides of the `in × out` matrices: between inputs, between outputs.
    in_stride: usize,
    out_stride: usize,
    taps: usize,
}

impl Layer {
    fn new(weight: Tensor<4>, bias: Option<Tensor<1>>, transposed: bool) -> Layer {
        let [d0, d1, kh, kw] = weight.dims();
        let taps = kh * kw;
        let (ci, co, in_stride, out_stride) = if transposed {
            (d0, d1, d1 * taps, taps)
        } else {
            (d1, d0, taps, d1 * taps)
        };
        Layer {
            ci,
            co,
            weights: floats(weight),
            bias: bias.map(floats).unwrap_or_else(|| vec![0.0; co]),
            in_stride,
            out_stride,
            taps,
        }
    }

    fn conv(c: &Conv2d) -> Layer {
        Layer::new(c.weight.val(), c.bias.as_ref().map(|b| b.val()), false)
    }

    fn transposed(c: &ConvTranspose2d) -> Layer {
        Layer::new(c.weight.val(), c.bias.as_ref().map(|b| b.val()), true)
    }

    /// Adds the bias to the first `co` values of every `stride` values of `pixels`.
    fn add_bias(&self, pixels: &mut [f32], stride: usize) {
        for px in pixels.chunks_exact_mut(stride) {
            px.iter_mut().zip(&self.bias).for_each(|(v, b)| *v += b);
        }
    }

    /// `dst[m × co] (+)= lhs[m × ci] · tap t's weights`, row strides given, one thread (the
    /// callers split the work).
    ///
    /// # Safety
    /// m rows of `co` values at stride `dst_rs` from `dst`, and of `ci` at stride `lhs_rs`
    /// from `lhs`, must lie inside their allocations, and `dst`'s must not overlap `lhs`. (The
    /// weights' side is checked here.)
    #[allow(clippy::too_many_arguments)]
    unsafe fn product(
        &self,
        t: usize,
        m: usize,
        dst: *mut f32,
        dst_rs: usize,
        accumulate: bool,
        lhs: *const f32,
        lhs_rs: usize,
    ) {
        assert!(t < self.taps && self.weights.len() == self.ci * self.co * self.taps);
        gemm(
            m,
            self.co,
            self.ci,
            dst,
            1,
            dst_rs as isize,
            accumulate,
            lhs,
            1,
            lhs_rs as isize,
            self.weights.as_ptr().add(t),
            self.out_stride as isize,
            self.in_stride as isize,
            1.0,
            1.0,
            false,
            false,
            false,
            Parallelism::None,
        )
    }
}

fn floats<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .expect("f32 after conversion")
}

/// `dst`'s channels `d_off..d_off + co` ← leaky ReLU(conv3×3(`src`'s channels
/// `s_off..s_off + ci`) + bias). `dst` is a different map of the same size.
fn conv3x3(src: &Map, s_off: usize, k: &Layer, dst: &mut Map, d_off: usize) {
    let (h, w, c_src, c_dst) = (src.h, src.w, src.c, dst.c);
    // What keeps every product inside its strip.
    assert!(
        (dst.h, dst.w) == (h, w) && s_off + k.ci <= c_src && d_off + k.co <= c_dst && k.taps == 9
    );
    let wp = w + 2;
    // Up to four strips a thread, so that the deep levels' few rows still split evenly.
    let rows = (STRIP_PIXELS / wp)
        .min(h.div_ceil(4 * rayon::current_num_threads()))
        .max(1);
    // Output pixel p of a strip is interior pixel (y0 + p / wp, p % wp): the two of each row
    // past its end land on the border, and are put back to zero below.
    let first = dst.at(0, 0);
    let out = &mut dst.data[first..first + h * wp * c_dst];
    out.par_chunks_mut(rows * wp * c_dst)
        .enumerate()
        .for_each(|(s, strip)| {
            let (y0, m) = (s * rows, strip.len() / c_dst);
            for t in 0..9 {
                let (ky, kx) = (t / 3, t % 3);
                let lhs = &src.data[((y0 + ky) * wp + kx) * c_src + s_off..];
                assert!((m - 1) * c_src + k.ci <= lhs.len());
                // SAFETY: m rows of co values at stride c_dst from d_off lie in `strip`
                // (asserted above); m rows of ci at stride c_src lie in `lhs` (checked).
                unsafe {
                    k.product(
                        t,
                        m,
                        strip.as_mut_ptr().add(d_off),
                        c_dst,
                        t > 0,
                        lhs.as_ptr(),
                        c_src,
                    )
                }
            }
            for (p, px) in strip.chunks_exact_mut(c_dst).enumerate() {
                let v = &mut px[d_off..d_off + k.co];
                if p % wp >= w {
                    v.fill(0.0);
                } else {
                    for (v, b) in v.iter_mut().zip(&k.bias) {
                        let t = *v + b;
                        *v = if t >= 0.0 { t } else { LEAK as f32 * t };
                    }
                }
            }
        });
}

/// Interior rows of `dst` in parallel: `f(y, row)` gets row y's `w·c` interior values.
fn rows_of(dst: &mut Map, f: impl Fn(usize, &mut [f32]) + Sync) {
    let (w, c) = (dst.w, dst.c);
    let stride = (w + 2) * c;
    let first = dst.at(0, 0);
    dst.data[first..first + dst.h * stride]
        .par_chunks_mut(stride)
        .enumerate()
        .for_each(|(y, row)| f(y, &mut row[..w * c]));
}

/// A stride-2 2×2 convolution of `src`'s channels `s_off..s_off + ci` into a new map of half
/// the size (no activation: the next block's first convolution follows).
fn down(src: &Map, s_off: usize, k: &Layer) -> Map {
    assert!(s_off + k.ci <= src.c && k.taps == 4);
    let mut dst = Map::zeros(src.h / 2, src.w / 2, k.co);
    let (c_src, w2) = (src.c, dst.w);
    rows_of(&mut dst, |y, row| {
        for t in 0..4 {
            let (i, j) = (t / 2, t % 2);
            let lhs = &src.data[src.at(2 * y + i, j) + s_off..];
            assert!((w2 - 1) * 2 * c_src + k.ci <= lhs.len());
            // SAFETY: w2 rows of co in `row` (a row of dst); w2 rows of ci at stride 2·c_src
            // in `lhs` (checked).
            unsafe {
                k.product(
                    t,
                    w2,
                    row.as_mut_ptr(),
                    k.co,
                    t > 0,
                    lhs.as_ptr(),
                    2 * c_src,
                )
            }
        }
        k.add_bias(row, k.co);
    });
    dst
}

/// A stride-2 2×2 transposed convolution of `src` (all its channels) into channels
/// `0..co` of `dst`, twice its size.
fn up(src: &Map, k: &Layer, dst: &mut Map) {
    // What keeps every product inside its row.
    assert!(
        (dst.h, dst.w) == (2 * src.h, 2 * src.w) && src.c == k.ci && k.co <= dst.c && k.taps == 4
    );
    let (c_dst, w) = (dst.c, src.w);
    rows_of(dst, |yy, row| {
        let (y, i) = (yy / 2, yy % 2);
        let lhs = &src.data[src.at(y, 0)..];
        for j in 0..2 {
            let t = i * 2 + j;
            // SAFETY: w rows of co at stride 2·c_dst from pixel j lie in `row` (a row of dst,
            // 2w pixels); w rows of ci lie in `lhs` (a row of src).
            unsafe {
                k.product(
                    t,
                    w,
                    row.as_mut_ptr().add(j * c_dst),
                    2 * c_dst,
                    false,
                    lhs.as_ptr(),
                    k.ci,
                )
            }
        }
        k.add_bias(row, c_dst);
    });
}

/// A U-Net's weights laid out for [`CpuUNet::forward`].
pub struct CpuUNet {
    enc: Vec<[Layer; 2]>,
    down: Vec<Layer>,
    bottom: [Layer; 2],
    up: Vec<Layer>,
    dec: Vec<[Layer; 2]>,
    /// The 1×1 output layer.
    out: Layer,
    residual: Option<usize>,
    unshuffle: usize,
}

fn block_layers(b: &Block) -> [Layer; 2] {
    [Layer::conv(&b.c1), Layer::conv(&b.c2)]
}

/// A [`Block`]'s two convolutions over all of `x`'s channels, into `dst`'s channels from
/// `d_off` on.
fn block(b: &[Layer; 2], x: &Map, dst: &mut Map, d_off: usize) {
    let mut mid = Map::zeros(x.h, x.w, b[0].co);
    conv3x3(x, 0, &b[0], &mut mid, 0);
    conv3x3(&mid, 0, &b[1], dst, d_off);
}

impl CpuUNet {
    /// `net`'s current weights, copied out of burn.
    pub fn new(net: &UNet) -> CpuUNet {
        CpuUNet {
            enc: net.enc.iter().map(block_layers).collect(),
            down: net.down.iter().map(Layer::conv).collect(),
            bottom: block_layers(&net.bottom),
            up: net.up.iter().map(Layer::transposed).collect(),
            dec: net.dec.iter().map(block_layers).collect(),
            out: Layer::conv(&net.out),
            residual: net.residual,
            unshuffle: net.unshuffle,
        }
    }

    /// [`UNet::forward`] of one `[channels, height, width]` input, channel-major; returns the
    /// `[height, width]` output.
    ///
    /// # Panics
    /// If the input is not `channels` planes of that size, `channels` not the network's, or a
    /// side not a multiple of the network's [`super::UNetConfig::multiple`] (as burn would).
    pub fn forward(&self, input: &[f32], channels: usize, height: usize, width: usize) -> Vec<f32> {
        let u = self.unshuffle;
        let multiple = u << self.enc.len();
        let inputs = self.enc.first().unwrap_or(&self.bottom)[0].ci / (u * u);
        assert!(
            input.len() == channels * height * width
                && channels == inputs
                && height.is_multiple_of(multiple)
                && width.is_multiple_of(multiple),
            "a {channels}×{height}×{width} input for a U-Net of {inputs} inputs and sides multiples of {multiple}"
        );
        let (h, w) = (height / u, width / u);
        // The input, each u×u block's pixels folded into channels (c·u + i)·u + j.
        let mut feat = Map::zeros(h, w, channels * u * u);
        for y in 0..h {
            for xx in 0..w {
                let at = feat.at(y, xx);
                let px = &mut feat.data[at..at + feat.c];
                for c in 0..channels {
                    for i in 0..u {
                        for j in 0..u {
                            px[(c * u + i) * u + j] =
                                input[(c * height + u * y + i) * width + u * xx + j];
                        }
                    }
                }
            }
        }
        // Encoder: each level's block writes its skip into the second half of the decoder's
        // concatenated input (the first half is the up-sampled path, as in `Tensor::cat`).
        let mut cats = Vec::with_capacity(self.enc.len());
        for (e, d) in self.enc.iter().zip(&self.down) {
            let co = e[1].co;
            let mut cat = Map::zeros(feat.h, feat.w, 2 * co);
            block(e, &feat, &mut cat, co);
            feat = down(&cat, co, d);
            cats.push(cat);
        }
        let mut bottom = Map::zeros(feat.h, feat.w, self.bottom[1].co);
        block(&self.bottom, &feat, &mut bottom, 0);
        feat = bottom;
        for (u_layer, d) in self.up.iter().zip(&self.dec) {
            let mut cat = cats.pop().expect("one skip per level");
            up(&feat, u_layer, &mut cat);
            feat = Map::zeros(cat.h, cat.w, d[1].co);
            block(d, &cat, &mut feat, 0);
        }
        // The 1×1 output layer, unfolded back to full resolution, plus the residual channel.
        let (ow, ob) = (&self.out.weights, &self.out.bias);
        let uu = u * u;
        let mut out = vec![0f32; height * width];
        out.par_chunks_mut(width * u)
            .enumerate()
            .for_each(|(y, rows)| {
                for xx in 0..w {
                    let px = &feat.data[feat.at(y, xx)..][..feat.c];
                    for o in 0..uu {
                        let mut v = ob[o];
                        for (c, a) in px.iter().enumerate() {
                            v += a * ow[o * feat.c + c];
                        }
                        let (i, j) = (o / u, o % u);
                        let full = (u * y + i) * width + u * xx + j;
                        let base = self
                            .residual
                            .map_or(0.0, |r| input[r * height * width + full]);
                        rows[i * width + u * xx + j] = base + v;
                    }
                }
            });
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::unet::UNetConfig;

    /// Random weights (burn's initializers draw them, output layer included) give every layer a
    /// say; the input is a smooth pattern plus a ramp, on non-square frames so that a mix-up of
    /// width and height cannot pass. `residual`: the input channel the output is added to, set
    /// after building, since a network built with a residual other than 0 starts with its
    /// output layer at zero (and would then return that channel whatever its layers did).
    fn agrees(cfg: UNetConfig, residual: Option<usize>, h: usize, w: usize) {
        let d = crate::cpu();
        let mut net = cfg.init(&d);
        net.residual = residual;
        let c = cfg.in_channels;
        let x: Vec<f32> = (0..c * h * w)
            .map(|i| ((i as f32 * 0.37).sin() + (i % w) as f32 / w as f32) * 0.8)
            .collect();
        let want: Vec<f32> = net
            .forward(Tensor::<4>::from_data(
                TensorData::new(x.clone(), [1, c, h, w]),
                &d,
            ))
            .into_data()
            .try_into_vec::<f32>()
            .unwrap();
        let got = CpuUNet::new(&net).forward(&x, c, h, w);
        assert_eq!(got.len(), want.len());
        // Both sum the same products in f32, in another order: the difference is rounding,
        // a few ulps of the largest partial sums (|·| ≲ 10 here).
        let worst = got
            .iter()
            .zip(&want)
            .map(|(a, b)| (a - b).abs())
            .fold(0f32, f32::max);
        assert!(worst < 1e-4, "{cfg:?} {h}×{w}: differs by {worst}");
        // The layers' part is not negligible beside the residual channel.
        let base = residual.map_or(0.0, |r| x[r * h * w]);
        assert!(
            (got[0] - base).abs() > 1e-3,
            "{cfg:?}: the layers add nothing"
        );
    }

    #[test]
    fn the_cpu_forward_pass_is_burns_u_net() {
        let small = UNetConfig {
            channels: 8,
            levels: 2,
            ..UNetConfig::DEFAULT
        };
        agrees(small, Some(0), 24, 40);
        // A temporal network's inputs and residual channel.
        let movie = UNetConfig {
            in_channels: 6,
            ..small
        };
        agrees(movie, Some(2), 16, 32);
        // A direct output (no residual).
        agrees(small, None, 32, 16);
        // Pixel-unshuffled, with a residual on the third input.
        let folded = UNetConfig {
            unshuffle: 2,
            in_channels: 3,
            ..small
        };
        agrees(folded, Some(2), 32, 48);
        // The default size, four levels deep; at 16 × 32 its deepest map is 1 × 2 px.
        agrees(UNetConfig::DEFAULT, Some(0), 32, 48);
        agrees(UNetConfig::DEFAULT, Some(0), 16, 32);
    }

    #[test]
    #[should_panic(expected = "sides multiples of 4")]
    fn a_frame_the_network_cannot_take_is_refused() {
        let cfg = UNetConfig {
            channels: 4,
            levels: 2,
            ..UNetConfig::DEFAULT
        };
        let net = CpuUNet::new(&cfg.init(&crate::cpu()));
        net.forward(&[0.0; 2 * 8 * 10], 2, 8, 10);
    }
}
