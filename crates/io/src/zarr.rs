//! OME-Zarr stacks (OME-NGFF 0.5 on Zarr v3) through the `zarrs` crate: a reader for any Zarr
//! array of frames (OME groups of either NGFF version, bare arrays), and a writer that many
//! processes can fill at once.
//!
//! The writer stores one chunk per frame, so processes that write different frames never touch
//! the same file. A chunk is encoded in the writer's own staging folder and renamed into place,
//! then a completion marker (`OUT.zarr/0/.emccd-done/FRAME`) is created: a frame without its
//! marker (its process was killed first) is written again by whoever resumes. Both folders are
//! inside the array's own folder, where Zarr readers look only for the chunks they need (in the
//! group's folder zarr-python warns of every entry that is not a Zarr node). Staging folders
//! that killed processes left are removed by a later writer once they are [`crate::STALE`], and a
//! store's temporary folder left beside it after a minute. The store itself is built
//! in a temporary folder and renamed into place, so among processes that start together exactly
//! one creates it and the others open it and check that it was made for the same work
//! ([`ZarrStackWriter::create_or_open`]). Frames never written are refused by name by the
//! reader (their chunks are missing; other readers see NaN, the fill value).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use serde_json::{json, Map, Value};
use zarrs::array::{data_type, Array};
use zarrs::filesystem::FilesystemStore;
use zarrs::group::{Group, GroupBuilder};

use crate::{Error, Format, FrameReader, Limits, Metadata, PixelType, Result, StackInfo};

/// Which share of a stack one process of a job array writes (`I/N`, I from 0, as
/// `SLURM_ARRAY_TASK_ID` counts with `--array=0-N-1`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    /// This process's index, from 0.
    pub index: usize,
    /// How many processes share the stack.
    pub count: usize,
}

impl Shard {
    /// The whole stack, for a process that works alone.
    pub const ALL: Shard = Shard { index: 0, count: 1 };

    /// The frames (from 0) of a `frames`-long stack that this shard writes: contiguous, and
    /// together the N shards cover every frame once.
    pub fn range(self, frames: usize) -> std::ops::Range<usize> {
        let at = |i: usize| (i as u128 * frames as u128 / self.count as u128) as usize;
        at(self.index)..at(self.index + 1)
    }
}

impl std::str::FromStr for Shard {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Shard, String> {
        let bad = || {
            format!("'{s}': a shard is I/N with 0 ≤ I < N (I counts from 0, as SLURM_ARRAY_TASK_ID does with --array=0-N-1)")
        };
        let (i, n) = s.split_once('/').ok_or_else(bad)?;
        match (i.trim().parse::<usize>(), n.trim().parse::<usize>()) {
            (Ok(index), Ok(count)) if index < count => Ok(Shard { index, count }),
            _ => Err(bad()),
        }
    }
}

/// The folder of completion markers inside the array folder of a store written by
/// [`ZarrStackWriter`] (stores written before 2026-11-27 kept it at the store's top; a writer
/// moves it).
pub const DONE_DIR: &str = ".emccd-done";
/// Where each [`ZarrStackWriter`] stages its chunks before renaming them into place, inside
/// the array folder.
const STAGING_DIR: &str = ".emccd-staging";
/// A store's temporary folder this old belongs to a process killed while it built the store
/// (which takes milliseconds).
const STALE_BUILD: std::time::Duration = std::time::Duration::from_secs(60);
/// The array (multiscale level 0) inside a store written by [`ZarrStackWriter`].
const LEVEL0: &str = "0";
/// The group attribute that holds what the store's frames were made from.
pub const PROVENANCE_KEY: &str = "emccd";
/// The group attribute with the creating run's notes (see [`ZarrStackSpec::notes`]).
pub const NOTES_KEY: &str = "emccd_notes";

/// Whether `path` is a Zarr store or array folder (v3 `zarr.json`, v2 `.zgroup`/`.zarray`).
pub fn is_zarr(path: &Path) -> bool {
    path.is_dir()
        && ["zarr.json", ".zgroup", ".zarray"]
            .iter()
            .any(|m| path.join(m).is_file())
}

fn zerr(e: impl std::fmt::Display) -> Error {
    Error::Format(format!("Zarr: {e}"))
}

fn store(path: &Path) -> Result<Arc<FilesystemStore>> {
    Ok(Arc::new(FilesystemStore::new(path).map_err(zerr)?))
}

