//! BM3D (Dabov et al. 2007), written here: no maintained Rust crate implements the general
//! two-stage filter (`bm3d_core` targets streak removal). Grayscale, additive white Gaussian
//! noise of known σ; for Poisson–Gaussian data apply [`crate::vst`] first.
//!
//! Stage 1 (hard thresholding): 8×8 blocks every 3 px, block matching in a 39×39 window on
//! pixel distances, groups of up to 16 (a power of two), 2-D biorthogonal-1.5 × 1-D Haar, hard
//! threshold 2.7σ, aggregation weighted by 1/(σ²·kept coefficients) with a Kaiser window (β = 2).
//! Stage 2 (Wiener): matching on the basic estimate, groups of up to 32, 2-D DCT × 1-D Haar,
//! empirical Wiener shrinkage with the basic estimate's spectrum, weights 1/(σ²·‖W‖²). For
//! σ > 40 the reference implementation's very-noisy profile: stage-1 reference blocks every
//! 4 px, groups of 32 with a permissive matching threshold, threshold 2.8σ, and 11×11 Wiener
//! blocks every 6 px. (The 2007 paper's prefiltered matching, its older very-noisy setting,
//! measured 0.15 dB worse on BSD68 at σ = 50 and is not used.)
//!
//! Noise that is not white ([`Covariance`]: a mean of resampled frames) is thresholded and
//! shrunk at each 2-D coefficient's own variance, σ² times [`Covariance::coefficient_variances`],
//! and the aggregation weights sum those variances (Mäkinen, Azzari & Foi 2020, simplified:
//! the blocks of a group are taken as independent). White noise gives exactly the filter above.

use rayon::prelude::*;

use crate::noise::Covariance;

const N1: usize = 8;
const STEP: usize = 3;
const SEARCH: isize = 19;
/// Largest block side used (the very-noisy Wiener stage); blocks live in arrays of this area.
const NMAX: usize = 11;
type Block = [f64; NMAX * NMAX];

#[derive(Clone, Copy)]
struct StageParams {
    /// Block side.
    n: usize,
    /// Distance between reference blocks.
    step: usize,
    max_group: usize,
    /// Matching threshold: mean squared difference per pixel, 8-bit units.
    tau: f64,
}

/// A separable n-point block transform: forward basis rows `f` and synthesis basis rows `t`
/// (the inverse matrix, transposed), both row-major n×n.
struct Transform {
    n: usize,
    f: Vec<f64>,
    /// The synthesis rows transposed: the inverse applied as the forward is.
    t_rows: Vec<f64>,
    /// `f` transposed, and `t_rows` transposed (the synthesis rows themselves).
    f_cols: Vec<f64>,
    t: Vec<f64>,
}

impl Transform {
    /// An orthonormal transform: its inverse is its transpose.
    fn orthonormal(f: Vec<f64>, n: usize) -> Transform {
        Transform::new(n, f.clone(), f)
    }

    /// The transform of `n` samples with analysis rows `f` and synthesis rows `t`.
    fn new(n: usize, f: Vec<f64>, t: Vec<f64>) -> Transform {
        let transposed = |m: &[f64]| (0..n * n).map(|i| m[(i % n) * n + i / n]).collect();
        Transform {
            n,
            t_rows: transposed(&t),
            f_cols: transposed(&f),
            f,
            t,
        }
    }

    /// The biorthogonal 1.5 wavelet transform of 8 samples with its dual basis.
    fn bior15() -> Transform {
        Transform::new(8, bior15_matrix(), bior15_synthesis())
    }

    /// Forward `F·B·Fᵀ`, or inverse `Tᵀ·C·T`, of an n×n block.
    fn apply(&self, input: &[f64], inverse: bool, out: &mut [f64]) {
        // Forward: out[k][l] = Σ f[k][i] b[i][j] f[l][j]; inverse: out[i][j] = Σ t[k][i] c[k][l] t[l][j],
        // i.e. the forward product with Tᵀ's rows.
        let (m, mt) = if inverse {
            (&self.t_rows, &self.t)
        } else {
            (&self.f, &self.f_cols)
        };
        // The block sizes BM3D uses, with the size known to the compiler (it unrolls the
        // products: this was a quarter of BM3D's time); the sums are in the same order.
        match self.n {
            8 => separable::<8>(m, mt, input, out),
            11 => separable::<11>(m, mt, input, out),
            n => separable_n(n, m, input, out),
        }
    }
}

