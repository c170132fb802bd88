//! Inference on frames of any size: reflect-pad to the network's multiple, run overlapping tiles,
//! and blend them with weights that ramp down linearly across the overlap, so no seam shows.
//! Optionally averages the network over flips and transposes of the frame (geometric
//! self-ensemble), which trades time for a little PSNR.

use burn::prelude::*;

use crate::model::Net;
use crate::unet::CpuUNet;

/// How a tile goes through the network: a U-Net on the CPU through [`CpuUNet`] (the same
/// network, faster than burn's CPU convolution: docs/networks.md), anything else through burn.
enum Forward<'a> {
    Gemm(Box<CpuUNet>),
    Burn(&'a Net, &'a Device),
}

impl<'a> Forward<'a> {
    fn new(net: &'a Net, device: &'a Device) -> Forward<'a> {
        match net {
            Net::UNet(u) if *device == Device::flex() => Forward::Gemm(Box::new(CpuUNet::new(u))),
            _ => Forward::Burn(net, device),
        }
    }

    /// The network's [H, W] output for a [C, H, W] input.
    fn run(&self, tile: Vec<f32>, [c, h, w]: [usize; 3]) -> Vec<f32> {
        match self {
            Forward::Gemm(u) => u.forward(&tile, c, h, w),
            Forward::Burn(net, device) => {
                let x = Tensor::<4>::from_data(TensorData::new(tile, [1, c, h, w]), *device);
                net.forward(x)
                    .into_data()
                    .convert::<f32>()
                    .try_into_vec::<f32>()
                    .unwrap_or_default()
            }
        }
    }
}

/// Tiling parameters (with the `clap` feature, `emccd denoise`'s tiling flags).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct Tiling {
    /// Tile side for large frames, px, at least 64 (a 512×512 frame runs in one piece).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = Tiling::default().tile, value_parser = parse_tile))]
    pub tile: usize,
    /// Overlap between tiles, px (at most half a tile; more is reduced to that).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = Tiling::default().overlap))]
    pub overlap: usize,
}

/// A tile side as a flag gives it, checked ([`Tiling::check_tile`]).
#[cfg(feature = "clap")]
fn parse_tile(s: &str) -> std::result::Result<usize, String> {
    let t = s.parse::<usize>().unwrap_or(0);
    Tiling::check_tile(t).map_err(|e| e.to_string())
}

impl Tiling {
    /// The smallest tile side: a smaller one leaves the network too little context.
    pub const MIN_TILE: usize = 64;

    /// `tile` if it is a usable tile side (at least [`Tiling::MIN_TILE`]).
    pub fn check_tile(tile: usize) -> crate::Result<usize> {
        if tile >= Tiling::MIN_TILE {
            Ok(tile)
        } else {
            Err(crate::Error::Model(format!(
                "a tile is at least {} px",
                Tiling::MIN_TILE
            )))
        }
    }
}

impl Default for Tiling {
    fn default() -> Tiling {
        Tiling {
            tile: 512,
            overlap: 32,
        }
    }
}

/// A network input: `channels` planes of `width`×`height`, channel-major ([C, H, W]).
#[derive(Clone, Copy, Debug)]
pub struct Planes<'a> {
    /// The pixels, plane after plane.
    pub data: &'a [f32],
    /// Planes.
    pub channels: usize,
    /// Width.
    pub width: usize,
    /// Height.
    pub height: usize,
}

/// Where the tiles of a frame go: the frame padded to the network's multiple, the tile size
/// along each axis, the overlap actually used, and the tile origins.
#[derive(Clone, Debug)]
pub struct Layout {
    /// Padded width and height.
    pub padded: (usize, usize),
    /// Tile width and height.
    pub tile: (usize, usize),
    /// Overlap, px.
    pub overlap: usize,
    /// Tile origins along x and along y.
    pub starts: (Vec<usize>, Vec<usize>),
}

impl Tiling {
    /// The layout of a `width`×`height` frame for a network needing multiples of `multiple`.
    pub fn layout(&self, width: usize, height: usize, multiple: usize) -> Layout {
        let round_up = |v: usize| v.div_ceil(multiple) * multiple;
        let (pw, ph) = (round_up(width), round_up(height));
        let t = round_up(self.tile.max(multiple));
        let (tw, th) = (t.min(pw), t.min(ph));
        let o = self.overlap.min(tw / 2).min(th / 2);
        Layout {
            padded: (pw, ph),
            tile: (tw, th),
            overlap: o,
            starts: (starts(pw, tw, o), starts(ph, th, o)),
        }
    }
}

fn reflect(i: isize, n: usize) -> usize {
    let n = n as isize;
    let mut i = i;
    if n == 1 {
        return 0;
    }
    while i < 0 || i >= n {
        i = if i < 0 { -i } else { 2 * (n - 1) - i };
    }
    i as usize
}

/// Tile origins covering `len` with tiles of `t` overlapping by at least `o`.
fn starts(len: usize, t: usize, o: usize) -> Vec<usize> {
    if len <= t {
        return vec![0];
    }
    let step = t - o;
    let mut v: Vec<usize> = (0..)
        .map(|k| k * step)
        .take_while(|&s| s + t < len)
        .collect();
    v.push(len - t);
    v
}