/// The path of the array holding the frames: the store itself if it is an array, else the first
/// dataset of the group's first OME multiscale (NGFF 0.5 keeps it under `ome`, 0.4 at the top).
fn frames_array_path(store: &Arc<FilesystemStore>, dir: &Path) -> Result<String> {
    if let Ok(g) = Group::open(store.clone(), "/") {
        let attrs = g.attributes();
        let ms = attrs
            .get("ome")
            .and_then(|o| o.get("multiscales"))
            .or_else(|| attrs.get("multiscales"));
        let path = ms
            .and_then(|m| m.get(0))
            .and_then(|m| m.get("datasets"))
            .and_then(|d| d.get(0))
            .and_then(|d| d.get("path"))
            .and_then(Value::as_str);
        return match path {
            Some(p) => Ok(format!("/{}", p.trim_matches('/'))),
            None => Err(Error::Format(format!(
                "a Zarr group without OME-NGFF multiscales; give the folder of the array inside it ({})",
                dir.display()
            ))),
        };
    }
    Ok("/".into())
}

/// A Zarr array of frames read one frame at a time: the last two dimensions are (y, x), the
/// leading ones (t, c, z in OME's order) are counted through as frames.
pub struct ZarrReader {
    array: Array<FilesystemStore>,
    info: StackInfo,
    lead: Vec<u64>,
    next: usize,
    done: Option<PathBuf>,
}

/// The sample type of a Zarr data type this reader converts to `f32`.
fn pixel_type(dt: &zarrs::array::DataType) -> Option<PixelType> {
    [
        (data_type::uint8(), PixelType::U8),
        (data_type::uint16(), PixelType::U16),
        (data_type::int16(), PixelType::I16),
        (data_type::uint32(), PixelType::U32),
        (data_type::int32(), PixelType::I32),
        (data_type::float32(), PixelType::F32),
        (data_type::float64(), PixelType::F64),
    ]
    .into_iter()
    .find(|(d, _)| d == dt)
    .map(|(_, p)| p)
}

impl ZarrReader {
    /// Opens the store or array at `dir` with the given limits.
    pub fn open(dir: &Path, limits: Limits) -> Result<ZarrReader> {
        let store = store(dir)?;
        let path = frames_array_path(&store, dir)?;
        let array = Array::open(store, &path).map_err(zerr)?;
        let shape = array.shape().to_vec();
        if shape.len() < 2 {
            return Err(Error::Unsupported(format!(
                "a {}-dimensional Zarr array; frames need (y, x) as the last two",
                shape.len()
            )));
        }
        let pt = pixel_type(array.data_type()).ok_or_else(|| {
            Error::Unsupported(format!(
                "Zarr data type {}; frames are u8, u16, i16, u32, i32, f32 or f64",
                array.data_type()
            ))
        })?;
        let (h, w) = (shape[shape.len() - 2], shape[shape.len() - 1]);
        let lead = shape[..shape.len() - 2].to_vec();
        let frames = lead.iter().try_fold(1u64, |a, &d| a.checked_mul(d));
        let frames = frames.ok_or_else(|| Error::Format("Zarr shape overflows".into()))?;
        limits.stack(frames)?;
        let too_big = |v: u64| usize::try_from(v).map_err(|_| zerr("shape beyond this machine"));
        let (width, height) = (too_big(w)?, too_big(h)?);
        limits.frame(width, height, pt.bytes())?;
        // The markers live in the array's folder of a store we wrote (at the store's top in
        // stores written before 2026-11-27); the array's own folder may have been given.
        let done = [
            Some(dir.join(path.trim_start_matches('/'))),
            Some(dir.to_path_buf()),
            dir.parent().map(Path::to_path_buf),
        ]
        .into_iter()
        .flatten()
        .map(|d| d.join(DONE_DIR))
        .find(|d| d.is_dir());
        let mut metadata = Metadata::default();
        if let Some(d) = &done {
            let n = count_markers(d, frames);
            if n < frames as usize {
                metadata.warnings.push(format!(
                    "{n} of {frames} frames written; the run that makes this store has not finished (resume it, or run its missing shards)"
                ));
            }
        }
        Ok(ZarrReader {
            info: StackInfo {
                width,
                height,
                frames: frames as usize,
                pixel_type: pt,
                format: Format::Zarr,
                metadata,
            },
            array,
            lead,
            next: 0,
            done,
        })
    }

