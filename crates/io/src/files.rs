//! The identity of files: for refusing a run that would overwrite one of its inputs, for naming
//! each input's output, and for recording what an output was made from.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::{Error, Result};

/// What identifies a file, for comparing files rather than spellings: its device and inode where
/// it exists (so `./x.tif`, `a/../x.tif`, and symbolic and hard links to `x.tif` are one file),
/// else the absolute path it would have.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub enum FileId {
    /// An existing file.
    Inode(u64, u64),
    /// A file not (yet) there.
    Path(PathBuf),
}

impl FileId {
    /// The identity of `p`.
    pub fn of(p: &Path) -> FileId {
        #[cfg(unix)]
        {
            use std::os::unix::fs::MetadataExt;
            if let Ok(m) = std::fs::metadata(p) {
                return FileId::Inode(m.dev(), m.ino());
            }
        }
        FileId::Path(canonical(p))
    }
}

/// The absolute path a file has or would have (its folder resolved).
fn canonical(p: &Path) -> PathBuf {
    if let Ok(c) = p.canonicalize() {
        return c;
    }
    match (
        p.parent().filter(|d| !d.as_os_str().is_empty()),
        p.file_name(),
    ) {
        (Some(d), Some(f)) => d
            .canonicalize()
            .map(|d| d.join(f))
            .unwrap_or_else(|_| p.to_path_buf()),
        (None, Some(f)) => std::env::current_dir()
            .map(|d| d.join(f))
            .unwrap_or_else(|_| p.to_path_buf()),
        _ => p.to_path_buf(),
    }
}

/// Refuses `out` where it is `input` (however spelled or linked): the message names the output
/// and `what` the input is ("the input x.tif", "the --init model").
pub fn refuse_overwrite(out: &Path, input: &Path, what: &str) -> Result<()> {
    if FileId::of(out) == FileId::of(input) {
        return Err(overwrite_error(out, what));
    }
    Ok(())
}

fn overwrite_error(out: &Path, what: &str) -> Error {
    Error::Usage(format!(
        "{}: the output is {what}; choose another output, inputs are never overwritten",
        out.display()
    ))
}

/// The first output that is one of the inputs (the same file, however named), as (index in
/// `outputs`, index in `inputs`). Each file's identity is looked up once: thousands of inputs
/// are compared in memory, not on disk.
pub fn input_among(outputs: &[PathBuf], inputs: &[PathBuf]) -> Option<(usize, usize)> {
    let ids: HashMap<FileId, usize> = inputs
        .iter()
        .enumerate()
        .rev()
        .map(|(k, p)| (FileId::of(p), k))
        .collect();
    outputs
        .iter()
        .enumerate()
        .find_map(|(o, p)| ids.get(&FileId::of(p)).map(|&k| (o, k)))
}

/// Where each input's result goes: `out` itself for one input without `suffix`, else
/// `out/STEM{suffix}` (`x.tif` → `out/x_denoised.tif`). Refused before anything runs: an output
/// that is one of the inputs (it would be replaced, or overwritten before it is read), two
/// inputs that would share an output, an output that is a folder, and a folder of outputs that
/// is a Zarr store.
pub fn output_paths(inputs: &[PathBuf], out: &Path, suffix: Option<&str>) -> Result<Vec<PathBuf>> {
    let outs: Vec<PathBuf> = inputs
        .iter()
        .map(|input| match suffix {
            Some(suffix) => {
                let stem = input
                    .file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_else(|| "frame".into());
                out.join(format!("{stem}{suffix}"))
            }
            None => out.to_path_buf(),
        })
        .collect();
    // outs[i] is inputs[i]'s output.
    if let Some((i, k)) = input_among(&outs, inputs) {
        let (input, other) = (&inputs[i], &inputs[k]);
        let what = if other == input {
            format!("the input {}", other.display())
        } else {
            format!(
                "the input {}, the output for {}",
                other.display(),
                input.display()
            )
        };
        return Err(overwrite_error(&outs[i], &what));
    }
    // A folder of outputs that is a Zarr store would get files that are no Zarr nodes (zarr
    // readers then warn of each); an output that is a folder cannot be replaced by a file, and
    // finding that after the earlier inputs' outputs were placed would leave them.
    if suffix.is_some() && crate::zarr::is_zarr(out) {
        return Err(Error::Usage(
            "a Zarr store; several inputs' files go into a plain folder".into(),
        )
        .with_path(out));
    }
    if let Some(o) = outs.iter().find(|o| o.is_dir()) {
        return Err(Error::Usage(
            "a folder is in the way of this output; remove it or choose another -o".into(),
        )
        .with_path(o));
    }
    for (i, o) in outs.iter().enumerate() {
        if let Some(j) = outs[..i].iter().position(|p| p == o) {
            return Err(Error::Usage(format!(
                "{} and {} would both be written to {}; run them separately (different outputs) or rename one",
                inputs[j].display(),
                inputs[i].display(),
                o.display()
            )));
        }
    }
    Ok(outs)
}

