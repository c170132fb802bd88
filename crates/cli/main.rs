//! `emccd`: the command-line front end. The commands (`commands/`) are glue: parsing, the
//! device from `BURN_DEVICE`, progress bars, messages and exit codes; the work is done by the
//! library crates under `crates/`. The benchmarks `emccd bench` runs live here (`bench/`),
//! since they time the libraries and, for the archive benchmark, this binary itself.

// The standard `println!`/`eprintln!` panic when the stream is closed (`emccd info f | head -1`,
// or a log reader that went away in the middle of a batch). These shadow them for the whole
// binary: once stdout is closed nobody reads the rest, so later output is dropped while the
// command finishes its work (files it writes after its table, temporary files it removes);
// stderr closed loses only the messages.
static STDOUT_CLOSED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Writes to stdout unless it was found closed; a broken pipe marks it closed.
fn write_stdout(args: std::fmt::Arguments) {
    use std::io::Write as _;
    use std::sync::atomic::Ordering;
    if !STDOUT_CLOSED.load(Ordering::Relaxed) {
        if let Err(e) = std::io::stdout().write_fmt(args) {
            if e.kind() == std::io::ErrorKind::BrokenPipe {
                STDOUT_CLOSED.store(true, Ordering::Relaxed);
            }
        }
    }
}
macro_rules! println {
    () => {
        crate::write_stdout(format_args!("\n"))
    };
    ($($t:tt)*) => {
        crate::write_stdout(format_args!("{}\n", format_args!($($t)*)))
    };
}
macro_rules! print {
    ($($t:tt)*) => {
        crate::write_stdout(format_args!($($t)*))
    };
}
macro_rules! eprintln {
    ($($t:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stderr(), $($t)*);
    }};
}

mod bench;
mod commands;
mod common;

use clap::{Parser, Subcommand};

/// Physics-based noise modeling for EMCCD cameras: calibrate a camera, simulate it, synthesize
/// noisy/clean training pairs, and read the files it writes (TIFF/BigTIFF, Andor SIF, FITS).
#[derive(Parser, Debug)]
#[command(name = "emccd", version, about, long_about = None, propagate_version = true)]
struct Cli {
    /// Read files beyond the readers' default limits (frames of 2²⁸ pixels, 2²⁴ frames, 4 GiB
    /// in one allocation), which refuse damaged headers before they are believed. For good
    /// files that are larger; what a file's own length bounds is checked regardless.
    #[arg(long, global = true)]
    no_limits: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Print what an image file holds: size, frames, pixel type and camera metadata.
    Info(commands::info::Args),
    /// Calibrate a camera from its bias, flat, blooming and gain-series stacks.
    Calibrate(commands::calibrate::Args),
    /// Show or create camera profiles.
    #[command(subcommand)]
    Profile(commands::profile::Cmd),
    /// Run the virtual camera: write a calibration acquisition or noisy/clean pairs.
    #[command(subcommand)]
    Simulate(commands::simulate::Cmd),
    /// Add noise from one of the noise models to clean images (training-pair synthesis).
    Synthesize(commands::synthesize::Args),
    /// Denoise raw EMCCD frames: profile preprocessing, then a movie's frames from their
    /// neighbours (default on stacks), iterative BM3D averaged with a network (default on single
    /// frames), iterative BM3D, one BM3D pass, a network, or BM3D refined by one.
    Denoise(commands::denoise::Args),
    /// Count photons below a few tenths of a photo-electron per pixel per frame: each pixel's
    /// most likely rate under the camera's model (or one threshold), coincidences and false
    /// events corrected, an uncertainty per pixel.
    Count(commands::count::Args),
    /// PSNR/SSIM of denoisers (input, BM3D, models) on virtual-camera pairs.
    Evaluate(commands::evaluate::Args),
    /// Train or fine-tune a denoising network on pairs synthesized on the fly.
    Train(commands::train::Args),
    /// Adapt a network to your own recording (no clean data): fine-tune it on its scene.
    Adapt(commands::adapt::Args),
    /// Benchmarks: synthesis (vs emccd-detect), calibration streaming, denoising, BM3D on BSD68.
    Bench(commands::bench::Args),
}