    /// The key of the first chunk holding part of `subset` that the store does not have.
    fn missing_chunk(&self, subset: &[std::ops::Range<u64>]) -> Option<String> {
        use zarrs::storage::ReadableStorageTraits;
        let subset = zarrs::array::ArraySubset::new_with_ranges(subset);
        let chunks = self.array.chunks_in_array_subset(&subset).ok()??;
        let storage = self.array.storage();
        chunks.indices().into_iter().find_map(|idx| {
            let key = self.array.chunk_key(&idx);
            matches!(storage.size_key(&key), Ok(None)).then(|| key.to_string())
        })
    }

    /// The frame's index along each leading dimension (row-major, last fastest).
    fn lead_index(&self, mut k: u64) -> Vec<u64> {
        let mut idx = vec![0; self.lead.len()];
        for (i, &d) in self.lead.iter().enumerate().rev() {
            idx[i] = k % d;
            k /= d;
        }
        idx
    }
}

impl FrameReader for ZarrReader {
    fn info(&self) -> &StackInfo {
        &self.info
    }

    fn read_frame(&mut self, out: &mut [f32]) -> Result<bool> {
        if self.next >= self.info.frames {
            return Ok(false);
        }
        crate::check_buffer(out, &self.info)?;
        let k = self.next;
        if let Some(d) = &self.done {
            if !d.join(k.to_string()).is_file() {
                return Err(Error::Format(format!(
                    "frame {} is not written yet: the run that makes this store has not finished it",
                    k + 1
                )));
            }
        }
        let mut subset: Vec<std::ops::Range<u64>> = self
            .lead_index(k as u64)
            .iter()
            .map(|&i| i..i + 1)
            .collect();
        subset.push(0..self.info.height as u64);
        subset.push(0..self.info.width as u64);
        let e = |e: zarrs::array::ArrayError| zerr(format!("frame {}: {e}", k + 1));

        macro_rules! conv {
            ($t:ty) => {{
                let v: Vec<$t> = self.array.retrieve_array_subset(&subset).map_err(e)?;
                out.iter_mut().zip(v).for_each(|(o, x)| *o = x as f32);
            }};
        }
        match self.info.pixel_type {
            PixelType::U8 => conv!(u8),
            PixelType::U16 => conv!(u16),
            PixelType::I16 => conv!(i16),
            PixelType::U32 => conv!(u32),
            PixelType::I32 => conv!(i32),
            PixelType::F32 => conv!(f32),
            PixelType::F64 => conv!(f64),
        }
        // A chunk the store lacks reads as the fill value. Writers leave out chunks equal to
        // it (zarr-python and zarrs do by default), so a missing chunk is data where the fill
        // value is one; where it is NaN (our stores) it is said as missing, not left to be
        // refused later as a non-finite pixel.
        if out.iter().any(|v| !v.is_finite()) {
            if let Some(key) = self.missing_chunk(&subset) {
                return Err(Error::Format(format!(
                    "frame {}: its data is missing from the store (no chunk {key}); the store is incomplete or damaged",
                    k + 1
                )));
            }
        }
        self.next += 1;
        Ok(true)
    }

    fn skip_frame(&mut self) -> Result<bool> {
        if self.next >= self.info.frames {
            return Ok(false);
        }
        self.next += 1;
        Ok(true)
    }
}

/// The completion markers in `dir` that name a frame of a `frames`-long stack.
fn count_markers(dir: &Path, frames: u64) -> usize {
    std::fs::read_dir(dir)
        .map(|r| {
            r.filter_map(|e| e.ok())
                .filter(|e| {
                    e.file_name()
                        .to_str()
                        .and_then(|n| n.parse::<u64>().ok())
                        .is_some_and(|k| k < frames && e.path().is_file())
                })
                .count()
        })
        .unwrap_or(0)
}

/// What a store written by several processes holds, and what every one of them must agree on.
#[derive(Clone, Debug, PartialEq)]
pub struct ZarrStackSpec {
    /// Frame width in pixels.
    pub width: usize,
    /// Frame height in pixels.
    pub height: usize,
    /// Frames in the whole stack.
    pub frames: usize,
    /// The multiscale's name (shown by OME viewers).
    pub name: String,
    /// What the frames are a function of (inputs' identities, method, model, profile): stored
    /// as the group attribute [`PROVENANCE_KEY`] and compared by every process that opens the
    /// store to write.
    pub provenance: Value,
    /// What a person wants to read but that does not change the frames (names as typed):
    /// stored as [`NOTES_KEY`] by the process that creates the store, never compared.
    pub notes: Value,
}

