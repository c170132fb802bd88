//! The BM3D benchmark of `emccd bench --bm3d`: BSD68 with additive Gaussian noise of known σ,
//! beside the figures BM3D's authors published.

use emccd_classical::bm3d::bm3d;

/// BM3D's published PSNR (dB, 8-bit range) on BSD68 with additive Gaussian noise of σ = 15, 25
/// and 50 (8-bit units), the figures implementations are checked against.
pub const PUBLISHED_BSD68_DB: [(f64, f64); 3] = [(15.0, 31.07), (25.0, 28.57), (50.0, 25.62)];

/// The published BSD68 PSNR at `sigma`, where there is one.
pub fn published_bsd68_db(sigma: f64) -> Option<f64> {
    PUBLISHED_BSD68_DB
        .iter()
        .find(|(s, _)| *s == sigma)
        .map(|(_, db)| *db)
}

/// One image of the Gaussian-noise benchmark: PSNRs (8-bit range) of the noisy and the
/// denoised image, and BM3D's time.
#[derive(Clone, Copy, Debug)]
pub struct GaussianTrial {
    /// The noisy image's PSNR, dB.
    pub noisy_db: f64,
    /// BM3D's PSNR, dB.
    pub denoised_db: f64,
    /// Seconds BM3D took.
    pub seconds: f64,
}

/// Adds N(0, σ²) noise drawn from `seed` to `clean` (`w × h`, 8-bit units), denoises it with
/// [`bm3d`] at the true σ and scores both against `clean`.
pub fn gaussian_trial(clean: &[f32], w: usize, h: usize, sigma: f64, seed: u64) -> GaussianTrial {
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let nd = Normal::new(0.0, sigma).expect("σ is a positive number");
    let noisy: Vec<f32> = clean
        .iter()
        .map(|&c| c + nd.sample(&mut rng) as f32)
        .collect();
    let t = std::time::Instant::now();
    let den = bm3d(&noisy, w, h, sigma, 255.0);
    let seconds = t.elapsed().as_secs_f64();
    GaussianTrial {
        noisy_db: emccd_eval::psnr(&noisy, clean, 255.0),
        denoised_db: emccd_eval::psnr(&den, clean, 255.0),
        seconds,
    }
}

/// One σ of the BSD68 benchmark: the mean over `scenes` of [`gaussian_trial`] (the clean image
/// scaled to 8 bits; scene `i` seeded `1000·σ + i`, so the noise is the same on every run),
/// beside the published figure.
#[derive(Clone, Copy, Debug)]
pub struct Bsd68Row {
    /// Noise standard deviation (8-bit units).
    pub sigma: f64,
    /// Mean PSNR of the noisy images, dB.
    pub noisy_db: f64,
    /// Mean PSNR of BM3D's output, dB.
    pub denoised_db: f64,
    /// The published BM3D figure at this σ, where there is one ([`published_bsd68_db`]).
    pub published_db: Option<f64>,
    /// Mean seconds of BM3D per image.
    pub seconds: f64,
}

impl Bsd68Row {
    /// The header of the table [`Bsd68Row`]'s `Display` writes rows of.
    pub fn header() -> String {
        format!(
            "{:>6} {:>10} {:>10} {:>10} {:>12}",
            "σ", "noisy dB", "BM3D dB", "published", "s/image"
        )
    }
}

/// One row of `emccd bench --bm3d`'s table (under [`Bsd68Row::header`]).
impl std::fmt::Display for Bsd68Row {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let p = self.published_db.map_or("–".into(), |v| format!("{v:.2}"));
        write!(
            f,
            "{:>6} {:>10.2} {:>10.2} {p:>10} {:>12.2}",
            self.sigma, self.noisy_db, self.denoised_db, self.seconds
        )
    }
}

/// [`Bsd68Row`] at `sigma` over the clean images `scenes` (values in [0, 1]).
pub fn bsd68_row(scenes: &[emccd_io::Image], sigma: f64) -> Bsd68Row {
    let (mut pn, mut pd, mut secs) = (0.0, 0.0, 0.0);
    for (i, img) in scenes.iter().enumerate() {
        let clean: Vec<f32> = img.data.iter().map(|v| v * 255.0).collect();
        let seed = 1000 * sigma as u64 + i as u64;
        let t = gaussian_trial(&clean, img.width, img.height, sigma, seed);
        pn += t.noisy_db;
        pd += t.denoised_db;
        secs += t.seconds;
    }
    let n = scenes.len().max(1) as f64;
    Bsd68Row {
        sigma,
        noisy_db: pn / n,
        denoised_db: pd / n,
        published_db: published_bsd68_db(sigma),
        seconds: secs / n,
    }
}