/// What an input file was when it was read: its real path, size and modification time (a file
/// rewritten in between is another input). Recorded in an output's provenance.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct FileStamp {
    /// The file's canonical path.
    pub file: String,
    /// Its size in bytes.
    pub bytes: u64,
    /// Its modification time, ns since the Unix epoch, where the file system keeps one.
    pub modified_ns: Option<String>,
}

impl FileStamp {
    /// The stamp of `path` now.
    pub fn of(path: &Path) -> Result<FileStamp> {
        let m = std::fs::metadata(path).map_err(|e| Error::from(e).with_path(path))?;
        let modified_ns = m
            .modified()
            .ok()
            .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
            .map(|d| d.as_nanos().to_string());
        let real = std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf());
        Ok(FileStamp {
            file: real.display().to_string(),
            bytes: m.len(),
            modified_ns,
        })
    }
}

/// Refuses a write of `bytes` into the folder `dir` (or the nearest existing folder above it)
/// when its filesystem has less room, before anything is written: a run that would fill the
/// disk fails at once, with the sizes, rather than after hours with half its outputs. Where the
/// free space cannot be read (not Unix, a filesystem that does not say), nothing is refused.
pub fn check_room(dir: &Path, bytes: u64) -> Result<()> {
    let Some(free) = free_space(dir) else {
        return Ok(());
    };
    if bytes > free {
        let gb = |b: u64| b as f64 / 1e9;
        return Err(Error::Usage(format!(
            "needs {:.3} GB and its filesystem has {:.3} GB free; make room, write elsewhere or ask for less",
            gb(bytes),
            gb(free)
        ))
        .with_path(dir));
    }
    Ok(())
}

/// The bytes an unprivileged process may still write on the filesystem holding `dir` (or the
/// nearest existing folder above it).
fn free_space(dir: &Path) -> Option<u64> {
    let at = dir
        .ancestors()
        .find(|a| !a.as_os_str().is_empty() && a.exists())
        .unwrap_or(Path::new("."));
    #[cfg(unix)]
    {
        let s = rustix::fs::statvfs(at).ok()?;
        Some(s.f_bavail.saturating_mul(s.f_frsize))
    }
    #[cfg(not(unix))]
    {
        let _ = at;
        None
    }
}

/// Reads a whole regular file. A FIFO (opening one waits for a writer, forever if none comes)
/// or a device (`/dev/zero` reads without end, filling memory) is refused before it is opened,
/// as an `InvalidInput` error saying what it is: for every settings, manifest, profile and model
/// file read whole.
pub fn read_regular(path: &Path) -> std::io::Result<Vec<u8>> {
    if let Some(what) = not_a_file(path) {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("{what}, not a regular file"),
        ));
    }
    std::fs::read(path)
}

/// [`read_regular`] of a text file.
pub fn read_regular_text(path: &Path) -> std::io::Result<String> {
    String::from_utf8(read_regular(path)?)
        .map_err(|_| std::io::Error::new(std::io::ErrorKind::InvalidData, "not UTF-8 text"))
}

/// What `path` is when it exists but is not a regular file (`a folder`, `a device or other
/// special file`), for a message that says so rather than "not found".
pub fn not_a_file(path: &Path) -> Option<&'static str> {
    match std::fs::metadata(path) {
        Ok(m) if m.is_dir() => Some("a folder"),
        Ok(m) if !m.is_file() => Some("a device or other special file"),
        _ => None,
    }
}

/// FNV-1a over bytes: [`content_hash`] of bytes in memory (a built-in model's).
pub fn bytes_hash(bytes: &[u8]) -> u64 {
    use std::hash::Hasher;
    let mut h = fnv::FnvHasher::default();
    h.write(bytes);
    h.finish()
}

/// FNV-1a over a file's bytes: which file (a model, say) an output was made with, whatever its
/// name.
pub fn content_hash(path: &Path) -> Result<u64> {
    use std::hash::Hasher;
    use std::io::Read;
    let mut f = std::fs::File::open(path).map_err(|e| Error::from(e).with_path(path))?;
    let mut h = fnv::FnvHasher::default();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = f
            .read(&mut buf)
            .map_err(|e| Error::from(e).with_path(path))?;
        if n == 0 {
            return Ok(h.finish());
        }
        h.write(&buf[..n]);
    }
}

/// `bytes` (a safetensors file) with its JSON header's keys in sorted order. safetensors
/// writes the metadata map in hash order, which differs from run to run, so the same profile or
/// model would be saved as different bytes under a different checksum; re-serialized sorted
/// (the same compact JSON, so the same length) the file is a function of its content alone.
/// Bytes that are not a safetensors file are returned as they are.
pub fn safetensors_sorted(mut bytes: Vec<u8>) -> Vec<u8> {
    let Some(n) = bytes
        .get(..8)
        .map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes")) as usize)
    else {
        return bytes;
    };
    let Some(header) = n.checked_add(8).and_then(|end| bytes.get(8..end)) else {
        return bytes;
    };
    let Ok(sorted) = serde_json::from_slice::<serde_json::Value>(header)
        .and_then(|v| serde_json::to_vec(&sort_keys(v)))
    else {
        return bytes;
    };
    // The same keys and values re-serialized compactly: never longer than what was there.
    debug_assert!(
        sorted.len() <= n,
        "a sorted header longer than the original"
    );
    if sorted.len() <= n {
        // The header's padding (spaces to a multiple of 8 bytes) is kept.
        bytes[8..8 + sorted.len()].copy_from_slice(&sorted);
        bytes[8 + sorted.len()..8 + n].fill(b' ');
    }
    bytes
}