/// Weight of position `i` in a tile of `t` starting at `s` in a frame of `len`: ramps over the
/// overlap except at the frame's own edges.
fn ramp(i: usize, s: usize, t: usize, o: usize, len: usize) -> f32 {
    let o = o.max(1) as f32;
    let lo = if s == 0 {
        1.0
    } else {
        ((i as f32 + 0.5) / o).min(1.0)
    };
    let hi = if s + t >= len {
        1.0
    } else {
        (((t - i) as f32 - 0.5) / o).min(1.0)
    };
    lo.min(hi).max(1e-3)
}

/// Runs `net` (which needs sides that are multiples of `multiple`) on `input`; returns the
/// [H, W] output.
pub fn run(net: &Net, input: Planes, multiple: usize, tiling: Tiling, device: &Device) -> Vec<f32> {
    run_with(&Forward::new(net, device), input, multiple, tiling)
}

fn run_with(forward: &Forward, input: Planes, multiple: usize, tiling: Tiling) -> Vec<f32> {
    let Planes {
        data: input,
        channels,
        width,
        height,
    } = input;
    let Layout {
        padded: (pw, ph),
        tile: (tw, th),
        overlap: o,
        starts: (xs, ys),
    } = tiling.layout(width, height, multiple);
    let mut acc = vec![0f32; pw * ph];
    let mut wsum = vec![0f32; pw * ph];
    for &y0 in &ys {
        for &x0 in &xs {
            let mut tile = vec![0f32; channels * tw * th];
            for c in 0..channels {
                for y in 0..th {
                    let sy = reflect((y0 + y) as isize, height);
                    for x in 0..tw {
                        let sx = reflect((x0 + x) as isize, width);
                        tile[(c * th + y) * tw + x] = input[(c * height + sy) * width + sx];
                    }
                }
            }
            let out = forward.run(tile, [channels, th, tw]);
            for y in 0..th {
                let wy = ramp(y, y0, th, o, ph);
                for x in 0..tw {
                    let w = wy * ramp(x, x0, tw, o, pw);
                    let i = (y0 + y) * pw + x0 + x;
                    acc[i] += w * out[y * tw + x];
                    wsum[i] += w;
                }
            }
        }
    }
    let mut res = Vec::with_capacity(width * height);
    for y in 0..height {
        for x in 0..width {
            let i = y * pw + x;
            res.push(acc[i] / wsum[i]);
        }
    }
    res
}

/// Where pixel (x, y) of a `width`×`height` frame lands under dihedral transform `t` (0..8:
/// bit 2 transposes, then bit 0 flips x and bit 1 flips y); returns the index in the transformed
/// frame, whose width is `height` when transposed.
fn dihedral(t: usize, x: usize, y: usize, width: usize, height: usize) -> usize {
    let (mut tx, mut ty, tw, th) = if t & 4 != 0 {
        (y, x, height, width)
    } else {
        (x, y, width, height)
    };
    if t & 1 != 0 {
        tx = tw - 1 - tx;
    }
    if t & 2 != 0 {
        ty = th - 1 - ty;
    }
    ty * tw + tx
}

/// [`run`] averaged over the first `k` of the eight flips/transposes of the frame (k = 1: plain
/// `run`; 2: + horizontal flip; 4: + vertical flips; 8: + transposes). The network saw all eight
/// orientations in training, so each is an equally good estimate with partly independent errors.
pub fn run_ensemble(
    net: &Net,
    planes: Planes,
    multiple: usize,
    tiling: Tiling,
    k: usize,
    device: &Device,
) -> Vec<f32> {
    let k = k.clamp(1, 8);
    let forward = Forward::new(net, device);
    if k == 1 {
        return run_with(&forward, planes, multiple, tiling);
    }
    let Planes {
        data: input,
        channels,
        width,
        height,
    } = planes;
    let n = width * height;
    let mut acc = vec![0f32; n];
    let mut moved = vec![0f32; channels * n];
    for t in 0..k {
        for c in 0..channels {
            for y in 0..height {
                for x in 0..width {
                    moved[c * n + dihedral(t, x, y, width, height)] = input[c * n + y * width + x];
                }
            }
        }
        let (tw, th) = if t & 4 != 0 {
            (height, width)
        } else {
            (width, height)
        };
        let moved_planes = Planes {
            data: &moved,
            channels,
            width: tw,
            height: th,
        };
        let out = run_with(&forward, moved_planes, multiple, tiling);
        for y in 0..height {
            for x in 0..width {
                acc[y * width + x] += out[dihedral(t, x, y, width, height)];
            }
        }
    }
    acc.iter_mut().for_each(|v| *v /= k as f32);
    acc
}

#[cfg(test)]
mod tests {
    use super::{dihedral, Tiling};

    #[test]
    fn a_tile_is_at_least_the_smallest_side() {
        assert_eq!(Tiling::check_tile(64).unwrap(), 64);
        assert_eq!(Tiling::check_tile(512).unwrap(), 512);
        let e = Tiling::check_tile(63).unwrap_err().to_string();
        assert!(e.contains("at least 64 px"), "{e}");
    }

    #[test]
    fn dihedral_transforms_are_permutations() {
        let (w, h) = (5, 3);
        for t in 0..8 {
            let mut seen = vec![false; w * h];
            for y in 0..h {
                for x in 0..w {
                    seen[dihedral(t, x, y, w, h)] = true;
                }
            }
            assert!(
                seen.iter().all(|&s| s),
                "transform {t} is not a permutation"
            );
        }
        // Transpose then flip x: the top-left pixel goes to the top-right of the 3-wide frame.
        assert_eq!(dihedral(5, 0, 0, w, h), 2);
    }
}