/// A float32 `[t, y, x]` OME-Zarr stack, one chunk per frame, that several processes fill at
/// once (see the module documentation).
pub struct ZarrStackWriter {
    /// The same array in a private staging folder inside the store: zarrs encodes each chunk
    /// there, and it is renamed into place (see [`ZarrStackWriter::write_frame`]).
    staging: Array<FilesystemStore>,
    staging_dir: tempfile::TempDir,
    path: PathBuf,
    done: PathBuf,
    spec: ZarrStackSpec,
}

impl ZarrStackWriter {
    /// Creates the store at `path`, or opens it if another process (or an earlier run) created
    /// it; then it must have been made for the same `spec`, else an error says what differs.
    /// Returns the writer and whether this call created the store.
    pub fn create_or_open(path: &Path, spec: &ZarrStackSpec) -> Result<(ZarrStackWriter, bool)> {
        let at = |e: Error| e.with_path(path);
        if spec.width == 0 || spec.height == 0 || spec.frames == 0 {
            return Err(at(Error::Usage(format!(
                "cannot write {} frames of {}×{}",
                spec.frames, spec.width, spec.height
            ))));
        }
        let mut created = false;
        if let Some(name) = path.file_name().and_then(|n| n.to_str()) {
            crate::remove_stale(
                crate::folder_of(path),
                &format!(".{name}."),
                ".tmp",
                STALE_BUILD,
            );
        }
        if !path.exists() {
            let tmp = temp_dir_beside(path).map_err(|e| at(e.into()))?;
            Self::build(tmp.path(), spec).map_err(at)?;
            // rename(2) of a folder onto a name that meanwhile holds another process's store
            // fails: that process won, and this one opens what it made.
            match std::fs::rename(tmp.path(), path) {
                Ok(()) => {
                    let _ = tmp.keep();
                    created = true;
                }
                Err(e) if path.exists() => drop(e),
                Err(e) => return Err(at(e.into())),
            }
        }
        let w = Self::open_matching(path, spec).map_err(at)?;
        Ok((w, created))
    }

    fn build(dir: &Path, spec: &ZarrStackSpec) -> Result<()> {
        let store = store(dir)?;
        let mut attrs = Map::new();
        attrs.insert(
            "ome".into(),
            json!({
                "version": "0.5",
                "multiscales": [{
                    "name": spec.name,
                    "axes": [
                        {"name": "t", "type": "time"},
                        {"name": "y", "type": "space"},
                        {"name": "x", "type": "space"}
                    ],
                    "datasets": [{
                        "path": LEVEL0,
                        "coordinateTransformations": [{"type": "scale", "scale": [1.0, 1.0, 1.0]}]
                    }]
                }]
            }),
        );
        attrs.insert(PROVENANCE_KEY.into(), spec.provenance.clone());
        attrs.insert(NOTES_KEY.into(), spec.notes.clone());
        GroupBuilder::new()
            .attributes(attrs)
            .build(store.clone(), "/")
            .map_err(zerr)?
            .store_metadata()
            .map_err(zerr)?;
        let (f, h, w) = (spec.frames as u64, spec.height as u64, spec.width as u64);
        zarrs::array::ArrayBuilder::new(
            vec![f, h, w],
            vec![1, h, w],
            data_type::float32(),
            f32::NAN,
        )
        .dimension_names(["t", "y", "x"].into())
        .build(store, &format!("/{LEVEL0}"))
        .map_err(zerr)?
        .store_metadata()
        .map_err(zerr)?;
        std::fs::create_dir(dir.join(LEVEL0).join(DONE_DIR))?;
        crate::readable_dir(dir)?;
        Ok(())
    }

