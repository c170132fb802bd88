//! BM3D (Dabov et al. 2007), written here: no maintained Rust crate implements the general
//! two-stage filter (`bm3d_core` targets streak removal). Grayscale, additive white Gaussian
//! noise of known σ; for Poisson–Gaussian data apply [`crate::vst`] first.
//!
//! Stage 1 (hard thresholding): 8×8 blocks every 3 px, block matching in a 39×39 window on
//! pixel distances, groups of up to 16 (a power of two), 2-D DCT × 1-D Haar, hard threshold
//! 2.7σ, aggregation weighted by 1/(σ²·kept coefficients) with a Kaiser window (β = 2).
//! Stage 2 (Wiener): matching on the basic estimate, groups of up to 32, empirical Wiener
//! shrinkage with the basic estimate's spectrum, weights 1/(σ²·‖W‖²). The parameters are the
//! paper's "normal profile" (σ > 40: larger threshold and 2-D prefiltered matching).

use rayon::prelude::*;

const N1: usize = 8;
const STEP: usize = 3;
const SEARCH: isize = 19;

#[derive(Clone, Copy)]
struct StageParams {
    max_group: usize,
    tau: f64,
}

/// A separable 8-point block transform: forward rows and the exact inverse matrix.
struct Transform {
    f: [[f64; N1]; N1],
    g: [[f64; N1]; N1],
}

impl Transform {
    fn new(f: [[f64; N1]; N1]) -> Transform {
        Transform { f, g: invert8(&f) }
    }
}

/// Inverse of an 8×8 matrix (Gauss–Jordan, partial pivoting); the transforms here are well
/// conditioned (bior1.5: condition number 1.42).
fn invert8(a: &[[f64; N1]; N1]) -> [[f64; N1]; N1] {
    let mut m = *a;
    let mut inv = [[0.0; N1]; N1];
    for (i, row) in inv.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for c in 0..N1 {
        let p = (c..N1).max_by(|&i, &j| m[i][c].abs().total_cmp(&m[j][c].abs())).unwrap_or(c);
        m.swap(c, p);
        inv.swap(c, p);
        let d = m[c][c];
        for k in 0..N1 {
            m[c][k] /= d;
            inv[c][k] /= d;
        }
        for r in 0..N1 {
            if r != c {
                let f = m[r][c];
                for k in 0..N1 {
                    m[r][k] -= f * m[c][k];
                    inv[r][k] -= f * inv[c][k];
                }
            }
        }
    }
    // The inverse's columns are the synthesis basis; transpose to the same "row k = basis k"
    // layout as the forward matrix so that block = Σ_k coef_k · g[k].
    let mut t = [[0.0; N1]; N1];
    for i in 0..N1 {
        for j in 0..N1 {
            t[i][j] = inv[j][i];
        }
    }
    t
}

/// The biorthogonal 1.5 wavelet transform of 8 samples (3 levels, periodic), rows normalized to
/// unit norm, as BM3D's hard-thresholding stage uses it. Values computed with PyWavelets
/// (`wavedec(e_i, 'bior1.5', mode='periodization', level=3)` for each unit vector).
fn bior15_matrix() -> [[f64; N1]; N1] {
    let (a, b) = (0.3535533905932738, 0.7071067811865476);
    let (p, q) = (0.2194176492525008, 0.44928375799321585);
    let (u, v, x) = (0.5693593983428461, 0.402347308162278, 0.08350604509028409);
    [
        [a, a, a, a, a, a, a, a],
        [p, q, q, p, -p, -q, -q, -p],
        [u, v, -v, -u, -x, x, -x, x],
        [-x, x, -x, x, u, v, -v, -u],
        [b, -b, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, b, -b, 0.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, b, -b, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, b, -b],
    ]
}

