//! A folder of test pairs from the virtual camera, as `emccd simulate pairs` writes it: per
//! scene and light level a stack of noisy raw frames (`noisy/`, 16-bit), the ground truth
//! (`clean/`, DN above bias, float32), a preview PNG (`preview/`) and, with a denoiser, its
//! output for the first frame (`denoised/`); then `pairs.toml`.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use emccd_camera::acquisition::{pair_seed, PairLevel};
use emccd_camera::VirtualCamera;
use emccd_io::{Metadata, SampleFormat, StackWriter};
use emccd_profile::CameraProfile;

use crate::{Pair, PairsManifest};

/// What to write: the scenes, the levels, and how the manifest names the camera.
#[derive(Clone, Debug)]
pub struct PairsPlan<'a> {
    /// Clean scenes (image files, values in [0, 1]); one larger than the camera is
    /// centre-cropped to it, a smaller one gets a camera over the sensor's top-left corner.
    pub scenes: &'a [PathBuf],
    /// The light levels of every scene.
    pub levels: &'a [PairLevel],
    /// Noisy frames per pair (≥ 1).
    pub frames: usize,
    /// The run's seed: pair (scene, level) draws from [`pair_seed`]`(seed, scene, level)`.
    pub seed: u64,
    /// The camera's name, in the manifest and the frames' metadata.
    pub camera_name: &'a str,
    /// The profile the manifest names (`default`, or a path as given).
    pub profile: &'a str,
}

/// Denoises raw frames (profile, one frame or a movie's frames one after another, exposure in
/// s) to DN above bias, frame for frame: a movie's methods may use each frame's neighbours.
pub type Denoise<'a> = dyn Fn(&CameraProfile, &[f32], f64) -> crate::Result<Vec<f32>> + 'a;

/// The subfolders a run writes.
fn subfolders(denoised: bool) -> &'static [&'static str] {
    if denoised {
        &["noisy", "clean", "preview", "denoised"]
    } else {
        &["noisy", "clean", "preview"]
    }
}

/// The stem of scene `si`'s output names.
fn scene_stem(si: usize, scene: &Path) -> String {
    scene
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| format!("scene{si}"))
}

/// Writes the pairs of `plan` from `camera` to `out` and returns the manifest it wrote, calling
/// `tick` after each pair. `denoise` also denoises each pair's first frame (with the camera's
/// own profile, as a user's calibrated profile) and records the PSNR after. Refuses, before
/// anything is written, a run that would overwrite its own outputs (two scenes with one file
/// stem) or an input scene; folders it creates are removed again if it fails or is stopped.
pub fn write_pairs(
    out: &Path,
    plan: &PairsPlan,
    camera: &VirtualCamera,
    denoise: Option<&Denoise>,
    mut tick: impl FnMut(),
) -> crate::Result<PairsManifest> {
    if plan.frames == 0 {
        return Err("a pair needs at least 1 noisy frame".into());
    }
    let dirs = subfolders(denoise.is_some());
    check_outputs(plan, dirs, out)?;
    // Written in full beside `out` and moved there at the end: a run that fails or is stopped
    // leaves `out` as it was, an earlier set of pairs it replaces (`--force`) included.
    let io = |e: emccd_io::Error| crate::Error(emccd_io::error_lines(&e).join(": "));
    // At most the camera's size per pair: the raw frames (16-bit), the truth and a denoised
    // frame (float32), a preview and headers.
    let px = (camera.width() * camera.height()) as u64;
    let pair = (plan.frames as u64)
        .saturating_mul(px * 2)
        .saturating_add(px * 10 + (1 << 16));
    let pairs = (plan.scenes.len() * plan.levels.len()) as u64;
    emccd_io::check_room(out, pair.saturating_mul(pairs)).map_err(io)?;
    let stage = emccd_io::StagedDir::beside(out).map_err(io)?;
    for d in dirs {
        let dir = stage.path().join(d);
        std::fs::create_dir_all(&dir).map_err(|e| format!("creating {}: {e}", dir.display()))?;
    }
    let recorded = relative_to(plan.profile, out);
    let plan = PairsPlan {
        profile: &recorded,
        ..*plan
    };
    let manifest = write_all(stage.path(), &plan, camera, denoise, &mut tick)?;
    stage.place().map_err(io)?;
    Ok(manifest)
}