/// `v` with every object's keys in sorted order (serde_json keeps insertion order where a
/// dependency enables its `preserve_order`, as zarrs does).
fn sort_keys(v: serde_json::Value) -> serde_json::Value {
    use serde_json::Value;
    match v {
        Value::Object(m) => {
            let sorted: std::collections::BTreeMap<String, Value> =
                m.into_iter().map(|(k, v)| (k, sort_keys(v))).collect();
            Value::Object(sorted.into_iter().collect())
        }
        Value::Array(a) => Value::Array(a.into_iter().map(sort_keys).collect()),
        other => other,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn files_are_known_however_spelled_and_outputs_never_replace_inputs() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::create_dir_all(d.join("a")).unwrap();
        std::fs::create_dir_all(d.join("b")).unwrap();
        for f in ["s.tif", "a/x.tif", "b/x.tif"] {
            std::fs::write(d.join(f), f).unwrap();
        }
        let path = d.join("s.tif");
        // one file, however it is spelled; a file not yet there by its absolute path
        assert_eq!(FileId::of(&path), FileId::of(&d.join(".").join("s.tif")));
        assert_eq!(
            FileId::of(&d.join("new.tif")),
            FileId::Path(d.canonicalize().unwrap().join("new.tif"))
        );
        let e = refuse_overwrite(&d.join("a/../s.tif"), &path, "the input s.tif").unwrap_err();
        assert!(
            e.to_string().contains("the output is the input s.tif"),
            "{e}"
        );
        assert!(refuse_overwrite(&d.join("o.tif"), &path, "the input").is_ok());
        let ins = [path.clone(), d.join("a/x.tif")];
        assert_eq!(
            output_paths(&ins, &d.join("out"), Some("_d.tif")).unwrap(),
            vec![d.join("out/s_d.tif"), d.join("out/x_d.tif")]
        );
        assert_eq!(
            output_paths(&ins[..1], &d.join("o.tif"), None).unwrap(),
            vec![d.join("o.tif")]
        );
        let e = output_paths(&ins[..1], &path, None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("is the input"), "{e}");
        let twins = [d.join("a/x.tif"), d.join("b/x.tif")];
        let e = output_paths(&twins, d, Some("_d.tif"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("would both be written"), "{e}");
        // an input that is another input's output
        std::fs::write(d.join("a/x_d.tif"), "x").unwrap();
        let e = output_paths(
            &[d.join("a/x.tif"), d.join("a/x_d.tif")],
            &d.join("a"),
            Some("_d.tif"),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("is the input"), "{e}");
        // the first output that is an input, with the first input it is
        let outs = [d.join("new.tif"), d.join("b/../a/x.tif"), d.join("s.tif")];
        let ins = [d.join("s.tif"), d.join("a/x.tif"), d.join("./a/x.tif")];
        assert_eq!(input_among(&outs, &ins), Some((1, 1)));
        assert_eq!(input_among(&outs[..1], &ins), None);
    }

    #[test]
    fn safetensors_headers_are_sorted_and_other_bytes_kept() {
        let header = br#"{"b":{"dtype":"F32","shape":[1],"data_offsets":[0,4]},"__metadata__":{"z":"1","a":"2"}}"#;
        let pad = (8 - header.len() % 8) % 8;
        let mut file = ((header.len() + pad) as u64).to_le_bytes().to_vec();
        file.extend_from_slice(header);
        file.extend(std::iter::repeat_n(b' ', pad));
        file.extend_from_slice(&1f32.to_le_bytes());
        let sorted = safetensors_sorted(file.clone());
        assert_eq!(sorted.len(), file.len());
        let want = br#"{"__metadata__":{"a":"2","z":"1"},"b":{"data_offsets":[0,4],"dtype":"F32","shape":[1]}}"#;
        assert_eq!(&sorted[8..8 + want.len()], want);
        assert_eq!(&sorted[sorted.len() - 4..], &1f32.to_le_bytes());
        // not safetensors, or a length past the end: unchanged, no panic
        for junk in [
            vec![],
            vec![1, 2, 3],
            u64::MAX.to_le_bytes().to_vec(),
            b"12345678{".to_vec(),
        ] {
            assert_eq!(safetensors_sorted(junk.clone()), junk);
        }
    }

    #[test]
    fn stamps_and_hashes_follow_the_content() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("m.bin");
        std::fs::write(&p, b"abc").unwrap();
        let s = FileStamp::of(&p).unwrap();
        assert_eq!(s.bytes, 3);
        assert!(s.file.ends_with("m.bin"));
        // FNV-1a 64 of "abc"
        assert_eq!(content_hash(&p).unwrap(), 0xe71fa2190541574b);
        let e = content_hash(&dir.path().join("none"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("none"), "{e}");
    }
}
