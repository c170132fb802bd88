//! Headers that claim more than the file holds: refused when the file is opened, with the file
//! named, before any caller allocates a frame buffer of the claimed size.

use std::path::Path;

/// A little-endian classic TIFF whose one page claims `w`×`h` float32 pixels with the given
/// compression, followed by `payload` bytes of "data".
fn tiff(path: &Path, w: u32, h: u32, compression: u16, payload: usize) {
    let entries: [(u16, u16, u32); 10] = [
        (256, 4, w),  // ImageWidth, LONG
        (257, 4, h),  // ImageLength
        (258, 3, 32), // BitsPerSample, SHORT
        (259, 3, compression as u32),
        (262, 3, 1),              // PhotometricInterpretation: min-is-black
        (273, 4, 8),              // StripOffsets: right after the header
        (277, 3, 1),              // SamplesPerPixel
        (278, 4, h),              // RowsPerStrip
        (279, 4, payload as u32), // StripByteCounts
        (339, 3, 3),              // SampleFormat: IEEE float
    ];
    let ifd = 8 + payload as u32;
    let mut b = Vec::new();
    b.extend_from_slice(b"II*\0");
    b.extend_from_slice(&ifd.to_le_bytes());
    b.extend(std::iter::repeat_n(0u8, payload));
    b.extend_from_slice(&(entries.len() as u16).to_le_bytes());
    for (tag, typ, v) in entries {
        b.extend_from_slice(&tag.to_le_bytes());
        b.extend_from_slice(&typ.to_le_bytes());
        b.extend_from_slice(&1u32.to_le_bytes());
        if typ == 3 {
            b.extend_from_slice(&(v as u16).to_le_bytes());
            b.extend_from_slice(&[0, 0]);
        } else {
            b.extend_from_slice(&v.to_le_bytes());
        }
    }
    b.extend_from_slice(&0u32.to_le_bytes());
    std::fs::write(path, b).unwrap();
}

#[test]
fn claimed_sizes_beyond_the_file_or_the_limit_are_refused_at_open() {
    let dir = tempfile::tempdir().unwrap();
    // A sane control: 16×16 float32 with its 1024 bytes present opens.
    let good = dir.path().join("good.tif");
    tiff(&good, 16, 16, 1, 16 * 16 * 4);
    let (info, f) = emccd_io::read_first(&good).unwrap();
    assert_eq!((info.width, info.height, f.len()), (16, 16, 256));
    for (name, w, h, compression, want) in [
        // 1 kB claiming 65535² float32 uncompressed (17 GB): more than the file holds.
        ("big.tif", 65535, 65535, 1, "but the file holds"),
        // 4294967295²: its byte count overflows 64 bits (the check counts in 128).
        (
            "huge.tif",
            u32::MAX,
            u32::MAX,
            1,
            "(73786976260478468100 bytes), but the file holds",
        ),
        // Deflate-compressed: no more than Deflate's best ratio times the file.
        (
            "deflate.tif",
            65535,
            65535,
            8,
            "more than compression 8 can unpack",
        ),
    ] {
        let p = dir.path().join(name);
        tiff(&p, w, h, compression, 1024);
        let e = match emccd_io::open(&p) {
            Ok(_) => panic!("{name} opened"),
            Err(e) => e.to_string(),
        };
        assert!(e.contains(want) && e.contains(name), "{name}: {e}");
    }
}

/// A compressed page cannot unpack to more than its method's best ratio (Deflate about 1032:1)
/// times the file, whatever the limits: 17000² float32 (1.16 GB) in 1 kB is refused even without
/// them. In 1.2 MB it could be real: the default pixel limit refuses it (2.89·10⁸ pixels, past
/// 2²⁸), and without limits (`--no-limits`) the header is believed.
#[test]
fn a_large_compressed_claim_opens_only_without_limits_and_only_if_it_can_unpack() {
    let dir = tempfile::tempdir().unwrap();
    let small = dir.path().join("small.tif");
    tiff(&small, 17000, 17000, 8, 1024);
    let e = emccd_io::open_with(&small, emccd_io::Limits::NONE)
        .err()
        .expect("refused without limits")
        .to_string();
    assert!(e.contains("more than compression 8 can unpack"), "{e}");
    let p = dir.path().join("wide.tif");
    tiff(&p, 17000, 17000, 8, 1_200_000);
    let e = emccd_io::open(&p)
        .err()
        .expect("refused by default")
        .to_string();
    assert!(e.contains("beyond the limit of 268435456 pixels"), "{e}");
    let r = emccd_io::open_with(&p, emccd_io::Limits::NONE).unwrap();
    assert_eq!((r.info().width, r.info().height), (17000, 17000));
}

/// A FITS header whose axes multiply past 64 bits, and one whose frame is beyond the limit.
#[test]
fn fits_axes_beyond_the_limit_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    for (name, n1, n2) in [
        ("wide.fits", 4294967296u64, 4294967296u64),
        ("big.fits", 65536, 65536),
    ] {
        let mut h = String::new();
        for card in [
            "SIMPLE  =                    T".to_string(),
            "BITPIX  =                   16".into(),
            "NAXIS   =                    3".into(),
            format!("NAXIS1  = {n1:>20}"),
            format!("NAXIS2  = {n2:>20}"),
            format!("NAXIS3  = {:>20}", u32::MAX),
            "END".into(),
        ] {
            h.push_str(&format!("{card:<80}"));
        }
        let mut b = h.into_bytes();
        b.resize(2880 * 2, b' ');
        let p = dir.path().join(name);
        std::fs::write(&p, b).unwrap();
        let e = match emccd_io::open(&p) {
            Ok(_) => panic!("{name} opened"),
            Err(e) => e.to_string(),
        };
        assert!(e.contains(name), "{name}: {e}");
    }
}