/// `M·B·Mᵀ` of an `N × N` block `input` (row-major), for `N` known at compile time; `mt` is
/// `M` transposed. Each output is the same sum, in the same order, as [`separable_n`]'s, but
/// accumulated a row of outputs at a time, which vector units do side by side.
fn separable<const N: usize>(m: &[f64], mt: &[f64], input: &[f64], out: &mut [f64]) {
    let (m, mt, input) = (&m[..N * N], &mt[..N * N], &input[..N * N]);
    // tmp[y][k] = Σ_j input[y][j]·m[k][j]
    let mut tmp = [[-0.0f64; N]; N];
    for (y, row) in tmp.iter_mut().enumerate() {
        for j in 0..N {
            let v = input[y * N + j];
            let col = &mt[j * N..][..N];
            for k in 0..N {
                row[k] += col[k] * v;
            }
        }
    }
    // out[k][x] = Σ_j m[k][j]·tmp[j][x]
    for k in 0..N {
        let mut acc = [-0.0f64; N];
        for (j, t) in tmp.iter().enumerate() {
            let a = m[k * N + j];
            for x in 0..N {
                acc[x] += a * t[x];
            }
        }
        out[k * N..][..N].copy_from_slice(&acc);
    }
}

/// [`separable`] for any `n`.
fn separable_n(n: usize, m: &[f64], input: &[f64], out: &mut [f64]) {
    let mut tmp = [0.0; NMAX * NMAX];
    for y in 0..n {
        for k in 0..n {
            tmp[y * n + k] = (0..n).map(|j| m[k * n + j] * input[y * n + j]).sum();
        }
    }
    for k in 0..n {
        for x in 0..n {
            out[k * n + x] = (0..n).map(|j| m[k * n + j] * tmp[j * n + x]).sum();
        }
    }
}

/// The biorthogonal 1.5 wavelet transform of 8 samples (3 levels, periodic), rows normalized to
/// unit norm, as BM3D's hard-thresholding stage uses it. Values computed with PyWavelets
/// (`wavedec(e_i, 'bior1.5', mode='periodization', level=3)` for each unit vector).
fn bior15_matrix() -> Vec<f64> {
    let (a, b) = (0.3535533905932738, std::f64::consts::FRAC_1_SQRT_2);
    let (p, q) = (0.2194176492525008, 0.44928375799321585);
    let (u, v, x) = (0.5693593983428461, 0.402347308162278, 0.08350604509028409);
    vec![
        a, a, a, a, a, a, a, a, //
        p, q, q, p, -p, -q, -q, -p, //
        u, v, -v, -u, -x, x, -x, x, //
        -x, x, -x, x, u, v, -v, -u, //
        b, -b, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, //
        0.0, 0.0, b, -b, 0.0, 0.0, 0.0, 0.0, //
        0.0, 0.0, 0.0, 0.0, b, -b, 0.0, 0.0, //
        0.0, 0.0, 0.0, 0.0, 0.0, 0.0, b, -b,
    ]
}

/// The synthesis basis of [`bior15_matrix`] (its inverse, transposed: the dual wavelets at
/// the same normalization), rows as there; `transforms_invert` checks it against the analysis rows.
fn bior15_synthesis() -> Vec<f64> {
    let (a, b) = (0.3535533905932738, std::f64::consts::FRAC_1_SQRT_2);
    let (r, m, e) = (0.3738589410626687, 0.5145585562523474, 0.12153397801643778);
    vec![
        a, a, a, a, a, a, a, a, //
        r, r, r, r, -r, -r, -r, -r, //
        m, m, -m, -m, 0.0, 0.0, 0.0, 0.0, //
        0.0, 0.0, 0.0, 0.0, m, m, -m, -m, //
        b, -b, e, e, 0.0, 0.0, -e, -e, //
        -e, -e, b, -b, e, e, 0.0, 0.0, //
        0.0, 0.0, -e, -e, b, -b, e, e, //
        e, e, 0.0, 0.0, -e, -e, b, -b,
    ]
}

