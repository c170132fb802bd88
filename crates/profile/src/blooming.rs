//! Blooming and its exact inverse, and the preprocessing of paper eq. 4: beside the profile
//! whose fit they apply, so calibration and the networks need no camera model for them.
//!
//! Blooming adds to every pixel a share `x` of its column's mean: `B[Y] = Y + x·colmean(Y)`.
//! Since `colmean(B[Y]) = (1+x)·colmean(Y)`, the inverse is `B⁻¹(D) = D − x/(1+x)·colmean(D)`.

/// Column means of a row-major frame (f64 accumulation).
pub fn column_means(frame: &[f32], width: usize) -> Vec<f64> {
    let height = frame.len() / width;
    let mut acc = vec![0f64; width];
    for row in frame.chunks_exact(width) {
        for (a, &v) in acc.iter_mut().zip(row) {
            *a += v as f64;
        }
    }
    for a in &mut acc {
        *a /= height.max(1) as f64;
    }
    acc
}

/// Applies blooming `B[Y] = Y + x·colmean(Y)` in place.
pub fn apply_blooming(frame: &mut [f32], width: usize, x: f64) {
    let cm = column_means(frame, width);
    for row in frame.chunks_exact_mut(width) {
        for (v, &m) in row.iter_mut().zip(&cm) {
            *v = (*v as f64 + x * m) as f32;
        }
    }
}

/// Removes blooming in place: `D − x/(1+x)·colmean(D)`.
pub fn remove_blooming(frame: &mut [f32], width: usize, x: f64) {
    apply_blooming(frame, width, -x / (1.0 + x));
}

/// Paper eq. 4 in place: `D' = B⁻¹(D) − FPN_t`. Pass `x = 0` to skip blooming removal.
pub fn preprocess(frame: &mut [f32], width: usize, x: f64, fpn_t: &[f32]) {
    assert_eq!(frame.len(), fpn_t.len(), "FPN map and frame differ in size");
    if x != 0.0 {
        remove_blooming(frame, width, x);
    }
    for (v, &f) in frame.iter_mut().zip(fpn_t) {
        *v -= f;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blooming_inverse_is_exact() {
        let w = 5;
        let orig: Vec<f32> = (0..30)
            .map(|i| ((i * 37) % 11) as f32 * 10.0 + 3.0)
            .collect();
        let mut f = orig.clone();
        apply_blooming(&mut f, w, 0.07);
        assert!(f.iter().zip(&orig).any(|(a, b)| (a - b).abs() > 1.0));
        remove_blooming(&mut f, w, 0.07);
        for (a, b) in f.iter().zip(&orig) {
            assert!((a - b).abs() < 1e-4, "{a} vs {b}");
        }
    }
}