    fn open_matching(path: &Path, spec: &ZarrStackSpec) -> Result<ZarrStackWriter> {
        let other = |what: String| {
            Error::Usage(format!(
                "a store made for other work is already here ({what}); choose another -o, or remove it to start over"
            ))
        };
        if !is_zarr(path) {
            return Err(Error::Usage(
                "exists and is not a Zarr store; choose another -o".into(),
            ));
        }
        let root = store(path)?;
        let group = Group::open(root.clone(), "/").map_err(|e| other(format!("{e}")))?;
        let theirs = group.attributes().get(PROVENANCE_KEY).cloned();
        if theirs.as_ref() != Some(&spec.provenance) {
            return Err(other(match theirs {
                None => "not written by emccd".into(),
                Some(t) => first_difference(&t, &spec.provenance, ""),
            }));
        }
        let array = Array::open(root, &format!("/{LEVEL0}")).map_err(zerr)?;
        let want = [spec.frames as u64, spec.height as u64, spec.width as u64];
        if array.shape() != want || *array.data_type() != data_type::float32() {
            return Err(other(format!(
                "array {:?} of {}, this run writes {:?} of float32",
                array.shape(),
                array.data_type(),
                want
            )));
        }
        let level = path.join(LEVEL0);
        let done = level.join(DONE_DIR);
        // A store written before the markers moved into the array's folder: moved there (a
        // rename, so a process that resumes it alongside finds one or the other).
        let old = path.join(DONE_DIR);
        if !done.is_dir() && old.is_dir() {
            if let Err(e) = std::fs::rename(&old, &done) {
                if !done.is_dir() {
                    return Err(e.into());
                }
            }
        }
        // The staging area of that layout: what killed writers left there, once stale.
        let old_area = path.join(STAGING_DIR);
        crate::remove_stale(&old_area, "w", "", crate::STALE);
        let _ = std::fs::remove_dir(&old_area);
        if !done.is_dir() {
            return Err(other(format!("no {LEVEL0}/{DONE_DIR} folder")));
        }
        // Each writer stages its chunks in a folder of its own inside the array's folder (same
        // filesystem), holding the same array metadata, so the staged chunk's key, under the
        // staging folder, is the store's key for that frame.
        let area = level.join(STAGING_DIR);
        crate::remove_stale(&area, "w", "", crate::STALE);
        // A writer that ends removes the area when it is empty: made again if it went between.
        let mut tries = 0;
        let staging_dir = loop {
            std::fs::create_dir_all(&area)?;
            match tempfile::Builder::new().prefix("w").tempdir_in(&area) {
                Err(e) if e.kind() == std::io::ErrorKind::NotFound && tries < 5 => tries += 1,
                r => break r?,
            }
        };
        // Stopped by Ctrl-C or SIGTERM, the destructor does not run: removed by the handler.
        crate::live_temps().insert(staging_dir.path().to_path_buf());
        let staging = Array::new_with_metadata(
            store(staging_dir.path())?,
            &format!("/{LEVEL0}"),
            array.metadata().clone(),
        )
        .map_err(zerr)?;
        Ok(ZarrStackWriter {
            staging,
            staging_dir,
            path: path.to_path_buf(),
            done,
            spec: spec.clone(),
        })
    }

    /// What the store was made for (frames, size, provenance).
    pub fn spec(&self) -> &ZarrStackSpec {
        &self.spec
    }

    /// Whether frame `k` (from 0) is complete: its marker written and, under it, its chunk
    /// whole (a marker is not trusted alone: a chunk deleted or cut short after its frame was
    /// marked is written again).
    pub fn is_done(&self, k: usize) -> bool {
        if k >= self.spec.frames || !self.done.join(k.to_string()).is_file() {
            return false;
        }
        let key = self.staging.chunk_key(&[k as u64, 0, 0]);
        // The store's chunks are uncompressed float32 frames (the array has no compressor).
        let whole = (self.spec.width * self.spec.height * 4) as u64;
        std::fs::metadata(self.path.join(key.as_str())).is_ok_and(|m| m.len() == whole)
    }

    /// How many frames of the whole store are complete ([`ZarrStackWriter::is_done`]; files in
    /// the marker folder that name no frame are not counted).
    pub fn done_count(&self) -> usize {
        (0..self.spec.frames).filter(|&k| self.is_done(k)).count()
    }

