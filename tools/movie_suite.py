#!/usr/bin/env python3
"""The movie suite (issue 35): movies of scenes in motion from cameras emccd never saw (NASA JPL's
emccd-detect with the low-light suite's parameter sets, tools/unseen_camera.py), each camera
calibrated by `emccd calibrate` from its own bias and flat stacks, denoised through that profile
by `emccd denoise` with every method asked for, and beside them BM4D after the generalized
Anscombe transform over the whole stack (the BM3D authors' `bm4d` from PyPI, the temporal peer).
The ground truth is used only to score.

Motions (each a movie of --frames frames of --size² px cut from a larger crop of the scene):
  static     nothing moves
  drift      the scene slides 0.6 px right and 0.3 px down per frame (cubic resampling)
  rotate     the scene turns 0.75° per frame about the centre
  deform     a smooth travelling wave displaces the scene by up to 2 px
  particles  40 Gaussian spots (σ 1.2 px) diffusing 1 px per frame on a dim background, each
             blinking (on → off with p 0.15, off → on with p 0.3 per frame)
  jitter     point sources (σ 1.5 px, brightness over a decade) shaken by tip-tilt of 1.5 px rms
  bleach     the scene fading by 4 % per frame
  cut        one scene for the first half, another for the second

Light: the mean over the movie's frames is --levels photo-electrons per pixel (0.5, 1, 4, 16).
Scenes: McMaster 1 and 7 and FMD field 5 (never trained on: the low-light suite's), one per
motion in turn; particles and jitter make their own. A run of some --motions has the same scenes
and moves as the full run; only the noise is drawn anew.

Usage: python3 tools/movie_suite.py [OUT] [--cameras lowlight-a,lowlight-b] [--levels 0.5,1,4,16]
           [--motions static,drift,...] [--frames 16] [--size 256] [--methods bm3d,blend,temporal]
           [--no-bm4d] [--fast] [--uncalibrated temporal,bm3d] [--data-sheet]
--fast: the simulator's fast gain mode without its partial CIC, for the calibration acquisition
and the movies alike (tools/unseen_camera.py --fast): several times quicker, for validation
runs; the reported tables are made without it.
Needs: python3 with emccd-detect, bm4d, scipy, tifffile, pillow (pip install emccd-detect bm4d
scipy tifffile pillow) and the release binary (built if missing). Each camera's movies and their
truth stacks go to OUT/CAMERA/movies with a pairs.toml, and every emccd method is scored there by
`emccd evaluate` (movie pairs: PSNR over all the frames, the truth's peak as range); BM4D is run
here on the same preprocessed frames and scored the same way. Writes OUT/table.md (PSNR per
camera, motion and level, with each method's seconds per 512² frame) and OUT/results.json; the
acquisitions and profiles are made once and reused.
"""

import argparse
import json
import math
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import tifffile
from scipy import ndimage

warnings.filterwarnings("ignore")
ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tools"))
import unseen_camera  # noqa: E402  (the cameras' parameters, one definition)

DATA = ROOT.parent / "shared/data/clean"
SCENES = [DATA / "natural/McMaster/1.tif", DATA / "natural/McMaster/7.tif",
          DATA / "microscopy/fmd-confocal-bpae/field5-avg50.png"]
MOTIONS = ["static", "drift", "rotate", "deform", "particles", "jitter", "bleach", "cut"]
EXPOSURE = unseen_camera.TEST_EXPOSURE


def centre(img, n):
    y0, x0 = (img.shape[0] - n) // 2, (img.shape[1] - n) // 2
    return img[y0:y0 + n, x0:x0 + n]