fn check_outputs(plan: &PairsPlan, dirs: &[&str], out: &Path) -> crate::Result<()> {
    let stems: Vec<String> = plan
        .scenes
        .iter()
        .enumerate()
        .map(|(i, s)| scene_stem(i, s))
        .collect();
    let mut by_stem: HashMap<&str, &Path> = HashMap::new();
    for (stem, scene) in stems.iter().zip(plan.scenes) {
        if let Some(other) = by_stem.insert(stem, scene) {
            return Err(crate::Error(format!(
                "scenes {} and {} have the same name, so their pairs would overwrite each other; rename one",
                other.display(),
                scene.display()
            )));
        }
    }
    let mut outputs = Vec::new();
    for stem in &stems {
        for lv in plan.levels {
            let name = lv.pair_name(stem);
            for d in dirs {
                let ext = if *d == "preview" { "png" } else { "tif" };
                outputs.push(out.join(d).join(format!("{name}.{ext}")));
            }
        }
    }
    if let Some((o, _)) = emccd_io::input_among(&outputs, plan.scenes) {
        return Err(crate::Error(format!(
            "{}: an output of this run is an input scene; choose another -o, inputs are never overwritten",
            outputs[o].display()
        )));
    }
    Ok(())
}

/// Rounds a dB figure to the manifest's two decimals.
fn db2(v: f64) -> f64 {
    (v * 100.0).round() / 100.0
}

/// The profile argument `profile` as the manifest in `out` (which may not exist yet) records
/// it: a folder given by a relative path as a path relative to `out` (the manifest's paths are
/// relative to it, so the pairs and the profile can move together and `evaluate` finds this
/// profile from anywhere); `default`, absolute paths and paths that cannot be made relative
/// as given.
fn relative_to(profile: &str, out: &Path) -> String {
    let absolute = |p: &Path| {
        std::fs::canonicalize(p).ok().or_else(|| {
            let parent = p.parent().filter(|d| !d.as_os_str().is_empty());
            let parent = std::fs::canonicalize(parent.unwrap_or(Path::new("."))).ok()?;
            Some(parent.join(p.file_name()?))
        })
    };
    if profile == "default" || Path::new(profile).is_absolute() {
        return profile.to_string();
    }
    let (Some(p), Some(o)) = (absolute(Path::new(profile)), absolute(out)) else {
        return profile.to_string();
    };
    if !p.is_dir() {
        return profile.to_string();
    }
    let (pc, oc): (Vec<_>, Vec<_>) = (p.components().collect(), o.components().collect());
    let common = pc.iter().zip(&oc).take_while(|(a, b)| a == b).count();
    let mut rel = std::path::PathBuf::new();
    for _ in common..oc.len() {
        rel.push("..");
    }
    for c in &pc[common..] {
        rel.push(c);
    }
    // Forward slashes, so a manifest written on one system reads on another.
    rel.to_string_lossy().replace('\\', "/")
}

