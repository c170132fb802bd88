//! Movies for a temporal network's training ([`emccd_nn::Inputs::Movie`]): a window of clean
//! frames around a centre frame, made from one clean image by the kinds of motion and change a
//! recording shows, drawn at random and combined — sub-pixel drift, rotation, a smooth
//! travelling deformation, tip-tilt jitter, bleaching, diffusing and blinking spots (which also
//! make one-frame events), a cut to an unrelated scene, and a window at a movie's end, whose
//! missing frames are the mirrored ones (as [`emccd_nn::norm::mirror`] fills them at inference),
//! and now and then a recording of one frame (the frame in every slot). The network
//! has to learn where its neighbours match the frame and where they do not.

use rand::Rng;
use rand_pcg::Pcg64;

use emccd_io::Image;

/// A Gaussian spot that diffuses and blinks: its centre and whether it is lit in each frame of
/// the window (index `d + k`), in crop pixels.
#[derive(Clone, Debug)]
struct Spot {
    sigma: f32,
    amp: f32,
    at: Vec<[f32; 2]>,
    lit: Vec<bool>,
}

/// A smooth travelling displacement wave: `amp · sin(k·x + ω·d + φ)` along `dir`.
#[derive(Clone, Copy, Debug)]
struct Wave {
    amp: f32,
    k: [f32; 2],
    omega: f32,
    phase: f32,
    dir: [f32; 2],
}

/// How one training movie moves and changes across its window, relative to its centre frame.
#[derive(Clone, Debug)]
pub struct Motion {
    k: usize,
    /// Pixels per frame.
    velocity: [f32; 2],
    /// Radians per frame about the crop's centre.
    spin: f32,
    wave: Option<Wave>,
    /// Tip-tilt offset of each frame (zero for the centre).
    jitter: Vec<[f32; 2]>,
    /// Brightness falls by this fraction per frame (`exp(−bleach·d)`).
    bleach: f32,
    /// The scene's brightness under the spots (1 without spots).
    background: f32,
    spots: Vec<Spot>,
    /// Frames `d` with `d·cut.signum() >= |cut|` show another scene.
    cut: Option<isize>,
    /// The window at a movie's end: (side −1 or +1, frames the centre has on that side, 0 or
    /// 1); the frames beyond are mirrored.
    end: Option<(isize, isize)>,
    /// A recording of one frame: every slot of the window shows the frame itself.
    lone: bool,
}

impl Motion {
    /// A random motion for a window of `k` frames each side of crops `crop` px wide.
    pub fn draw(rng: &mut Pcg64, k: usize, crop: usize) -> Motion {
        assert!(k >= 1, "a window of at least one frame each side");
        let n = 2 * k + 1;
        let c = crop as f32;
        let angle = |rng: &mut Pcg64| rng.random::<f32>() * std::f32::consts::TAU;
        let velocity = if rng.random::<f32>() < 0.6 {
            let speed = (rng.random::<f32>() * (3f32 / 0.05).ln()).exp() * 0.05;
            let a = angle(rng);
            [speed * a.cos(), speed * a.sin()]
        } else {
            [0.0; 2]
        };
        let spin = if rng.random::<f32>() < 0.25 {
            (0.1 + 1.4 * rng.random::<f32>()).to_radians() * if rng.random() { 1.0 } else { -1.0 }
        } else {
            0.0
        };
        let wave = (rng.random::<f32>() < 0.25).then(|| {
            let (a, b) = (angle(rng), angle(rng));
            let len = 24.0 + 72.0 * rng.random::<f32>();
            let kk = std::f32::consts::TAU / len;
            Wave {
                amp: 0.3 + 2.2 * rng.random::<f32>(),
                k: [kk * a.cos(), kk * a.sin()],
                omega: (0.05 + 0.25 * rng.random::<f32>()) * std::f32::consts::TAU,
                phase: angle(rng),
                dir: [b.cos(), b.sin()],
            }
        });
        let jitter = if rng.random::<f32>() < 0.25 {
            let s = 0.2 + 1.8 * rng.random::<f32>();
            (0..n)
                .map(|i| {
                    if i == k {
                        [0.0; 2]
                    } else {
                        [s * normal(rng), s * normal(rng)]
                    }
                })
                .collect()
        } else {
            vec![[0.0; 2]; n]
        };
        let bleach = if rng.random::<f32>() < 0.3 {
            0.1 * rng.random::<f32>()
        } else {
            0.0
        };
        let (background, spots) = if rng.random::<f32>() < 0.3 {
            let background = if rng.random() {
                1.0
            } else {
                0.02 + 0.48 * rng.random::<f32>()
            };
            let count = rng.random_range(5..=60);
            let step = 0.2 + 1.8 * rng.random::<f32>();
            let (p_off, p_on) = (0.4 * rng.random::<f32>(), 0.6 * rng.random::<f32>());
            let spots = (0..count)
                .map(|_| {
                    let mut at = vec![[0.0f32; 2]; n];
                    let mut lit = vec![false; n];
                    at[k] = [rng.random::<f32>() * c, rng.random::<f32>() * c];
                    lit[k] = rng.random::<f32>() < 0.8;
                    // From the centre outwards, each way: a random walk and an on/off chain.
                    for dir in [-1isize, 1] {
                        let mut i = k as isize;
                        while (0..n as isize).contains(&(i + dir)) {
                            let (a, b) = (i as usize, (i + dir) as usize);
                            at[b] = [at[a][0] + step * normal(rng), at[a][1] + step * normal(rng)];
                            let u = rng.random::<f32>();
                            lit[b] = if lit[a] { u >= p_off } else { u < p_on };
                            i += dir;
                        }
                    }
                    Spot {
                        sigma: 0.8 + 1.2 * rng.random::<f32>(),
                        amp: 0.1 + 0.9 * rng.random::<f32>(),
                        at,
                        lit,
                    }
                })
                .collect();
            (background, spots)
        } else {
            (1.0, Vec::new())
        };
        let cut = (rng.random::<f32>() < 0.1).then(|| {
            let b = rng.random_range(1..=k as i64) as isize;
            if rng.random() {
                b
            } else {
                -b
            }
        });
        let end = (rng.random::<f32>() < 0.15).then(|| {
            (
                if rng.random() { 1 } else { -1 },
                rng.random_range(0..k as i64) as isize,
            )
        });
        let lone = end.is_none() && rng.random::<f32>() < 0.03;
        Motion {
            lone,
            k,
            velocity,
            spin,
            wave,
            jitter,
            bleach,
            background,
            spots,
            cut,
            end,
        }
    }