/// Orthonormal 8-point DCT-II matrix, row k = basis k (the tests check the fixed-size path with it).
#[cfg(test)]
fn dct_matrix() -> [[f64; N1]; N1] {
    let mut m = [[0.0; N1]; N1];
    for (k, row) in m.iter_mut().enumerate() {
        let a = if k == 0 { (1.0 / N1 as f64).sqrt() } else { (2.0 / N1 as f64).sqrt() };
        for (n, v) in row.iter_mut().enumerate() {
            *v = a * (std::f64::consts::PI * (2 * n + 1) as f64 * k as f64 / (2 * N1) as f64).cos();
        }
    }
    m
}

/// Kaiser window (β = 2), outer product of 1-D windows.
fn kaiser() -> [f64; N1 * N1] {
    fn i0(x: f64) -> f64 {
        let (mut s, mut t) = (1.0, 1.0);
        for k in 1..30 {
            t *= (x / 2.0) / k as f64;
            s += t * t;
        }
        s
    }
    let beta = 2.0;
    let w1: Vec<f64> = (0..N1).map(|n| {
        let r = 2.0 * n as f64 / (N1 - 1) as f64 - 1.0;
        i0(beta * (1.0 - r * r).max(0.0).sqrt()) / i0(beta)
    }).collect();
    let mut w = [0.0; N1 * N1];
    for y in 0..N1 {
        for x in 0..N1 {
            w[y * N1 + x] = w1[y] * w1[x];
        }
    }
    w
}

fn dct2(block: &[f64; N1 * N1], t: &Transform, out: &mut [f64; N1 * N1]) {
    let m = &t.f;
    let mut tmp = [0.0; N1 * N1];
    for y in 0..N1 {
        for k in 0..N1 {
            tmp[y * N1 + k] = (0..N1).map(|n| m[k][n] * block[y * N1 + n]).sum();
        }
    }
    for k in 0..N1 {
        for x in 0..N1 {
            out[k * N1 + x] = (0..N1).map(|n| m[k][n] * tmp[n * N1 + x]).sum();
        }
    }
}

fn idct2(coef: &[f64; N1 * N1], t: &Transform, out: &mut [f64; N1 * N1]) {
    let m = &t.g;
    let mut tmp = [0.0; N1 * N1];
    for n in 0..N1 {
        for x in 0..N1 {
            tmp[n * N1 + x] = (0..N1).map(|k| m[k][n] * coef[k * N1 + x]).sum();
        }
    }
    for y in 0..N1 {
        for n in 0..N1 {
            out[y * N1 + n] = (0..N1).map(|k| m[k][n] * tmp[y * N1 + k]).sum();
        }
    }
}

/// In-place orthonormal Haar transform along the group (length a power of two), per coefficient.
fn haar(g: &mut [[f64; N1 * N1]], inverse: bool) {
    let n = g.len();
    let s = std::f64::consts::FRAC_1_SQRT_2;
    let mut tmp = vec![[0.0; N1 * N1]; n];
    if !inverse {
        let mut len = n;
        while len > 1 {
            let h = len / 2;
            for i in 0..h {
                for c in 0..N1 * N1 {
                    let (a, b) = (g[2 * i][c], g[2 * i + 1][c]);
                    tmp[i][c] = (a + b) * s;
                    tmp[h + i][c] = (a - b) * s;
                }
            }
            g[..len].copy_from_slice(&tmp[..len]);
            len = h;
        }
    } else {
        let mut len = 2;
        while len <= n {
            let h = len / 2;
            for i in 0..h {
                for c in 0..N1 * N1 {
                    let (a, d) = (g[i][c], g[h + i][c]);
                    tmp[2 * i][c] = (a + d) * s;
                    tmp[2 * i + 1][c] = (a - d) * s;
                }
            }
            g[..len].copy_from_slice(&tmp[..len]);
            len *= 2;
        }
    }
}

fn positions(len: usize) -> Vec<usize> {
    let last = len - N1;
    let mut v: Vec<usize> = (0..=last).step_by(STEP).collect();
    if *v.last().unwrap_or(&0) != last {
        v.push(last);
    }
    v
}