fn write_all(
    out: &Path,
    plan: &PairsPlan,
    full: &VirtualCamera,
    denoise: Option<&Denoise>,
    tick: &mut dyn FnMut(),
) -> crate::Result<PairsManifest> {
    let mut manifest = PairsManifest {
        camera: Some(plan.camera_name.into()),
        profile: Some(plan.profile.into()),
        em_gain: Some(full.em_gain),
        k_dn_per_e: Some(full.k_dn()),
        qe: Some(full.physics.qe),
        note: Some("noisy: raw 16-bit frames; clean: photo-signal in DN above bias (K·QE·photons), float32. \
               psnr_input_db: preprocessed noisy frame (eq. 4 with the true FPN and blooming) against clean, \
               data range = the clean frame's peak."
            .into()),
        pair: vec![],
    };
    for (si, path) in plan.scenes.iter().enumerate() {
        let img = emccd_io::Image::read_scene(path)
            .map_err(|e| format!("reading scene {}: {e}", path.display()))?;
        let (w, h) = (img.width.min(full.width()), img.height.min(full.height()));
        let cropped;
        let cam = if (w, h) == (full.width(), full.height()) {
            full
        } else {
            cropped = full.crop(w, h).map_err(|e| e.to_string())?;
            &cropped
        };
        let scene = Scene {
            path,
            index: si,
            stem: scene_stem(si, path),
            cam,
            image: img.center_crop(w, h).data,
        };
        for pi in 0..plan.levels.len() {
            manifest
                .pair
                .push(write_pair(out, plan, &scene, pi, denoise)?);
            tick();
        }
    }
    emccd_io::write_atomic(
        out.join(PairsManifest::FILE),
        manifest.to_toml("`emccd simulate pairs`").as_bytes(),
    )
    .map_err(|e| e.to_string())?;
    Ok(manifest)
}

/// One scene of a plan, cropped to what its camera sees.
struct Scene<'a> {
    path: &'a Path,
    /// Its place in the plan (it seeds the pairs).
    index: usize,
    stem: String,
    /// The camera, cropped to the scene where the scene is smaller.
    cam: &'a VirtualCamera,
    image: Vec<f32>,
}

/// Synthesizes, writes and scores the pair of `scene` at the plan's light level `level`: the
/// noisy stack, the clean frame, the denoised frame (with `denoise`) and the preview.
fn write_pair(
    out: &Path,
    plan: &PairsPlan,
    scene: &Scene,
    level: usize,
    denoise: Option<&Denoise>,
) -> crate::Result<Pair> {
    let io = |e: emccd_io::Error| e.to_string();
    let (cam, lv) = (scene.cam, &plan.levels[level]);
    let (w, h) = (cam.width(), cam.height());
    let (photons, exposure_s) = (lv.photons, lv.exposure_s);
    let pair = cam.test_pair(
        &scene.image,
        photons,
        exposure_s,
        pair_seed(plan.seed, scene.index, level),
    );
    let (e, truth) = (&pair.exposure, &pair.truth);
    let name = lv.pair_name(&scene.stem);
    let noisy_rel = format!("noisy/{name}.tif");
    let clean_rel = format!("clean/{name}.tif");
    let preview_rel = format!("preview/{name}.png");
    let mut wr = StackWriter::create(
        out.join(&noisy_rel),
        w,
        h,
        SampleFormat::U16,
        Some(plan.frames),
    )
    .map_err(io)?;
    wr.set_metadata(&Metadata {
        exposure_s: Some(exposure_s),
        em_gain: Some(cam.em_gain),
        camera_model: Some(plan.camera_name.into()),
        ..Default::default()
    });
    let mut raw = vec![0f32; w * h];
    let mut first = Vec::new();
    for k in 0..plan.frames {
        pair.frame(k, &mut raw);
        wr.write_frame(&raw).map_err(io)?;
        if k == 0 {
            first = raw.clone();
        }
    }
    wr.finish().map_err(io)?;
    let clean_meta = Metadata {
        exposure_s: Some(exposure_s),
        ..Default::default()
    };
    write_frame_f32(&out.join(&clean_rel), w, h, truth, Some(&clean_meta)).map_err(io)?;
    let raw_first = first.clone();
    // Preview and input PSNR use the preprocessed frame (true FPN and blooming removed).
    emccd_profile::preprocess(&mut first, w, e.blooming_x, &e.fpn);
    let peak = crate::scores::truth_peak(truth);
    let p_in = crate::psnr(&first, truth, peak);
    let mut panels: Vec<&[f32]> = vec![&first];
    let mut denoised = None;
    let den;
    if let Some(d) = denoise {
        den = d(&cam.profile, &raw_first, exposure_s)?;
        let rel = format!("denoised/{name}.tif");
        write_frame_f32(&out.join(&rel), w, h, &den, None).map_err(io)?;
        denoised = Some((rel, db2(crate::psnr(&den, truth, peak))));
        panels.push(&den);
    }
    panels.push(truth);
    let np = panels.len();
    let side = crate::scores::side_by_side(&panels, w, (0, 0), (w, h));
    emccd_io::write_png_preview(out.join(&preview_rel), np * w, h, &side, 0.0, peak as f32)
        .map_err(io)?;
    let (denoised, psnr_denoised_db) = denoised.unzip();
    Ok(Pair {
        scene: scene.path.display().to_string(),
        noisy: noisy_rel,
        clean: clean_rel,
        preview: Some(preview_rel),
        exposure_s,
        photons,
        exposure_ratio: lv.ratio,
        mean_electrons: None,
        frames: Some(plan.frames),
        width: Some(w),
        height: Some(h),
        psnr_input_db: Some(db2(p_in)),
        denoised,
        psnr_denoised_db,
    })
}

