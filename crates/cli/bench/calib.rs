//! The calibration streaming benchmark of `emccd bench --calibration`: how fast a stack is
//! decoded and reduced to per-pixel mean and variance, beside a plain read of the same bytes.

use std::io::Read;
use std::path::Path;
use std::time::Instant;

use anyhow::{anyhow, Result};

/// Frame side of the benchmark's stack.
pub const SIDE: usize = 512;

/// What [`streaming`] measured.
#[derive(Clone, Copy, Debug)]
pub struct Streaming {
    /// Frames in the stack.
    pub frames: usize,
    /// Bytes of the TIFF file.
    pub bytes: f64,
    /// Seconds to read the bytes and do nothing with them (the reference).
    pub reference_s: f64,
    /// Seconds to decode them and accumulate per-pixel mean and variance.
    pub decode_s: f64,
    /// This process's peak resident memory before the stack was read and after, MiB (NaN
    /// where the system does not report it): streaming keeps the difference small.
    pub peak_mib: [f64; 2],
    /// Worker threads (rayon's pool).
    pub threads: usize,
}

impl Streaming {
    /// Decoding throughput, GB/s.
    pub fn decode_gb_s(&self) -> f64 {
        self.bytes / self.decode_s / 1e9
    }

    /// The reference read's throughput, GB/s.
    pub fn reference_gb_s(&self) -> f64 {
        self.bytes / self.reference_s / 1e9
    }
}

/// The report `emccd bench --calibration` prints: both passes, their ratio against the
/// 1 GB/s target, and the peak memory.
impl std::fmt::Display for Streaming {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "calibration streaming: {} frames of {SIDE}×{SIDE} u16 ({:.0} MB TIFF, page cache), {} threads",
            self.frames,
            self.bytes / 1e6,
            self.threads
        )?;
        writeln!(f, "{:<46} {:>9} {:>9}", "pass", "s", "GB/s")?;
        let row = |f: &mut std::fmt::Formatter<'_>, what: &str, s: f64, gb: f64| {
            writeln!(f, "{what:<46} {s:>9.3} {gb:>9.2}")
        };
        row(
            f,
            "reference: read the bytes, no decoding",
            self.reference_s,
            self.reference_gb_s(),
        )?;
        row(
            f,
            "emccd: decode + per-pixel mean and variance",
            self.decode_s,
            self.decode_gb_s(),
        )?;
        writeln!(f)?;
        let met = if self.decode_gb_s() >= 1.0 {
            "met"
        } else {
            "not met"
        };
        writeln!(
            f,
            "ratio to the reference read: {:.2}  (target ≥ 1 GB/s: {met})",
            self.reference_s / self.decode_s
        )?;
        write!(
            f,
            "peak memory: {:.1} MiB (before reading the stack: {:.1} MiB; the stack itself is {:.0} MiB)",
            self.peak_mib[1],
            self.peak_mib[0],
            self.bytes / (1 << 20) as f64
        )
    }
}

/// Writes a stack of `frames` (at least 2) 512×512 16-bit frames to `dir/stack.tif` (a fixed pattern, no
/// randomness), reads it once as plain bytes and once through the calibration's streaming
/// statistics (both from the page cache), and removes it.
pub fn streaming(dir: &Path, frames: usize) -> Result<Streaming> {
    let frames = frames.max(2);
    let path = dir.join("stack.tif");
    let io = |e: emccd_io::Error| anyhow!("{}: {e}", path.display());
    let mut wr =
        emccd_io::StackWriter::create(&path, SIDE, SIDE, emccd_io::SampleFormat::U16, Some(frames))
            .map_err(io)?;
    let mut f = vec![0f32; SIDE * SIDE];
    for k in 0..frames {
        for (i, v) in f.iter_mut().enumerate() {
            *v = 500.0 + ((i * 7919 + k * 104729) % 23) as f32;
        }
        wr.write_frame(&f).map_err(io)?;
    }
    wr.finish().map_err(io)?;
    let os = |e: std::io::Error| anyhow!("{}: {e}", path.display());
    let bytes = std::fs::metadata(&path).map_err(os)?.len() as f64;
    let peak_before = peak_rss_mib();
    // Reference: reading the same bytes from the page cache and doing nothing with them.
    let t = Instant::now();
    let mut file = std::fs::File::open(&path).map_err(os)?;
    let mut buf = vec![0u8; 1 << 20];
    let mut sink = 0u64;
    loop {
        let n = file.read(&mut buf).map_err(os)?;
        if n == 0 {
            break;
        }
        sink = sink.wrapping_add(buf[n - 1] as u64);
    }
    let reference_s = t.elapsed().as_secs_f64();
    std::hint::black_box(sink);
    let t = Instant::now();
    let (_, st) =
        emccd_calib::stats::accumulate(&path, None, 2, &[], None, None, &emccd_calib::Silent)?;
    let decode_s = t.elapsed().as_secs_f64();
    std::hint::black_box(st.mean());
    let _ = std::fs::remove_file(&path);
    Ok(Streaming {
        frames,
        bytes,
        reference_s,
        decode_s,
        peak_mib: [peak_before, peak_rss_mib()],
        threads: rayon::current_num_threads(),
    })
}

/// Peak resident memory of this process so far (Linux's `VmHWM`), MiB; NaN elsewhere.
fn peak_rss_mib() -> f64 {
    let kib = || -> Option<f64> {
        let s = std::fs::read_to_string("/proc/self/status").ok()?;
        let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
        line.split_whitespace().nth(1)?.parse().ok()
    };
    kib().map_or(f64::NAN, |k| k / 1024.0)
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_streaming_bench_reads_what_it_wrote_and_removes_it() {
        let dir = tempfile::tempdir().unwrap();
        let r = super::streaming(dir.path(), 1).unwrap();
        // At least two frames, so a variance exists; 512×512 u16 each, plus the TIFF's headers.
        assert_eq!(r.frames, 2);
        assert!(r.bytes >= (2 * 512 * 512 * 2) as f64);
        assert!(r.decode_s > 0.0 && r.reference_s > 0.0);
        // On Linux both are reported (a process's peak is never zero), and a peak never falls.
        let [before, after] = r.peak_mib;
        if cfg!(target_os = "linux") {
            assert!(before > 0.0 && after >= before, "{before} → {after} MiB");
        }
        assert!(r.decode_gb_s().is_finite() && r.reference_gb_s().is_finite());
        assert!(!dir.path().join("stack.tif").exists());
    }
}
