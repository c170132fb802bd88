//! The covariance of noise that is not white against closed forms: white noise, noise smoothed
//! by a two-tap mean, binning, normalizing, and filters applied in turn.

use emccd_classical::bm3d::dct_matrix as dct;
use emccd_classical::noise::{convolved, filtered, Covariance};

#[test]
fn white_noise_is_one_everywhere_and_binned_stays_white() {
    let w = Covariance::white();
    assert!(w
        .coefficient_variances(&dct(8), 8)
        .iter()
        .all(|&v| v == 1.0));
    for b in 2..4 {
        let binned = w.binned(b);
        assert!(binned
            .coefficient_variances(&dct(8), 8)
            .iter()
            .all(|&v| (v - 1.0).abs() < 1e-12));
    }
}

/// Noise smoothed by a two-tap mean [½ ½]: its covariance is ½, and ¼ at lag 1. A DCT
/// coefficient's variance over white noise's is then the filter's squared response at its
/// frequency, `cos²(πk/2n)`, less the lag-1 products a block's edge cuts off,
/// `¼·(r₀² + r₇²)` for the coefficient's row `r` (exactly, for the DCT).
#[test]
fn smoothed_noise_keeps_its_coarse_coefficients_and_loses_its_fine() {
    let c = filtered(&[0.5, 0.5]);
    assert_eq!(c, vec![0.25, 0.5, 0.25]);
    let mut cov = Covariance::empty();
    cov.add(1.0, &c, &[1.0]);
    let rows = dct(8);
    let v = cov.coefficient_variances(&rows, 8);
    // Row 0 along y is white: along x the coefficients follow the filter.
    for l in 0..8 {
        let edge = 0.25 * (rows[l * 8].powi(2) + rows[l * 8 + 7].powi(2));
        let want = (std::f64::consts::PI * l as f64 / 16.0).cos().powi(2) - edge;
        assert!(
            (v[l] - want).abs() < 1e-12,
            "coefficient {l}: {} against {want}",
            v[l]
        );
    }
    // Along y white: every row of coefficients is the first.
    assert!((0..64).all(|i| (v[i] - v[i % 8]).abs() < 1e-12));
    // Binned by 2, a pair's sum holds its pixels' covariance: var(a + b) = ½ + ½ + 2·¼ = 1.5,
    // over the 2 that white noise of variance 1 would give along the axis, 0.75 (each pixel
    // was 0.5): the coarse noise is larger than a pixel's says.
    let binned = cov.binned(2);
    assert!(
        (binned.variance() - 0.75).abs() < 1e-12,
        "{}",
        binned.variance()
    );
}

#[test]
fn normalizing_scales_to_unit_variance_and_filters_compose() {
    let mut cov = Covariance::empty();
    cov.add(3.0, &filtered(&[0.5, 0.5]), &[1.0]);
    assert!((cov.normalized().variance() - 1.0).abs() < 1e-12);
    assert_eq!(Covariance::empty().normalized(), Covariance::white());
    // Filtering by [½ ½] twice is filtering by [¼ ½ ¼].
    let twice = convolved(&filtered(&[0.5, 0.5]), &filtered(&[0.5, 0.5]));
    let once = filtered(&[0.25, 0.5, 0.25]);
    assert_eq!(twice.len(), once.len());
    assert!(twice.iter().zip(&once).all(|(a, b)| (a - b).abs() < 1e-15));
}