/// Writes one float32 frame as a TIFF, with `meta` where given.
fn write_frame_f32(
    path: &Path,
    w: usize,
    h: usize,
    frame: &[f32],
    meta: Option<&Metadata>,
) -> emccd_io::Result<()> {
    let mut wr = StackWriter::create(path, w, h, SampleFormat::F32, Some(1))?;
    if let Some(m) = meta {
        wr.set_metadata(m);
    }
    wr.write_frame(frame)?;
    wr.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 12×10 gradient scene written as a float TIFF under `dir/name`.
    fn scene(dir: &Path, name: &str) -> PathBuf {
        let path = dir.join(name);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        let mut w = StackWriter::create(&path, 12, 10, SampleFormat::F32, Some(1)).unwrap();
        let v: Vec<f32> = (0..120).map(|i| (i % 12) as f32 / 11.0).collect();
        w.write_frame(&v).unwrap();
        w.finish().unwrap();
        path
    }

    #[test]
    fn writes_pairs_that_read_back_and_refuses_clashing_names() {
        let dir = tempfile::tempdir().unwrap();
        let cam = VirtualCamera::new(
            emccd_profile::default_profile()
                .crop(emccd_profile::Roi::corner(16, 8))
                .unwrap(),
            Default::default(),
        )
        .unwrap();
        let scenes = [scene(dir.path(), "a.tif")];
        let levels = [PairLevel {
            exposure_s: 0.01,
            photons: 30.0,
            ratio: None,
        }];
        let plan = PairsPlan {
            scenes: &scenes,
            levels: &levels,
            frames: 2,
            seed: 3,
            camera_name: "test-cam",
            profile: "default",
        };
        let out = dir.path().join("pairs");
        let mut ticks = 0;
        let m = write_pairs(&out, &plan, &cam, None, || ticks += 1).unwrap();
        assert_eq!(ticks, 1);
        // 12×10 scene on a 16×8 camera: 12 wide (the camera over the corner), 8 high (cropped).
        let back = PairsManifest::load(&out).unwrap();
        assert_eq!(back.pair.len(), 1);
        assert_eq!((m.pair[0].width, m.pair[0].height), (Some(12), Some(8)));
        let f = back.pair[0].read(&out).unwrap();
        let img = emccd_io::Image::read_scene(&scenes[0])
            .unwrap()
            .center_crop(12, 8)
            .data;
        let corner = cam.crop(12, 8).unwrap();
        let want = corner.test_pair(&img, 30.0, 0.01, pair_seed(3, 0, 0));
        assert_eq!(f.clean, want.truth);
        let mut raw = vec![0f32; 96];
        want.frame(0, &mut raw);
        assert_eq!(f.noisy, raw);

        // Two scenes with one stem would overwrite each other: refused, nothing written.
        let twins = [scenes[0].clone(), scene(dir.path(), "b/a.tif")];
        let other = dir.path().join("other");
        let e = write_pairs(
            &other,
            &PairsPlan {
                scenes: &twins,
                ..plan
            },
            &cam,
            None,
            || {},
        )
        .unwrap_err();
        assert!(e.0.contains("same name"), "{e}");
        assert!(!other.exists());
    }
}