def movie(motion, scene, other, n, frames, rng):
    """The clean movie (frames, n, n), relative brightness: where each frame's light is."""
    big = centre(scene, min(scene.shape[0], scene.shape[1], n + 64))
    out = []
    if motion in ("particles", "jitter"):
        yy, xx = np.mgrid[0:n, 0:n]
        if motion == "particles":
            k = 40
            pos = rng.uniform(8, n - 8, (k, 2))
            amp = rng.uniform(0.5, 1.0, k)
            on = rng.random(k) < 0.7
        else:
            k = 30
            pos = rng.uniform(10, n - 10, (k, 2))
            amp = 10 ** rng.uniform(-1, 0, k)
        for _ in range(frames):
            img = np.full((n, n), 0.03)
            if motion == "particles":
                pos = np.clip(pos + rng.normal(0, 1.0, pos.shape), 4, n - 5)
                on = np.where(on, rng.random(k) > 0.15, rng.random(k) < 0.3)
                sig, shift = 1.2, np.zeros(2)
            else:
                sig, shift = 1.5, rng.normal(0, 1.5, 2)
            for (y, x), a, lit in zip(pos, amp, on if motion == "particles" else [True] * k):
                if lit:
                    img += a * np.exp(-((yy - y - shift[0]) ** 2 + (xx - x - shift[1]) ** 2) / (2 * sig * sig))
            out.append(img)
        return np.stack(out)
    for t in range(frames):
        if motion == "drift":
            f = centre(ndimage.shift(big, (0.3 * t, 0.6 * t), order=3, mode="reflect"), n)
        elif motion == "rotate":
            f = centre(ndimage.rotate(big, 0.75 * t, reshape=False, order=3, mode="reflect"), n)
        elif motion == "deform":
            m = big.shape[0]
            yy, xx = np.mgrid[0:m, 0:m].astype(np.float64)
            phase = 2 * math.pi * (yy / 64 + t / frames)
            f = centre(ndimage.map_coordinates(big, [yy + 2 * np.sin(phase), xx + 2 * np.cos(phase)],
                                               order=3, mode="reflect"), n)
        elif motion == "bleach":
            f = centre(big, n) * math.exp(-0.04 * t)
        elif motion == "cut" and t >= frames // 2:
            f = centre(other, n)
        else:
            f = centre(big, n)
        out.append(np.clip(f, 0, None))
    return np.stack(out)


def psnr(est, truth):
    """PSNR over every pixel of every frame, the truth's peak as range (as `emccd evaluate`)."""
    peak = truth.max()
    return float(10 * math.log10(peak * peak / max(np.mean((est - truth) ** 2), 1e-12)))


def gat(z, alpha, sigma):
    a = alpha * z + 0.375 * alpha * alpha + sigma * sigma
    return np.where(a > 0, 2.0 / alpha * np.sqrt(np.maximum(a, 0)), 0.0)


def gat_inverse(d, alpha, sigma):
    """The closed-form approximation of the exact unbiased inverse (Mäkitalo & Foi 2013), as
    emccd's own (crates/classical/src/vst.rs)."""
    s = sigma / alpha
    d0 = 2.0 * math.sqrt(0.375 + s * s)
    r = math.sqrt(1.5)
    dd = np.maximum(d, 1e-9)
    i = 0.25 * dd * dd + 0.25 * r / dd - 1.375 / (dd * dd) + 0.625 * r / dd ** 3 - 0.125 - s * s
    return np.where(d <= d0, 0.0, alpha * np.maximum(i, 0.0))