/// One character of a real SIF header changed (a digit of the cycle-time field turned into a
/// letter): an error naming the damage, not a file that opens with every later field shifted
/// (a wrong exposure, EM gain 0, 1 °C).
#[test]
fn a_damaged_sif_acquisition_line_is_an_error() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/data/emccd-real/andor-sif/ixon897_avg20.sif");
    let mut bytes = std::fs::read(&src).unwrap();
    // The acquisition line (the third) holds "… 0 1 1.02968 …": 0, the exposure, the cycle time.
    let line3 = bytes
        .iter()
        .enumerate()
        .filter(|(_, &b)| b == b'\n')
        .nth(1)
        .unwrap()
        .0
        + 1;
    let at = line3 + find(&bytes[line3..], b" 1.02968 ").unwrap() + 3;
    assert_eq!(bytes[at], b'0');
    bytes[at] = b'x';
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("damaged.sif");
    std::fs::write(&p, &bytes).unwrap();
    let e = emccd_io::open(&p)
        .err()
        .expect("a damaged header must not open")
        .to_string();
    assert!(
        e.contains("damaged acquisition line") && e.contains("1.x2968"),
        "{e}"
    );
    assert!(e.contains("damaged.sif"), "{e}");
    // The undamaged file still opens, with its 1 s exposure.
    let r = emccd_io::open(&src).unwrap();
    assert_eq!(r.info().metadata.exposure_s, Some(1.0));
}

/// The single-byte changes of the acquisition line that a review found to open with shifted
/// metadata (a space or a sign turned into a digit joins fields, a byte inserted splits one, a
/// binary byte turned printable): at every byte of that line, in four real files, the file is
/// refused or reads the same metadata. (A digit changed or deleted can leave another valid
/// number; a header without a checksum cannot tell, so those are not tried.)
#[test]
fn no_single_byte_change_of_the_sif_acquisition_line_shifts_its_fields() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/emccd-real/andor-sif");
    let mut tried = 0;
    for name in [
        "ixon897_avg20.sif",
        "ixon897_bias_truncated.sif",
        "ixon897_binned_gain56.sif",
        "ccd_cli0.sif",
    ] {
        let src = std::fs::read(dir.join(name)).unwrap();
        let meta = |b: Vec<u8>| {
            emccd_io::from_reader(std::io::Cursor::new(b), emccd_io::Limits::default())
                .map(|r| r.info().clone())
        };
        let want = meta(src.clone()).unwrap();
        let nl: Vec<usize> = (0..src.len())
            .filter(|&i| src[i] == b'\n')
            .take(3)
            .collect();
        for i in nl[1] + 1..nl[2] {
            let replaced: Vec<u8> = [&src[..i], b"7", &src[i + 1..]].concat();
            let inserted: Vec<u8> = [&src[..i], b" ", &src[i..]].concat();
            for (kind, v) in [("7 at", replaced), ("space before", inserted)] {
                // A digit turned into another digit is another valid number: not tried.
                if v == src || (kind == "7 at" && src[i].is_ascii_digit()) {
                    continue;
                }
                tried += 1;
                if let Ok(got) = meta(v) {
                    assert_eq!(
                        got, want,
                        "{name}: {kind} byte {i} opened with other metadata"
                    );
                }
            }
        }
    }
    assert!(tried > 600, "{tried}");
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

/// A stack known to outgrow classic TIFF's 32-bit offsets is written as BigTIFF even under a
/// .tif name (readers take BigTIFF there), instead of failing after hours of work at 4 GiB.
#[test]
fn stacks_beyond_4_gib_are_written_as_bigtiff() {
    use emccd_io::{needs_bigtiff, SampleFormat};
    // 512² float32 frames are 1 MiB each: 4000 fit in 4 GiB, 4095 do not with their headers.
    assert!(!needs_bigtiff(512, 512, SampleFormat::F32, 4000));
    assert!(needs_bigtiff(512, 512, SampleFormat::F32, 4095));
    assert!(!needs_bigtiff(512, 512, SampleFormat::U16, 8000));
    let dir = tempfile::tempdir().unwrap();
    for (frames_hint, version) in [(2, 42u16), (5000, 43)] {
        let p = dir.path().join(format!("s{frames_hint}.tif"));
        let mut w =
            emccd_io::StackWriter::create(&p, 512, 512, SampleFormat::F32, Some(frames_hint))
                .unwrap();
        for _ in 0..2 {
            w.write_frame(&vec![1.5; 512 * 512]).unwrap();
        }
        w.finish().unwrap();
        let b = std::fs::read(&p).unwrap();
        assert_eq!(
            u16::from_le_bytes([b[2], b[3]]),
            version,
            "{frames_hint} frames announced"
        );
        let (info, frames) = emccd_io::read_all(&p).unwrap();
        assert_eq!(info.frames, 2);
        assert!(frames.iter().flatten().all(|&v| v == 1.5));
    }
}