/// Orthonormal n-point DCT-II, row-major n×n (row k = basis k): the Wiener stage's transform,
/// whose rows [`Covariance::coefficient_variances`] takes.
pub fn dct_matrix(n: usize) -> Vec<f64> {
    let mut m = vec![0.0; n * n];
    for k in 0..n {
        let a = if k == 0 {
            (1.0 / n as f64).sqrt()
        } else {
            (2.0 / n as f64).sqrt()
        };
        for j in 0..n {
            m[k * n + j] =
                a * (std::f64::consts::PI * (2 * j + 1) as f64 * k as f64 / (2 * n) as f64).cos();
        }
    }
    m
}

/// Kaiser window (β = 2) of side n, row-major: the outer product of 1-D windows.
pub(crate) fn kaiser(n: usize) -> Vec<f64> {
    fn i0(x: f64) -> f64 {
        let (mut s, mut t) = (1.0, 1.0);
        for k in 1..30 {
            t *= (x / 2.0) / k as f64;
            s += t * t;
        }
        s
    }
    let w1: Vec<f64> = (0..n)
        .map(|j| {
            let r = 2.0 * j as f64 / (n - 1) as f64 - 1.0;
            i0(2.0 * (1.0 - r * r).max(0.0).sqrt()) / i0(2.0)
        })
        .collect();
    (0..n * n).map(|i| w1[i / n] * w1[i % n]).collect()
}

/// In-place orthonormal Haar transform along the group (length a power of two), applied to the
/// first `len` values of every block.
fn haar(g: &mut [Block], len: usize, inverse: bool) {
    let n = g.len();
    let s = std::f64::consts::FRAC_1_SQRT_2;
    let mut tmp = vec![[0.0; NMAX * NMAX]; n];
    let mut size = if inverse { 2 } else { n };
    while (inverse && size <= n) || (!inverse && size > 1) {
        let h = size / 2;
        for i in 0..h {
            for c in 0..len {
                if inverse {
                    let (a, d) = (g[i][c], g[h + i][c]);
                    tmp[2 * i][c] = (a + d) * s;
                    tmp[2 * i + 1][c] = (a - d) * s;
                } else {
                    let (a, b) = (g[2 * i][c], g[2 * i + 1][c]);
                    tmp[i][c] = (a + b) * s;
                    tmp[h + i][c] = (a - b) * s;
                }
            }
        }
        g[..size].copy_from_slice(&tmp[..size]);
        size = if inverse { size * 2 } else { h };
    }
}

/// Reference positions along one axis: every `step` px, plus the last possible one.
pub(crate) fn positions(len: usize, n: usize, step: usize) -> Vec<usize> {
    // A side shorter than a block holds none.
    let Some(last) = len.checked_sub(n) else {
        return Vec::new();
    };
    let mut v: Vec<usize> = (0..=last).step_by(step).collect();
    if *v.last().unwrap_or(&0) != last {
        v.push(last);
    }
    v
}

/// Copies the n×n block at (x, y) into the first n² values of `out`.
fn block(img: &[f64], w: usize, x: usize, y: usize, n: usize, out: &mut [f64]) {
    for r in 0..n {
        out[r * n..(r + 1) * n].copy_from_slice(&img[(y + r) * w + x..(y + r) * w + x + n]);
    }
}