def run(cmd):
    t = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    return time.perf_counter() - t


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out", nargs="?", type=Path, default=Path("out/movies"))
    ap.add_argument("--cameras", default="lowlight-a,lowlight-b")
    ap.add_argument("--levels", default="0.5,1,4,16")
    ap.add_argument("--motions", default=",".join(MOTIONS))
    ap.add_argument("--frames", type=int, default=16)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--methods", default="bm3d,blend,temporal")
    ap.add_argument("--no-bm4d", action="store_true")
    ap.add_argument("--uncalibrated", default="", help="methods also run with no --profile (the camera "
                    "characterized from each movie itself), scored here as METHOD@rec")
    ap.add_argument("--data-sheet", action="store_true", help="give the METHOD@rec runs the camera's "
                    "spurious charge as a data sheet would (--cic, --dark, --exposure-s): a recording cannot "
                    "tell it from light")
    ap.add_argument("--fast", action="store_true", help="fast gain mode, no partial CIC in the register")
    ap.add_argument("--seed", type=int, default=11)
    a = ap.parse_args()
    exe = ROOT / "target/release/emccd"
    if not exe.exists():
        subprocess.run(["cargo", "build", "--release", "--locked"], cwd=ROOT, check=True)
    levels = [float(v) for v in a.levels.split(",")]
    motions = a.motions.split(",")
    if unknown := [m for m in motions if m not in MOTIONS]:
        sys.exit(f"unknown motion(s) {', '.join(unknown)}; the motions are {', '.join(MOTIONS)}")
    methods = a.methods.split(",")
    rows, n = [], a.size
    for cam_name in a.cameras.split(","):
        cdir = a.out / cam_name
        # The camera's calibration acquisition and profile, made once (at the movies' size).
        if not (cdir / "profile/profile.toml").exists():
            subprocess.run([sys.executable, str(ROOT / "tools/unseen_camera.py"), str(cdir), "--camera", cam_name,
                            "--size", str(n), "--scenes", str(SCENES[0]), "--mean-electrons", "1"]
                           + (["--fast"] if a.fast else []), check=True)
            run([str(exe), "calibrate", str(cdir / "calibration.toml"), "-o", str(cdir / "profile"), "--force"])
        prof = json.loads(subprocess.run([str(exe), "profile", "show", str(cdir / "profile"), "--json"],
                                         check=True, capture_output=True, text=True).stdout)
        alpha = prof["ptc_slope_dn"]
        sigma = math.sqrt(prof["read_noise_dn"] ** 2 + prof["quantization_dn"] ** 2 / 12)
        spec = unseen_camera.CAMERAS[cam_name]
        cam = dict(unseen_camera.COMMON, **spec["camera"])
        np.random.seed(a.seed)  # emccd-detect draws from numpy's global generator
        det = unseen_camera.detector(cam, a.fast)
        g_dn = cam["em_gain"] / cam["eperdn"]
        hot = np.random.default_rng(a.seed).random((n, n)) < spec["hot_fraction"]
        rng = np.random.default_rng(a.seed + 1)
        mdir = cdir / "movies"
        mdir.mkdir(parents=True, exist_ok=True)
        # The movies, their truth stacks and pairs.toml: movie pairs `emccd evaluate` scores.
        pairs, bm4d_rows, rec_rows = [], {}, {}
        # Every motion's clean movie is made, in MOTIONS' order, so that a run of a few motions
        # has the same scenes and moves as the full run (its noise is drawn anew).
        clean = {}
        for mi, motion in enumerate(MOTIONS):
            scene, other = (unseen_camera.scene_image(SCENES[(mi + j) % 3], n + 64) for j in (0, 1))
            clean[motion] = movie(motion, scene, other, n, a.frames, rng)
        for motion in motions:
            rel = clean[motion]
            for level in levels:
                e = rel * (level / max(rel.mean(), 1e-6))
                stem = f"{motion}_m{level:g}"
                flux = lambda f: f / cam["qe"] / EXPOSURE + hot * (unseen_camera.HOT_RATE / cam["qe"])  # noqa: E731
                raw = np.stack([det.sim_sub_frame(flux(f), EXPOSURE) for f in e]).astype(np.uint16)
                truth = (e * g_dn).astype(np.float32)
                tifffile.imwrite(mdir / f"{stem}.tif", raw, imagej=True)
                tifffile.imwrite(mdir / f"{stem}_truth.tif", truth, imagej=True)
                pairs.append(dict(scene=motion, noisy=f"{stem}.tif", clean=f"{stem}_truth.tif",
                                  exposure_s=EXPOSURE, photons=float(e.max()), mean_electrons=level,
                                  frames=a.frames, width=n, height=n))
                if not a.no_bm4d:
                    import bm4d
                    pre_path = mdir / f"{stem}_none.tif"
                    subprocess.run([str(exe), "denoise", str(mdir / f"{stem}.tif"), "--profile",
                                    str(cdir / "profile"), "--exposure-s", str(EXPOSURE), "--method", "none",
                                    "-o", str(pre_path)], check=True, capture_output=True)
                    pre = tifffile.imread(pre_path).reshape(truth.shape).astype(np.float64)
                    t = time.perf_counter()
                    den = bm4d.bm4d(gat(pre, alpha, sigma), 1.0)
                    est = gat_inverse(np.asarray(den), alpha, sigma)
                    bm4d_rows[(motion, level)] = (psnr(est, truth),
                                                  (time.perf_counter() - t) / a.frames * (512 * 512) / (n * n),
                                                  float(est.mean() / truth.mean()))
                for m in filter(None, a.uncalibrated.split(",")):
                    out_path = mdir / f"{stem}_{m}_rec.tif"
                    t = time.perf_counter()
                    sheet = (["--cic", str(cam["cic"]), "--dark", str(cam["dark_current"]), "--exposure-s",
                              str(EXPOSURE)] if a.data_sheet else [])
                    r = subprocess.run([str(exe), "denoise", str(mdir / f"{stem}.tif"), "--method", m,
                                        "-o", str(out_path), "--force"] + sheet,
                                       capture_output=True, text=True)
                    if r.returncode == 2:
                        # Refused (no dark background to characterize by): a finding, not a crash.
                        why = r.stderr.strip().splitlines()[-1].strip()
                        rec_rows[(motion, level, m)] = (float("nan"), float("nan"), float("nan"), "refused: " + why)
                        print(f"{cam_name} {stem} {m}@rec: refused: {why}", file=sys.stderr)
                        continue
                    r.check_returncode()
                    sec = (time.perf_counter() - t) / a.frames * (512 * 512) / (n * n)
                    est = tifffile.imread(out_path).reshape(truth.shape).astype(np.float64)
                    said = next((l for l in r.stderr.splitlines() if "characterized from the recording" in l), "")
                    rec_rows[(motion, level, m)] = (psnr(est, truth), sec, float(est.mean() / truth.mean()),
                                                    said.split("(no --profile): ")[-1])
                    print(f"{cam_name} {stem} {m}@rec: {rec_rows[(motion, level, m)]}", file=sys.stderr)
                print(f"{cam_name} {stem}: made" + (f", bm4d {bm4d_rows[(motion, level)][0]:.2f} dB"
                                                      if (motion, level) in bm4d_rows else ""), file=sys.stderr)
        with open(mdir / "pairs.toml", "w") as f:
            f.write(f'camera = "{cam_name}"\nprofile = "../profile"\n'
                    f'note = "movies of tools/movie_suite.py: raw stacks and their truth stacks (DN above bias)"\n')
            for p in pairs:
                f.write("\n[[pair]]\n" + "".join(
                    f"{k} = {json.dumps(v)}\n" for k, v in p.items()))
        # Every emccd method through the product: `emccd evaluate` on the movie pairs.
        ev = json.loads(subprocess.run([str(exe), "evaluate", str(mdir), "--json", "--method", "input", *methods],
                                       check=True, capture_output=True, text=True).stdout)
        for motion in motions:
            for level in levels:
                row = dict(camera=cam_name, motion=motion, level=level, frames=a.frames, psnr={}, s_per_512={},
                           mean_ratio={})
                for sc in ev["pairs"]:
                    if sc["scene"] == motion and sc["mean_electrons"] == level:
                        row["psnr"][sc["method"]] = sc["psnr_db"]
                        row["s_per_512"][sc["method"]] = sc["seconds"] / sc["pixels"] * 512 * 512
                        row["mean_ratio"][sc["method"]] = sc.get("mean_ratio")
                if (motion, level) in bm4d_rows:
                    row["psnr"]["bm4d"], row["s_per_512"]["bm4d"], row["mean_ratio"]["bm4d"] = bm4d_rows[(motion, level)]
                for m in filter(None, a.uncalibrated.split(",")):
                    k = f"{m}@rec"
                    row["psnr"][k], row["s_per_512"][k], row["mean_ratio"][k], row["characterized"] = \
                        rec_rows[(motion, level, m)]
                rows.append(row)
                print(json.dumps(row), file=sys.stderr)
        (a.out / "results.json").write_text(json.dumps(rows, indent=1))
    cols = ["input", "bm3d", "blend", "bm4d"] + [m for m in methods if m not in ("bm3d", "blend")]
    cols = [c for c in cols if c == "input" or c in methods or (c == "bm4d" and not a.no_bm4d)]
    cols += [f"{m}@rec" for m in filter(None, a.uncalibrated.split(","))]
    lines = ["| camera | motion | mean e⁻ | " + " | ".join(cols) + " |", "|---" * (3 + len(cols)) + "|"]
    for r in rows:
        lines.append(f"| {r['camera']} | {r['motion']} | {r['level']:g} | "
                     + " | ".join("refused" if math.isnan(r['psnr'][c]) else f"{r['psnr'][c]:.2f}" for c in cols)
                     + " |")
    secs = {c: np.nanmean([r["s_per_512"][c] for r in rows]) for c in cols}
    lines += ["", "seconds per 512² frame: " + ", ".join(f"{c} {secs[c]:.2f}" for c in cols)]
    (a.out / "table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