    /// The frame whose noisy realization frame `d` of the window shows: `d` itself, or, beyond
    /// a movie's end, its mirror (the same noisy frame twice, as [`emccd_nn::norm::mirror`] gives at inference).
    pub fn shown(&self, d: isize) -> isize {
        if self.lone {
            return 0;
        }
        match self.end {
            Some((side, have)) if d * side > have => -d,
            _ => d,
        }
    }

    /// The scene's brightness under the spots (the centre frame's whole image is scaled by it).
    pub fn background(&self) -> f32 {
        self.background
    }

    /// The spots of frame `d` over a `c`×`c` crop, in the clean image's units.
    pub fn spots(&self, d: isize, c: usize) -> Vec<f32> {
        let i = (d + self.k as isize) as usize;
        let mut out = vec![0f32; c * c];
        for s in self.spots.iter().filter(|s| s.lit[i]) {
            let [sx, sy] = s.at[i];
            let r = (3.0 * s.sigma).ceil() as isize;
            let inv = 1.0 / (2.0 * s.sigma * s.sigma);
            let (cx, cy) = (sx.round() as isize, sy.round() as isize);
            for y in (cy - r).max(0)..(cy + r + 1).min(c as isize) {
                for x in (cx - r).max(0)..(cx + r + 1).min(c as isize) {
                    let (dx, dy) = (x as f32 - sx, y as f32 - sy);
                    out[y as usize * c + x as usize] += s.amp * (-(dx * dx + dy * dy) * inv).exp();
                }
            }
        }
        out
    }

    /// Clean frame `d` (≠ 0) of the window over the `c`×`c` crop at (`x0`, `y0`) of `img`, in
    /// the image's units: the centre frame's content moved, changed and lit as this motion
    /// says, or `other`'s after a cut.
    pub fn frame(
        &self,
        img: &Image,
        other: &Image,
        [x0, y0]: [usize; 2],
        c: usize,
        d: isize,
    ) -> Vec<f32> {
        let df = d as f32;
        let cut = self
            .cut
            .is_some_and(|b| d.signum() == b.signum() && d.abs() >= b.abs());
        let (scene, [ox, oy]) = if cut {
            // Another scene: a crop of the other image at the same place where it fits.
            let ox = x0.min(other.width.saturating_sub(c));
            let oy = y0.min(other.height.saturating_sub(c));
            (other, [ox as f32, oy as f32])
        } else {
            (img, [x0 as f32, y0 as f32])
        };
        let half = (c as f32 - 1.0) / 2.0;
        let (sn, cs) = (-self.spin * df).sin_cos();
        let j = self.jitter[(d + self.k as isize) as usize];
        let gain = self.background * (-self.bleach * df).exp();
        let spots = self.spots(d, c);
        let mut out = vec![0f32; c * c];
        for y in 0..c {
            for x in 0..c {
                // Where the content now at (x, y) was in the centre frame: undo the drift and
                // jitter, then the rotation about the crop's centre, then the wave.
                let (mut u, mut v) = (
                    x as f32 - self.velocity[0] * df - j[0] - half,
                    y as f32 - self.velocity[1] * df - j[1] - half,
                );
                (u, v) = (cs * u - sn * v + half, sn * u + cs * v + half);
                if let Some(w) = self.wave {
                    let s = w.amp * (w.k[0] * u + w.k[1] * v + w.omega * df + w.phase).sin()
                        - w.amp * (w.k[0] * u + w.k[1] * v + w.phase).sin();
                    u -= s * w.dir[0];
                    v -= s * w.dir[1];
                }
                let sample = if cut {
                    bicubic(scene, ox + x as f32, oy + y as f32)
                } else {
                    bicubic(scene, ox + u, oy + v)
                };
                out[y * c + x] = (gain * sample).max(0.0) + spots[y * c + x];
            }
        }
        out
    }
}