fn main() {
    let cli = Cli::parse();
    if cli.no_limits {
        emccd_io::Limits::set_process(emccd_io::Limits::NONE);
    }
    // Stopped by Ctrl-C or SIGTERM: the destructors that remove half-written outputs do not run,
    // so remove them here; everything already renamed into place is complete.
    let _ = ctrlc::set_handler(|| {
        let n = emccd_io::remove_live_temps();
        eprintln!("\ninterrupted: {n} unfinished output(s) removed");
        std::process::exit(130);
    });
    let result = match cli.command {
        Command::Info(a) => commands::info::run(a),
        Command::Calibrate(a) => commands::calibrate::run(a),
        Command::Profile(c) => commands::profile::run(c),
        Command::Simulate(c) => commands::simulate::run(c),
        Command::Synthesize(a) => commands::synthesize::run(a),
        Command::Train(a) => commands::train::run(a),
        Command::Adapt(a) => commands::adapt::run(a),
        Command::Denoise(a) => commands::denoise::run(a),
        Command::Count(a) => commands::count::run(a),
        Command::Evaluate(a) => commands::evaluate::run(a),
        Command::Bench(a) => commands::bench::run(a),
    };
    if let Err(e) = result {
        // A closed pipe (e.g. `emccd info f --json | head`) is not a failure.
        if e.chain().any(|c| {
            c.downcast_ref::<std::io::Error>()
                .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
        }) {
            std::process::exit(0);
        }
        let lines = emccd_io::error_lines(e.as_ref());
        eprintln!("error: {}", lines[0]);
        for cause in &lines[1..] {
            eprintln!("  caused by: {cause}");
        }
        std::process::exit(2);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_subcommand_parses() {
        for line in [
            "info x.tif --json",
            "profile show default --json",
            "calibrate cal/calibration.toml -o prof --report rep",
            "profile init-default out",
            "simulate calibration -o cal --crop 64x48 --frames 5",
            "simulate pairs --clean a.png --photons 10 --photons 100 -o p",
            "synthesize a.png -o n.tif --model pgn --signal-dn 500",
            "bench --frames 3",
            "adapt rec.tif --profile p --init microscopy -o a.safetensors",
            "adapt rec.tif --profile p --spread 2 --augment --lr 1e-4 -o a.safetensors",
            "profile crop default out --roi 8,8,64x32",
            "simulate pairs --clean a.png --crop 16,16,64x64 -o p",
            "train --clean dir --steps 10 -o m.safetensors",
            "denoise a.tif b.sif -o outdir --exposure-s 0.01",
            "evaluate pairs --method input --method bm3d --json --out ev",
        ] {
            let args = std::iter::once("emccd").chain(line.split_whitespace());
            Cli::try_parse_from(args).unwrap_or_else(|e| panic!("{line}: {e}"));
        }
        assert!(Cli::try_parse_from(["emccd", "simulate", "calibration", "--crop", "64"]).is_err());
    }

    /// The flags of library configs default to the configs' own defaults: one definition.
    #[test]
    fn flag_defaults_are_the_library_defaults() {
        let cli = Cli::try_parse_from(["emccd", "train", "--clean", "d", "-o", "m"]).unwrap();
        let Command::Train(a) = cli.command else {
            panic!("not train")
        };
        assert_eq!(a.cfg, emccd_nn::TrainConfig::default());
        assert_eq!(a.shape, emccd_nn::UNetConfig::DEFAULT);
        // The U-Net's width was `--base` before it was `--channels`; both are taken.
        for flag in ["--channels", "--base"] {
            let cli = Cli::try_parse_from(["emccd", "train", "--clean", "d", "-o", "m", flag, "8"])
                .unwrap();
            let Command::Train(a) = cli.command else {
                panic!("not train")
            };
            assert_eq!(a.shape.channels, 8, "{flag}");
        }
        let cli = Cli::try_parse_from([
            "emccd",
            "train",
            "--clean",
            "d",
            "-o",
            "m",
            "--no-augment",
            "--cic",
            "0,0.05",
        ])
        .unwrap();
        let Command::Train(a) = cli.command else {
            panic!("not train")
        };
        assert!(!a.cfg.augment);
        assert_eq!(a.cfg.cic_e, Some([0.0, 0.05]));
        let cli = Cli::try_parse_from(["emccd", "synthesize", "a.png", "-o", "n.tif"]).unwrap();
        let Command::Synthesize(a) = cli.command else {
            panic!("not synthesize")
        };
        assert_eq!(a.noise, emccd_camera::SceneNoise::default());
        let cli =
            Cli::try_parse_from(["emccd", "simulate", "pairs", "--clean", "a.png", "-o", "p"])
                .unwrap();
        let Command::Simulate(commands::simulate::Cmd::Pairs { camera, .. }) = cli.command else {
            panic!("not simulate pairs")
        };
        assert_eq!(camera.physics, emccd_camera::PhysicalParams::default());
        let cli =
            Cli::try_parse_from(["emccd", "adapt", "r.tif", "--profile", "p", "-o", "a"]).unwrap();
        let Command::Adapt(a) = cli.command else {
            panic!("not adapt")
        };
        assert_eq!(a.cfg, emccd_train::AdaptConfig::default());
        assert!(
            !a.cfg.augment,
            "adapt keeps the recording's orientation unless asked"
        );
        let cli = Cli::try_parse_from([
            "emccd",
            "adapt",
            "r.tif",
            "--profile",
            "p",
            "--augment",
            "-o",
            "a",
        ])
        .unwrap();
        let Command::Adapt(a) = cli.command else {
            panic!("not adapt")
        };
        assert!(a.cfg.augment);
        let cli = Cli::try_parse_from(["emccd", "denoise", "a.tif", "-o", "b.tif"]).unwrap();
        let Command::Denoise(a) = cli.command else {
            panic!("not denoise")
        };
        assert_eq!(a.tiling, emccd_nn::tile::Tiling::default());
    }
}
