//! `emccd evaluate`: PSNR and SSIM of denoisers on noisy/clean pairs from the virtual camera.

use std::path::PathBuf;

use anyhow::Result;
use emccd_denoise::Estimator;
use emccd_eval::evaluation::{evaluate, Contender, PairsDir};

use crate::common::progress;

/// Evaluate denoisers on the pairs `emccd simulate pairs` (or tools/unseen_camera.py) writes:
/// raw noisy frames, ground truth in DN above bias, pairs.toml. Prints a Markdown table of PSNR,
/// SSIM and seconds per 512² frame per method, overall and per light level — the mean
/// photoelectrons per pixel where pairs.toml gives them, else photons at the scene's peak — and,
/// for several pair directories (cameras), per camera too (JSON with --json); --out also gets
/// results.csv and PNG panels (input | each method | ground truth). PSNR uses the ground truth's
/// peak as data range; the paper's convention (images / 65535, range 1) is reported beside it.
/// LPIPS is not computed: its network weights cannot be obtained here. The input is never
/// aligned or rescaled with the ground truth's help. A pair whose truth is a stack as long as
/// its noisy stack is a movie: every frame is scored (PSNR over all of them, SSIM their mean,
/// the panel its middle frame), and the temporal methods use each frame's neighbours.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Directories with pairs.toml (one per camera).
    #[arg(required = true, num_args = 1..)]
    pub pairs: Vec<PathBuf>,
    /// Camera profile used for preprocessing and BM3D's noise parameters. Default: the
    /// `profile` that pairs.toml names (`default`, or a directory relative to pairs.toml),
    /// else the bundled default.
    #[arg(long)]
    pub profile: Option<String>,
    /// Methods: `input`, `bm3d` (one BM3D + GAT pass), `ivst` (iterative BM3D), `blend` (`ivst`
    /// and the `lowlight` network averaged, the default of `denoise`; `blend@8` with the
    /// network's self-ensemble, `blend:MODEL` with another network), `ivst:λ/b,λ/b,…` (iterative BM3D with these passes: the data's weight and the
    /// bin side, e.g. `ivst:1/3,0.7/2,0.4/1`), `hybrid` (the bundled BM3D-refining network), or
    /// a model file (`default`, `microscopy`, `lowlight`, `movie` = the bundled networks; a hybrid model file runs as
    /// the hybrid method, a temporal one as temporal-net), `temporal-net` (the bundled temporal
    /// network on each frame and the 2 before and after it), `temporal` (a movie's frames from their neighbours, the
    /// default window each side or `temporal:K` K; on a still pair, the frame's own estimate:
    /// `ivst` below one count per pixel, one BM3D pass from there), `count` (photon
    /// counting as `emccd count` does it by default, the likelihood, one estimate of the whole
    /// stack given to each of its frames; `count:N` one per N frames; on a still pair, from all
    /// its noisy frames) and `analog` (the analog mean the same way; `analog:N`), for stacks of
    /// a still or slow scene at a fraction of a photo-electron per pixel; repeatable. `MODEL@8` averages the model over 8 flips/transposes
    /// (self-ensemble; 2, 4, 8).
    #[arg(long = "method", required = true, num_args = 1..)]
    pub methods: Vec<String>,
    /// Print JSON instead of Markdown.
    #[arg(long)]
    pub json: bool,
    /// Write results.csv, results.json and PNG panels here.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

pub fn run(a: Args) -> Result<()> {
    let cameras = a
        .pairs
        .iter()
        .map(|d| PairsDir::open(d, a.profile.as_deref()))
        .collect::<Result<Vec<_>, _>>()?;
    // Counting and the analog mean are no denoisers: they come from emccd-count.
    let counting: Vec<Option<emccd_count::Request>> = a
        .methods
        .iter()
        .map(|m| counting(m))
        .collect::<Result<_>>()?;
    let estimators = a
        .methods
        .iter()
        .zip(&counting)
        .filter(|(_, c)| c.is_none())
        .map(|(m, _)| Estimator::parse(m, crate::common::load_model))
        .collect::<Result<Vec<_>, _>>()?;
    let mut denoisers = estimators.iter().map(Estimator::contender);
    let methods: Vec<Contender> = a
        .methods
        .iter()
        .zip(counting)
        .map(|(m, c)| match c {
            Some(req) => count_contender(m, req),
            None => denoisers
                .next()
                .expect("one estimator per denoising method"),
        })
        .collect();
    let total: usize = cameras.iter().map(|c| c.manifest.pair.len()).sum();
    let pb = progress((total * a.methods.len()) as u64, "evaluations");
    let ev = evaluate(&cameras, &methods, a.out.as_deref(), &|| pb.inc(1))?;
    pb.finish_and_clear();
    if a.json {
        println!("{}", serde_json::to_string_pretty(&ev.json())?);
    } else {
        print!("{}", ev.table.markdown());
    }
    Ok(())
}

/// `count[:N]` or `analog[:N]` as a counting request; None for any other method.
fn counting(method: &str) -> Result<Option<emccd_count::Request>> {
    let (stem, per) = match method.split_once(':') {
        Some((s @ ("count" | "analog"), n)) => match n.parse::<usize>() {
            Ok(n) if n > 0 => (s, Some(n)),
            _ => anyhow::bail!("--method {method}: after `:`, the frames per estimate (1 or more)"),
        },
        _ => (method, None),
    };
    Ok(match stem {
        "count" | "analog" => Some(emccd_count::Request {
            per,
            analog: stem == "analog",
            ..Default::default()
        }),
        _ => None,
    })
}

/// A counting method as a contender: each output frame (photo-electrons per pixel per frame)
/// in DN above bias, given to each of the input frames it was counted from.
fn count_contender(name: &str, req: emccd_count::Request) -> Contender<'_> {
    Contender {
        name,
        run: Box::new(move |p, raw, t| {
            let c = emccd_count::count_stack(p, raw, t, &req).map_err(|e| e.0)?;
            let px = p.width * p.height;
            let frames = raw.len() / px;
            let mut out = Vec::with_capacity(raw.len());
            for j in 0..frames {
                let k = j / c.per;
                out.extend(
                    c.rate[k * px..(k + 1) * px]
                        .iter()
                        .map(|&r| (r as f64 * c.dn_per_electron) as f32),
                );
            }
            Ok(out)
        }),
        whole_stack: true,
    }
}