/// A standard normal draw (Box–Muller).
fn normal(rng: &mut Pcg64) -> f32 {
    let u = rng.random::<f32>().max(1e-12);
    let v = rng.random::<f32>();
    (-2.0 * u.ln()).sqrt() * (std::f32::consts::TAU * v).cos()
}

/// `img` at (x, y) by Keys' cubic convolution (a = −½), the image mirrored at its borders.
fn bicubic(img: &Image, x: f32, y: f32) -> f32 {
    let (w, h) = (img.width as isize, img.height as isize);
    let at = |i: isize, n: isize| -> usize {
        let p = 2 * (n - 1).max(1);
        let m = i.rem_euclid(p);
        (if m >= n { p - m } else { m }) as usize
    };
    let weights = |t: f32| emccd_classical::resample::keys_weights(t as f64).map(|w| w as f32);
    let (fx, fy) = (x.floor(), y.floor());
    let (wx, wy) = (weights(x - fx), weights(y - fy));
    let (ix, iy) = (fx as isize, fy as isize);
    let mut sum = 0.0;
    for (b, wyb) in wy.iter().enumerate() {
        let row = at(iy - 1 + b as isize, h) * img.width;
        for (a, wxa) in wx.iter().enumerate() {
            sum += wyb * wxa * img.data[row + at(ix - 1 + a as isize, w)];
        }
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn ramp(w: usize, h: usize) -> Image {
        Image {
            width: w,
            height: h,
            data: (0..w * h)
                .map(|i| ((i % w) as f32 * 0.01 + (i / w) as f32 * 0.002).sin().abs())
                .collect(),
        }
    }

    /// A window of 2 frames each side in which nothing moves or changes.
    fn still() -> Motion {
        Motion {
            k: 2,
            velocity: [0.0; 2],
            spin: 0.0,
            wave: None,
            jitter: vec![[0.0; 2]; 5],
            bleach: 0.0,
            background: 1.0,
            spots: Vec::new(),
            cut: None,
            end: None,
            lone: false,
        }
    }

    #[test]
    fn a_still_motion_gives_the_centre_frames_crop() {
        let img = ramp(64, 48);
        let m = still();
        let f = m.frame(&img, &img, [10, 7], 16, 2);
        for y in 0..16 {
            for x in 0..16 {
                let want = img.data[(7 + y) * 64 + 10 + x];
                assert!((f[y * 16 + x] - want).abs() < 1e-5);
            }
        }
    }

    #[test]
    fn a_whole_pixel_drift_moves_the_content_by_that_many_pixels_per_frame() {
        let img = ramp(64, 48);
        let m = Motion {
            velocity: [1.0, 2.0],
            ..still()
        };
        // Frame d shows at (x, y) what the centre showed at (x − d·vx, y − d·vy).
        let f = m.frame(&img, &img, [20, 20], 16, -2);
        for y in 0..16 {
            for x in 0..16 {
                let want = img.data[(20 + y + 4) * 64 + 20 + x + 2];
                assert!((f[y * 16 + x] - want).abs() < 1e-5);
            }
        }
    }

    #[test]
    fn frames_beyond_an_end_show_their_mirror() {
        let m = Motion {
            end: Some((-1, 0)),
            ..Motion::draw(&mut Pcg64::seed_from_u64(3), 2, 16)
        };
        assert_eq!((m.shown(-2), m.shown(-1), m.shown(1)), (2, 1, 1));
        let m = Motion {
            end: Some((1, 1)),
            ..m
        };
        assert_eq!((m.shown(2), m.shown(1), m.shown(-2)), (-2, 1, -2));
        let m = Motion { lone: true, ..m };
        assert!((-2..=2).all(|d| m.shown(d) == 0));
    }

    #[test]
    fn spots_blink_and_stay_where_they_were_drawn() {
        let mut rng = Pcg64::seed_from_u64(9);
        let m = loop {
            let m = Motion::draw(&mut rng, 2, 32);
            if !m.spots.is_empty() {
                break m;
            }
        };
        let centre = m.spots(0, 32);
        let lit = m.spots.iter().filter(|s| s.lit[2]).count();
        assert_eq!(centre.iter().any(|&v| v > 0.0), lit > 0);
        assert!(centre.iter().all(|v| v.is_finite() && *v >= 0.0));
    }
}