/// The up-to-`max_group` most similar n×n blocks to the one at (x, y) within the search window,
/// by mean squared difference, including the reference itself; truncated to a power of two.
fn matches(
    img: &[f64],
    w: usize,
    h: usize,
    x: usize,
    y: usize,
    p: StageParams,
) -> Vec<(usize, usize)> {
    let n = p.n;
    let mut cand: Vec<(f64, usize, usize)> = Vec::with_capacity(1600);
    let (x0, x1) = (
        (x as isize - SEARCH).max(0) as usize,
        ((x as isize + SEARCH) as usize).min(w - n),
    );
    let (y0, y1) = (
        (y as isize - SEARCH).max(0) as usize,
        ((y as isize + SEARCH) as usize).min(h - n),
    );
    let lim = p.tau * (n * n) as f64;
    let mut r = [0.0; NMAX * NMAX];
    block(img, w, x, y, n, &mut r);
    for cy in y0..=y1 {
        for cx in x0..=x1 {
            let d = if n == 8 {
                distance8(img, w, (cx, cy), &r, lim)
            } else {
                distance_n(n, img, w, (cx, cy), &r, lim)
            };
            if d <= lim {
                cand.push((d, cx, cy));
            }
        }
    }
    // The closest `max_group`, in order; ties in scan order (rows, then columns), as a stable
    // sort of the whole list would leave them. Selecting them first spares sorting the ~1 600
    // candidates of a flat region, which was a quarter of BM3D's time.
    let order = |a: &(f64, usize, usize), b: &(f64, usize, usize)| {
        a.0.total_cmp(&b.0).then((a.2, a.1).cmp(&(b.2, b.1)))
    };
    if cand.len() > p.max_group {
        cand.select_nth_unstable_by(p.max_group, order);
        cand.truncate(p.max_group);
    }
    cand.sort_unstable_by(order);
    let k = if cand.is_empty() {
        1
    } else {
        1usize << (usize::BITS - 1 - cand.len().leading_zeros())
    };
    let mut out: Vec<(usize, usize)> = cand.into_iter().take(k).map(|c| (c.1, c.2)).collect();
    if out.is_empty() {
        out.push((x, y));
    }
    out
}

/// The summed squared difference of the 8 × 8 block at `at` in `img` and the block `r`, row
/// by row, given up once it is over `lim`. This is most of BM3D's time: each row's eight
/// squares are added as a tree (halves, then quarters), which vector units do in three steps
/// where a sum from left to right takes eight dependent ones.
fn distance8(img: &[f64], w: usize, at: (usize, usize), r: &[f64], lim: f64) -> f64 {
    let mut d = 0.0;
    for row in 0..8 {
        let a = &img[(at.1 + row) * w + at.0..][..8];
        let b = &r[row * 8..][..8];
        let sq: [f64; 8] = std::array::from_fn(|j| (a[j] - b[j]) * (a[j] - b[j]));
        let half: [f64; 4] = std::array::from_fn(|j| sq[j] + sq[j + 4]);
        let quarter: [f64; 2] = std::array::from_fn(|j| half[j] + half[j + 2]);
        d += quarter[0] + quarter[1];
        if d > lim {
            break;
        }
    }
    d
}

/// [`distance8`] for an `n × n` block (the rows' squares added from left to right).
fn distance_n(n: usize, img: &[f64], w: usize, at: (usize, usize), r: &[f64], lim: f64) -> f64 {
    let mut d = 0.0;
    for row in 0..n {
        let a = &img[(at.1 + row) * w + at.0..][..n];
        d += a
            .iter()
            .zip(&r[row * n..][..n])
            .map(|(p, q)| (p - q) * (p - q))
            .sum::<f64>();
        if d > lim {
            break;
        }
    }
    d
}

/// The group's 3-D spectrum: each block through `t`, then Haar along the group.
fn spectrum(img: &[f64], w: usize, group: &[(usize, usize)], t: &Transform) -> Vec<Block> {
    let n = t.n;
    let mut b = [0.0; NMAX * NMAX];
    let mut g: Vec<Block> = group
        .iter()
        .map(|&(bx, by)| {
            let mut c = [0.0; NMAX * NMAX];
            block(img, w, bx, by, n, &mut b);
            t.apply(&b, false, &mut c);
            c
        })
        .collect();
    haar(&mut g, n * n, false);
    g
}

