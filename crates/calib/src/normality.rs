//! Read-noise normality (paper Fig. 4b): a normal probability plot of one pixel's bias values
//! after removing its mean, and the r² of the straight line it should follow.

use serde::Serialize;

use crate::fit::normal_quantile;

/// One pixel's normal probability plot.
#[derive(Clone, Debug, Serialize)]
pub struct NormalPlot {
    /// Pixel column.
    pub x: usize,
    /// Pixel row.
    pub y: usize,
    /// Samples used.
    pub samples: usize,
    /// Sample std, DN.
    pub std_dn: f64,
    /// Squared correlation of ordered standardized values with normal quantiles.
    pub r2: f64,
    /// Up to 200 (theoretical quantile, standardized value) points for plotting.
    pub points: Vec<(f64, f64)>,
}

/// Builds the plot for one pixel's values (Blom plotting positions).
pub fn normal_plot(x: usize, y: usize, values: &[f32]) -> Option<NormalPlot> {
    let n = values.len();
    if n < 8 {
        return None;
    }
    let m = values.iter().map(|&v| v as f64).sum::<f64>() / n as f64;
    let sd = (values.iter().map(|&v| (v as f64 - m).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt();
    if !(sd > 0.0) {
        return None;
    }
    let mut z: Vec<f64> = values.iter().map(|&v| (v as f64 - m) / sd).collect();
    z.sort_by(f64::total_cmp);
    let q: Vec<f64> = (0..n)
        .map(|i| normal_quantile((i as f64 + 1.0 - 0.375) / (n as f64 + 0.25)))
        .collect();
    let (mq, mz) = (
        q.iter().sum::<f64>() / n as f64,
        z.iter().sum::<f64>() / n as f64,
    );
    let sqz: f64 = q.iter().zip(&z).map(|(a, b)| (a - mq) * (b - mz)).sum();
    let sqq: f64 = q.iter().map(|a| (a - mq).powi(2)).sum();
    let szz: f64 = z.iter().map(|b| (b - mz).powi(2)).sum();
    let r2 = sqz * sqz / (sqq * szz);
    let step = (n / 200).max(1);
    let points = (0..n)
        .step_by(step)
        .chain(std::iter::once(n - 1))
        .map(|i| (q[i], z[i]))
        .collect();
    Some(NormalPlot {
        x,
        y,
        samples: n,
        std_dn: sd,
        r2,
        points,
    })
}