fn block(img: &[f64], w: usize, x: usize, y: usize) -> [f64; N1 * N1] {
    let mut b = [0.0; N1 * N1];
    for r in 0..N1 {
        b[r * N1..(r + 1) * N1].copy_from_slice(&img[(y + r) * w + x..(y + r) * w + x + N1]);
    }
    b
}

/// Where block distances are measured: pixels of an image, or (for σ > 40) 2-D DCT coefficients
/// hard-thresholded at 2σ, one vector per block position — the paper's prefiltered matching.
enum Space<'a> {
    Pixels(&'a [f64]),
    Coeffs(&'a [[f32; N1 * N1]], usize),
}

/// Thresholded DCT coefficients of every block position (row stride `w − 7`).
fn prefiltered(img: &[f64], w: usize, h: usize, thr: f64, m: &Transform) -> Vec<[f32; N1 * N1]> {
    let bw = w - N1 + 1;
    (0..(h - N1 + 1) * bw)
        .into_par_iter()
        .map(|i| {
            let mut c = [0.0; N1 * N1];
            dct2(&block(img, w, i % bw, i / bw), m, &mut c);
            c.map(|v| if v.abs() < thr { 0.0 } else { v as f32 })
        })
        .collect()
}

/// The up-to-`max` most similar blocks to the one at (x, y) within the search window, by mean
/// squared difference, including the reference itself; truncated to a power of two.
fn matches(space: &Space<'_>, w: usize, h: usize, x: usize, y: usize, p: StageParams) -> Vec<(usize, usize)> {
    let mut cand: Vec<(f64, usize, usize)> = Vec::with_capacity(1600);
    let (x0, x1) = ((x as isize - SEARCH).max(0) as usize, ((x as isize + SEARCH) as usize).min(w - N1));
    let (y0, y1) = ((y as isize - SEARCH).max(0) as usize, ((y as isize + SEARCH) as usize).min(h - N1));
    let lim = p.tau * (N1 * N1) as f64;
    match space {
        Space::Pixels(img) => {
            let r = block(img, w, x, y);
            for cy in y0..=y1 {
                for cx in x0..=x1 {
                    let mut d = 0.0;
                    for row in 0..N1 {
                        let a = &img[(cy + row) * w + cx..(cy + row) * w + cx + N1];
                        let b = &r[row * N1..(row + 1) * N1];
                        d += a.iter().zip(b).map(|(p, q)| (p - q) * (p - q)).sum::<f64>();
                        if d > lim {
                            break;
                        }
                    }
                    if d <= lim {
                        cand.push((d, cx, cy));
                    }
                }
            }
        }
        Space::Coeffs(c, bw) => {
            let r = &c[y * bw + x];
            for cy in y0..=y1 {
                for cx in x0..=x1 {
                    let d: f64 = c[cy * bw + cx].iter().zip(r).map(|(a, b)| ((a - b) * (a - b)) as f64).sum();
                    if d <= lim {
                        cand.push((d, cx, cy));
                    }
                }
            }
        }
    }
    cand.sort_by(|a, b| a.0.total_cmp(&b.0));
    cand.truncate(p.max_group);
    let n = if cand.is_empty() { 1 } else { 1usize << (usize::BITS - 1 - cand.len().leading_zeros()) };
    let mut out: Vec<(usize, usize)> = cand.into_iter().take(n).map(|c| (c.1, c.2)).collect();
    if out.is_empty() {
        out.push((x, y));
    }
    out
}

/// Denoises `noisy` (`w × h`, row-major) with noise std `sigma`, in units where the image spans
/// about `data_range` (the matching thresholds are defined for 8-bit data).
pub fn bm3d(noisy: &[f32], w: usize, h: usize, sigma: f64, data_range: f64) -> Vec<f32> {
    assert_eq!(noisy.len(), w * h, "image size");
    assert!(w >= N1 && h >= N1, "BM3D needs images of at least 8×8");
    let scale = 255.0 / data_range;
    let s = sigma * scale;
    let z: Vec<f64> = noisy.iter().map(|&v| v as f64 * scale).collect();
    let high = s > 40.0;
    let p1 = StageParams { max_group: if high { 32 } else { 16 }, tau: if high { 5000.0 } else { 3000.0 } };
    let p2 = StageParams { max_group: 32, tau: if high { 3500.0 } else { 400.0 } };
    let lambda = if high { 2.8 } else { 2.7 };
    let ht = Transform::new(bior15_matrix());
    let win = kaiser();
    let (xs, ys) = (positions(w), positions(h));
    let refs: Vec<(usize, usize)> = ys.iter().flat_map(|&y| xs.iter().map(move |&x| (x, y))).collect();

    let aggregate = |contrib: &(dyn Fn(usize, usize, &mut [f64], &mut [f64]) + Sync)| -> Vec<f64> {
        let (num, den) = refs
            .par_chunks(64)
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
        num.iter().zip(&den).zip(&z).map(|((n, d), zz)| if *d > 0.0 { n / d } else { *zz }).collect()
    };

    // Stage 1. For σ > 40 blocks are compared after hard-thresholding their 2-D spectra at 2σ.
    let coeffs = if high { prefiltered(&z, w, h, 2.0 * s, &ht) } else { Vec::new() };
    let space1 = if high { Space::Coeffs(&coeffs, w - N1 + 1) } else { Space::Pixels(&z) };
    let basic = aggregate(&|x, y, num: &mut [f64], den: &mut [f64]| {
        let group = matches(&space1, w, h, x, y, p1);
        let mut g: Vec<[f64; N1 * N1]> = group.iter().map(|&(bx, by)| {
            let mut c = [0.0; N1 * N1];
            dct2(&block(&z, w, bx, by), &ht, &mut c);
            c
        }).collect();
        haar(&mut g, false);
        let thr = lambda * s;
        let mut kept = 0usize;
        for c in g.iter_mut() {
            for v in c.iter_mut() {
                if v.abs() < thr {
                    *v = 0.0;
                } else {
                    kept += 1;
                }
            }
        }
        haar(&mut g, true);
        let wt = 1.0 / (s * s * kept.max(1) as f64);
        for (c, &(bx, by)) in g.iter().zip(&group) {
            let mut b = [0.0; N1 * N1];
            idct2(c, &ht, &mut b);
            for r in 0..N1 {
                for q in 0..N1 {
                    let i = (by + r) * w + bx + q;
                    let k = wt * win[r * N1 + q];
                    num[i] += k * b[r * N1 + q];
                    den[i] += k;
                }
            }
        }
    });

    // Stage 2: 8×8 blocks every 3 px; for σ > 40 the reference's 11×11 blocks every 6 px.
    let (n2, step2) = if high { (11, 6) } else { (N1, STEP) };
    let fin = wiener_stage(&z, &basic, w, h, s, n2, step2, p2);
    fin.into_iter().map(|v| (v / scale) as f32).collect()
}

/// Orthonormal n-point DCT-II, row-major n×n (row k = basis k).
fn dct_n(n: usize) -> Vec<f64> {
    let mut m = vec![0.0; n * n];
    for k in 0..n {
        let a = if k == 0 { (1.0 / n as f64).sqrt() } else { (2.0 / n as f64).sqrt() };
        for j in 0..n {
            m[k * n + j] = a * (std::f64::consts::PI * (2 * j + 1) as f64 * k as f64 / (2 * n) as f64).cos();
        }
    }
    m
}

/// Kaiser window (β = 2) of side n, row-major.
fn kaiser_n(n: usize) -> Vec<f64> {
    fn i0(x: f64) -> f64 {
        let (mut s, mut t) = (1.0, 1.0);
        for k in 1..30 {
            t *= (x / 2.0) / k as f64;
            s += t * t;
        }
        s
    }
    let w1: Vec<f64> = (0..n).map(|j| {
        let r = 2.0 * j as f64 / (n - 1) as f64 - 1.0;
        i0(2.0 * (1.0 - r * r).max(0.0).sqrt()) / i0(2.0)
    }).collect();
    (0..n * n).map(|i| w1[i / n] * w1[i % n]).collect()
}

/// `m · B · mᵀ` (forward) or `mᵀ · C · m` (inverse) for an orthonormal n×n `m`.
fn sep2(b: &[f64], m: &[f64], n: usize, inverse: bool) -> Vec<f64> {
    let at = |k: usize, j: usize| if inverse { m[j * n + k] } else { m[k * n + j] };
    let mut tmp = vec![0.0; n * n];
    for y in 0..n {
        for k in 0..n {
            tmp[y * n + k] = (0..n).map(|j| at(k, j) * b[y * n + j]).sum();
        }
    }
    let mut out = vec![0.0; n * n];
    for k in 0..n {
        for x in 0..n {
            out[k * n + x] = (0..n).map(|j| at(k, j) * tmp[j * n + x]).sum();
        }
    }
    out
}

/// Orthonormal Haar along the group for blocks of any size.
fn haar_vec(g: &mut [Vec<f64>], inverse: bool) {
    let n = g.len();
    let s = std::f64::consts::FRAC_1_SQRT_2;
    let mut tmp = g.to_vec();
    if !inverse {
        let mut len = n;
        while len > 1 {
            let h = len / 2;
            for i in 0..h {
                for c in 0..g[0].len() {
                    let (a, b) = (g[2 * i][c], g[2 * i + 1][c]);
                    tmp[i][c] = (a + b) * s;
                    tmp[h + i][c] = (a - b) * s;
                }
            }
            g[..len].clone_from_slice(&tmp[..len]);
            len = h;
        }
    } else {
        let mut len = 2;
        while len <= n {
            let h = len / 2;
            for i in 0..h {
                for c in 0..g[0].len() {
                    let (a, d) = (g[i][c], g[h + i][c]);
                    tmp[2 * i][c] = (a + d) * s;
                    tmp[2 * i + 1][c] = (a - d) * s;
                }
            }
            g[..len].clone_from_slice(&tmp[..len]);
            len *= 2;
        }
    }
}

/// The Wiener stage with n×n blocks every `step` px, matching on the basic estimate.
#[allow(clippy::too_many_arguments)]
fn wiener_stage(z: &[f64], basic: &[f64], w: usize, h: usize, s: f64, n: usize, step: usize, p: StageParams) -> Vec<f64> {
    let m = dct_n(n);
    let win = kaiser_n(n);
    let pos = |len: usize| -> Vec<usize> {
        let last = len - n;
        let mut v: Vec<usize> = (0..=last).step_by(step).collect();
        if *v.last().unwrap_or(&0) != last {
            v.push(last);
        }
        v
    };
    let (xs, ys) = (pos(w), pos(h));
    let refs: Vec<(usize, usize)> = ys.iter().flat_map(|&y| xs.iter().map(move |&x| (x, y))).collect();
    let blk = |img: &[f64], x: usize, y: usize| -> Vec<f64> { (0..n).flat_map(|r| img[(y + r) * w + x..(y + r) * w + x + n].iter().copied()).collect() };
    let lim = p.tau * (n * n) as f64;
    let (num, den) = refs
        .par_chunks(32)
        .fold(
            || (vec![0.0; w * h], vec![0.0; w * h]),
            |(mut num, mut den), chunk| {
                for &(x, y) in chunk {
                    // Matching on the basic estimate.
                    let r = blk(basic, x, y);
                    let (x0, x1) = ((x as isize - SEARCH).max(0) as usize, ((x as isize + SEARCH) as usize).min(w - n));
                    let (y0, y1) = ((y as isize - SEARCH).max(0) as usize, ((y as isize + SEARCH) as usize).min(h - n));
                    let mut cand: Vec<(f64, usize, usize)> = Vec::new();
                    for cy in y0..=y1 {
                        for cx in x0..=x1 {
                            let mut d = 0.0;
                            for row in 0..n {
                                let a = &basic[(cy + row) * w + cx..(cy + row) * w + cx + n];
                                d += a.iter().zip(&r[row * n..(row + 1) * n]).map(|(p, q)| (p - q) * (p - q)).sum::<f64>();
                                if d > lim {
                                    break;
                                }
                            }
                            if d <= lim {
                                cand.push((d, cx, cy));
                            }
                        }
                    }
                    cand.sort_by(|a, b| a.0.total_cmp(&b.0));
                    cand.truncate(p.max_group);
                    let k = if cand.is_empty() { 1 } else { 1usize << (usize::BITS - 1 - cand.len().leading_zeros()) };
                    let mut group: Vec<(usize, usize)> = cand.into_iter().take(k).map(|c| (c.1, c.2)).collect();
                    if group.is_empty() {
                        group.push((x, y));
                    }
                    let tf = |img: &[f64]| -> Vec<Vec<f64>> {
                        let mut g: Vec<Vec<f64>> = group.iter().map(|&(bx, by)| sep2(&blk(img, bx, by), &m, n, false)).collect();
                        haar_vec(&mut g, false);
                        g
                    };
                    let gb = tf(basic);
                    let mut gn = tf(z);
                    let mut wsum = 0.0;
                    for (cn, cb) in gn.iter_mut().zip(&gb) {
                        for (vn, vb) in cn.iter_mut().zip(cb) {
                            let wf = vb * vb / (vb * vb + s * s);
                            *vn *= wf;
                            wsum += wf * wf;
                        }
                    }
                    haar_vec(&mut gn, true);
                    let wt = 1.0 / (s * s * wsum.max(1e-12));
                    for (c, &(bx, by)) in gn.iter().zip(&group) {
                        let b = sep2(c, &m, n, true);
                        for rr in 0..n {
                            for q in 0..n {
                                let i = (by + rr) * w + bx + q;
                                let kk = wt * win[rr * n + q];
                                num[i] += kk * b[rr * n + q];
                                den[i] += kk;
                            }
                        }
                    }
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
    num.iter().zip(&den).zip(basic).map(|((nn, d), b)| if *d > 0.0 { nn / d } else { *b }).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn transforms_invert() {
        let bi = Transform::new(bior15_matrix());
        let b: [f64; 64] = std::array::from_fn(|i| (i * 37 % 11) as f64);
        let (mut c, mut r) = ([0.0; 64], [0.0; 64]);
        dct2(&b, &bi, &mut c);
        idct2(&c, &bi, &mut r);
        assert!(b.iter().zip(&r).all(|(a, b)| (a - b).abs() < 1e-9));
        let m = Transform::new(dct_matrix());
        let b: [f64; 64] = std::array::from_fn(|i| (i * 37 % 11) as f64);
        let (mut c, mut r) = ([0.0; 64], [0.0; 64]);
        dct2(&b, &m, &mut c);
        idct2(&c, &m, &mut r);
        assert!(b.iter().zip(&r).all(|(a, b)| (a - b).abs() < 1e-9));
        let v: Vec<f64> = (0..121).map(|i| (i * 13 % 17) as f64).collect();
        let d11 = dct_n(11);
        let back = sep2(&sep2(&v, &d11, 11, false), &d11, 11, true);
        assert!(v.iter().zip(&back).all(|(a, b)| (a - b).abs() < 1e-9));
        let mut gv: Vec<Vec<f64>> = (0..4).map(|k| (0..121).map(|i| ((i + k) % 5) as f64).collect()).collect();
        let ov = gv.clone();
        haar_vec(&mut gv, false);
        haar_vec(&mut gv, true);
        assert!(gv.iter().flatten().zip(ov.iter().flatten()).all(|(a, b)| (a - b).abs() < 1e-9));
        let mut g: Vec<[f64; 64]> = (0..8).map(|k| std::array::from_fn(|i| ((i + 3 * k) % 7) as f64)).collect();
        let orig = g.clone();
        haar(&mut g, false);
        haar(&mut g, true);
        assert!(g.iter().flatten().zip(orig.iter().flatten()).all(|(a, b)| (a - b).abs() < 1e-9));
    }
}