/// Inverts a filtered group spectrum and adds its blocks, weighted by `wt` × the Kaiser window,
/// into the aggregation buffers.
#[allow(clippy::too_many_arguments)]
fn put_back(
    mut g: Vec<Block>,
    group: &[(usize, usize)],
    t: &Transform,
    win: &[f64],
    wt: f64,
    w: usize,
    num: &mut [f64],
    den: &mut [f64],
) {
    let n = t.n;
    haar(&mut g, n * n, true);
    let mut b = [0.0; NMAX * NMAX];
    for (c, &(bx, by)) in g.iter().zip(group) {
        t.apply(c, true, &mut b);
        for r in 0..n {
            for q in 0..n {
                let i = (by + r) * w + bx + q;
                let k = wt * win[r * n + q];
                num[i] += k * b[r * n + q];
                den[i] += k;
            }
        }
    }
}

/// Runs `contrib` for every reference block of the stage (in parallel, one pair of buffers per
/// worker) and returns the weighted average, `fallback` where no block landed.
fn aggregate(
    w: usize,
    h: usize,
    p: StageParams,
    fallback: &[f64],
    contrib: &(dyn Fn(usize, usize, &mut [f64], &mut [f64]) + Sync),
) -> Vec<f64> {
    let (xs, ys) = (positions(w, p.n, p.step), positions(h, p.n, p.step));
    let refs: Vec<(usize, usize)> = ys
        .iter()
        .flat_map(|&y| xs.iter().map(move |&x| (x, y)))
        .collect();
    let (num, den) = refs
        .par_chunks(32)
        .fold(
            || (vec![0.0; w * h], vec![0.0; w * h]),
            |(mut num, mut den), chunk| {
                for &(x, y) in chunk {
                    contrib(x, y, &mut num, &mut den);
                }
                (num, den)
            },
        )
        .reduce(
            || (vec![0.0; w * h], vec![0.0; w * h]),
            |(mut a, mut b), (c, d)| {
                a.iter_mut().zip(&c).for_each(|(x, y)| *x += y);
                b.iter_mut().zip(&d).for_each(|(x, y)| *x += y);
                (a, b)
            },
        );
    num.iter()
        .zip(&den)
        .zip(fallback)
        .map(|((n, d), f)| if *d > 0.0 { n / d } else { *f })
        .collect()
}

/// Index `i` of a side of `n` samples extended by half-sample symmetric reflection (period
/// `2n`, the edge sample repeats): valid for any `i`, however far beyond the side.
pub(crate) fn mirror(i: usize, n: usize) -> usize {
    let k = i % (2 * n);
    if k < n {
        k
    } else {
        2 * n - 1 - k
    }
}

/// BM3D of an image smaller than the largest block: mirrored (half-sample symmetric: the edge
/// pixel repeats, so a one-pixel side works too) to at least [`NMAX`] on each side, filtered,
/// and cut back.
fn bm3d_padded(
    noisy: &[f32],
    w: usize,
    h: usize,
    sigma: f64,
    data_range: f64,
    min_step: usize,
    noise: &Covariance,
) -> Vec<f32> {
    let (pw, ph) = (w.max(NMAX), h.max(NMAX));
    let padded: Vec<f32> = (0..pw * ph)
        .map(|i| noisy[mirror(i / pw, h) * w + mirror(i % pw, w)])
        .collect();
    let d = bm3d_spaced(&padded, pw, ph, sigma, data_range, min_step, noise);
    (0..w * h).map(|i| d[(i / w) * pw + i % w]).collect()
}

/// Denoises `noisy` (`w × h`, row-major) with noise std `sigma`, in units where the image spans
/// about `data_range` (the matching thresholds are defined for 8-bit data).
pub fn bm3d(noisy: &[f32], w: usize, h: usize, sigma: f64, data_range: f64) -> Vec<f32> {
    bm3d_spaced(noisy, w, h, sigma, data_range, 1, &Covariance::white())
}

