//! Crops of an image and their orientations: the augmentation every training pair goes
//! through, whether synthesized or cut from a recording.

use rand::Rng;
use rand_pcg::Pcg64;

/// A crop's orientation for [`orient`]: drawn whether or not `augment` is on, so the rest of a
/// run's random sequence does not depend on it; 0 (as recorded) without augmentation.
pub(crate) fn draw_orientation(rng: &mut Pcg64, augment: bool) -> u8 {
    let mode = rng.random_range(0..8u8);
    if augment {
        mode
    } else {
        0
    }
}

/// The `ww × wh` window at (`x0`, `y0`) of a row-major image `w` pixels wide.
pub(crate) fn sub_image(
    src: &[f32],
    w: usize,
    x0: usize,
    y0: usize,
    ww: usize,
    wh: usize,
) -> Vec<f32> {
    (0..ww * wh)
        .map(|i| src[(y0 + i / ww) * w + x0 + i % ww])
        .collect()
}

/// A c×c plane in one of the 8 orientations: optional transpose (`mode & 4`), then optional
/// horizontal (`& 1`) and vertical (`& 2`) flips.
pub(crate) fn orient(src: &[f32], c: usize, mode: u8) -> Vec<f32> {
    let mut out = vec![0f32; c * c];
    for y in 0..c {
        for x in 0..c {
            let (mut u, mut v) = if mode & 4 != 0 { (y, x) } else { (x, y) };
            if mode & 1 != 0 {
                u = c - 1 - u;
            }
            if mode & 2 != 0 {
                v = c - 1 - v;
            }
            out[y * c + x] = src[v * c + u];
        }
    }
    out
}