    /// Stores frame `k` (from 0), then its completion marker.
    pub fn write_frame(&self, k: usize, frame: &[f32]) -> Result<()> {
        let at = |e: Error| e.with_path(&self.path);
        if k >= self.spec.frames || frame.len() != self.spec.width * self.spec.height {
            return Err(at(Error::Usage(format!(
                "frame {} of {} pixels does not fit a store of {} frames of {}×{}",
                k + 1,
                frame.len(),
                self.spec.frames,
                self.spec.width,
                self.spec.height
            ))));
        }
        if let Some(i) = frame.iter().position(|v| !v.is_finite()) {
            return Err(at(Error::Usage(format!(
                "frame {} has a non-finite value ({}) at pixel ({}, {}); nothing was written",
                k + 1,
                frame[i],
                i % self.spec.width,
                i / self.spec.width
            ))));
        }
        // A chunk is never written in place: zarrs stores it in this writer's staging folder, it
        // is flushed to disk and renamed over the store's chunk (atomic), and only then is its
        // marker made. A reader, or another writer of the same frame, sees the old chunk or the
        // new one whole, never a truncated one, and a marker always names a whole chunk.
        let idx = [k as u64, 0, 0];
        self.staging
            .store_chunk(&idx, frame)
            .map_err(|e| at(zerr(format!("frame {}: {e}", k + 1))))?;
        let key = self.staging.chunk_key(&idx);
        let staged = self.staging_dir.path().join(key.as_str());
        let target = self.path.join(key.as_str());
        let io = |e: std::io::Error| at(Error::from(e));
        let parent = target.parent().unwrap_or(&self.path);
        std::fs::create_dir_all(parent).map_err(io)?;
        crate::move_into_place(&staged, &target).map_err(io)?;
        let marker = self.done.join(k.to_string());
        std::fs::File::create(&marker)
            .and_then(|f| f.sync_all())
            .map_err(io)?;
        crate::sync_dir(&self.done);
        Ok(())
    }
}

impl Drop for ZarrStackWriter {
    /// The writer's staging folder goes, and the staging area with it once no other writer
    /// stages there, so a finished store holds only the Zarr nodes and the markers.
    fn drop(&mut self) {
        crate::live_temps().remove(self.staging_dir.path());
        let _ = std::fs::remove_dir_all(self.staging_dir.path());
        if let Some(area) = self.staging_dir.path().parent() {
            let _ = std::fs::remove_dir(area);
        }
    }
}

/// Where two provenance records first differ, as `key: A here, B asked`.
fn first_difference(theirs: &Value, ours: &Value, at: &str) -> String {
    match (theirs, ours) {
        (Value::Object(a), Value::Object(b)) => {
            for (k, vb) in b {
                let key = if at.is_empty() {
                    k.clone()
                } else {
                    format!("{at}.{k}")
                };
                match a.get(k) {
                    Some(va) if va == vb => {}
                    Some(va) => return first_difference(va, vb, &key),
                    None => return format!("{key}: missing in the store, {vb} asked"),
                }
            }
            match a.keys().find(|k| !b.contains_key(*k)) {
                Some(k) => format!(
                    "{at}{}{k}: in the store, not asked",
                    if at.is_empty() { "" } else { "." }
                ),
                None => format!("{at}: differs"),
            }
        }
        (Value::Array(a), Value::Array(b)) if a.len() == b.len() => {
            for (i, (va, vb)) in a.iter().zip(b).enumerate() {
                if va != vb {
                    return first_difference(va, vb, &format!("{at}[{i}]"));
                }
            }
            format!("{at}: differs")
        }
        _ => format!("{at}: {theirs} in the store, {ours} asked"),
    }
}

/// A temporary folder beside `path` (same filesystem, so the rename into place is atomic).
fn temp_dir_beside(path: &Path) -> std::io::Result<tempfile::TempDir> {
    crate::make_beside(path, |b, dir| b.tempdir_in(dir))
}

#[cfg(test)]
mod tests {
    use super::Shard;

    #[test]
    fn shards_cover_every_frame_once_and_parse_as_slurm_counts() {
        for (frames, count) in [(10, 3), (2, 5), (7, 7), (0, 2)] {
            let mut next = 0;
            for index in 0..count {
                let r = Shard { index, count }.range(frames);
                assert_eq!(r.start, next, "{frames} frames, shard {index}/{count}");
                next = r.end;
            }
            assert_eq!(next, frames);
        }
        assert_eq!("2/3".parse(), Ok(Shard { index: 2, count: 3 }));
        assert_eq!(Shard::ALL.range(5), 0..5);
        for bad in ["3/3", "1", "-1/2", "a/b", "0/0"] {
            let e = bad.parse::<Shard>().unwrap_err();
            assert!(e.contains("I/N"), "{bad}: {e}");
        }
    }
}