/// [`bm3d`] with its reference blocks at least `min_step` px apart in both stages (each
/// stage's own spacing where it is wider: 3 px, or 4 and 6 above σ = 40). Every pixel is
/// still covered, by fewer overlapping groups; 4 px instead of 3 is 0.56 of the groups to
/// match and filter. The noise is σ² times `noise` ([`Covariance::white`]: white noise of
/// std σ).
pub fn bm3d_spaced(
    noisy: &[f32],
    w: usize,
    h: usize,
    sigma: f64,
    data_range: f64,
    min_step: usize,
    noise: &Covariance,
) -> Vec<f32> {
    assert_eq!(noisy.len(), w * h, "image size");
    if w == 0 || h == 0 {
        return Vec::new();
    }
    let high = sigma * 255.0 / data_range > 40.0;
    let p1 = if high {
        StageParams {
            n: N1,
            step: 4,
            max_group: 32,
            tau: 25000.0,
        }
    } else {
        StageParams {
            n: N1,
            step: STEP,
            max_group: 16,
            tau: 3000.0,
        }
    };
    let p2 = if high {
        StageParams {
            n: 11,
            step: 6,
            max_group: 32,
            tau: 3500.0,
        }
    } else {
        StageParams {
            n: N1,
            step: STEP,
            max_group: 32,
            tau: 400.0,
        }
    };
    let (p1, p2) = (
        StageParams {
            step: p1.step.max(min_step),
            ..p1
        },
        StageParams {
            step: p2.step.max(min_step),
            ..p2
        },
    );
    if w < NMAX || h < NMAX {
        return bm3d_padded(noisy, w, h, sigma, data_range, min_step, noise);
    }
    let scale = 255.0 / data_range;
    let s = sigma * scale;
    let z: Vec<f64> = noisy.iter().map(|&v| v as f64 * scale).collect();
    let lambda = if high { 2.8 } else { 2.7 };

    // Stage 1: hard thresholding.
    let ht = Transform::bior15();
    let win1 = kaiser(N1);
    // Each coefficient's noise variance over σ² (all 1 for white noise), and its threshold.
    let var1 = noise.coefficient_variances(&ht.f, N1);
    let thr: Vec<f64> = var1.iter().map(|v| lambda * s * v.sqrt()).collect();
    let basic = aggregate(w, h, p1, &z, &|x, y, num: &mut [f64], den: &mut [f64]| {
        let group = matches(&z, w, h, x, y, p1);
        let mut g = spectrum(&z, w, &group, &ht);
        // The noise variance of the coefficients kept, over σ².
        let mut kept = 0.0;
        for c in g.iter_mut() {
            for ((v, t), var) in c[..N1 * N1].iter_mut().zip(&thr).zip(&var1) {
                if v.abs() < *t {
                    *v = 0.0;
                } else {
                    kept += var;
                }
            }
        }
        put_back(
            g,
            &group,
            &ht,
            &win1,
            1.0 / (s * s * if kept > 0.0 { kept } else { 1.0 }),
            w,
            num,
            den,
        );
    });

    // Stage 2: empirical Wiener filtering guided by the basic estimate.
    let dct = Transform::orthonormal(dct_matrix(p2.n), p2.n);
    let win2 = kaiser(p2.n);
    let var2 = noise.coefficient_variances(&dct.f, p2.n);
    let fin = aggregate(
        w,
        h,
        p2,
        &basic,
        &|x, y, num: &mut [f64], den: &mut [f64]| {
            let group = matches(&basic, w, h, x, y, p2);
            let gb = spectrum(&basic, w, &group, &dct);
            let mut gn = spectrum(&z, w, &group, &dct);
            // Σ W²·(the coefficient's noise variance over σ²): the estimate's noise over σ².
            let mut wsum = 0.0;
            for (cn, cb) in gn.iter_mut().zip(&gb) {
                for ((vn, vb), r) in cn[..p2.n * p2.n]
                    .iter_mut()
                    .zip(&cb[..p2.n * p2.n])
                    .zip(&var2)
                {
                    let wf = vb * vb / (vb * vb + s * s * r);
                    *vn *= wf;
                    wsum += wf * wf * r;
                }
            }
            put_back(
                gn,
                &group,
                &dct,
                &win2,
                1.0 / (s * s * wsum.max(1e-12)),
                w,
                num,
                den,
            );
        },
    );
    fin.into_iter().map(|v| (v / scale) as f32).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Frames smaller than a block are filtered through a mirrored copy: right size, finite,
    /// and, where both sides have a few pixels, closer to the truth than the input (a flat 40
    /// with σ = 10 noise from a fixed LCG). A one-pixel line mirrors into identical columns,
    /// whose noise does not average, so it is only required to come back whole.
    #[test]
    fn frames_smaller_than_a_block_are_denoised() {
        let mut state = 12345u64;
        let mut noise = || {
            // Sum of 12 uniforms − 6: unit variance, close to normal.
            (0..12)
                .map(|_| {
                    state = state
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    (state >> 11) as f64 / (1u64 << 53) as f64
                })
                .sum::<f64>()
                - 6.0
        };
        for (w, h) in [(1, 1), (3, 20), (10, 10), (1, 40)] {
            let noisy: Vec<f32> = (0..w * h).map(|_| (40.0 + 10.0 * noise()) as f32).collect();
            let d = bm3d(&noisy, w, h, 10.0, 255.0);
            assert_eq!(d.len(), w * h);
            assert!(d.iter().all(|v| v.is_finite()), "{w}×{h}");
            let err = |x: &[f32]| x.iter().map(|v| (*v as f64 - 40.0).powi(2)).sum::<f64>();
            if w.min(h) >= 3 {
                assert!(
                    err(&d) < 0.5 * err(&noisy),
                    "{w}×{h}: {} vs {}",
                    err(&d),
                    err(&noisy)
                );
            }
        }
        assert!(bm3d(&[], 0, 5, 10.0, 255.0).is_empty());
    }

    #[test]
    fn transforms_invert() {
        for (t, n) in [
            (Transform::bior15(), 8),
            (Transform::orthonormal(dct_matrix(8), 8), 8),
            (Transform::orthonormal(dct_matrix(11), 11), 11),
        ] {
            let b: Vec<f64> = (0..n * n).map(|i| (i * 37 % 11) as f64).collect();
            let (mut c, mut r) = (vec![0.0; n * n], vec![0.0; n * n]);
            t.apply(&b, false, &mut c);
            t.apply(&c, true, &mut r);
            assert!(
                b.iter().zip(&r).all(|(a, b)| (a - b).abs() < 1e-9),
                "n = {n}"
            );
        }
        // The sizes known to the compiler give the general product's sums to the bit, forward
        // and inverse (the same products, added in the same order).
        for (t, n) in [
            (Transform::bior15(), 8),
            (Transform::orthonormal(dct_matrix(8), 8), 8),
            (Transform::orthonormal(dct_matrix(11), 11), 11),
        ] {
            let b: Vec<f64> = (0..n * n).map(|i| ((i * 53 % 17) as f64).sin()).collect();
            for (m, mt) in [(&t.f, &t.f_cols), (&t.t_rows, &t.t)] {
                let (mut fast, mut general) = (vec![0.0; n * n], vec![0.0; n * n]);
                if n == 8 {
                    separable::<8>(m, mt, &b, &mut fast);
                } else {
                    separable::<11>(m, mt, &b, &mut fast);
                }
                separable_n(n, m, &b, &mut general);
                assert!(
                    fast.iter()
                        .zip(&general)
                        .all(|(a, b)| a.to_bits() == b.to_bits()),
                    "n = {n}"
                );
            }
        }
        let mut g: Vec<Block> = (0..8)
            .map(|k| std::array::from_fn(|i| ((i + 3 * k) % 7) as f64))
            .collect();
        let orig = g.clone();
        haar(&mut g, NMAX * NMAX, false);
        haar(&mut g, NMAX * NMAX, true);
        assert!(g
            .iter()
            .flatten()
            .zip(orig.iter().flatten())
            .all(|(a, b)| (a - b).abs() < 1e-9));
    }
}
