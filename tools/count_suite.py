"""The photon-counting suite: stacks of known truth at 0.02–1 photo-electrons per pixel per frame,
each counted (`--threshold`: the command's default, `likelihood`, unless given), averaged with the analog estimate (the same preprocessing), and
beside them the ideal detector: a Poisson-limited one with no excess noise and no read noise (each
frame's photo-electrons counted exactly, averaged). PSNR against the truth (its peak as range),
dB, and the mean ratio (output mean over the truth's).

Cameras (--camera):
  virtual     emccd's own virtual camera of the bundled profile, through the Python package
              (`emccd.count`); the profile's read noise and CIC are the simulation's.
  lowlight-a  NASA JPL's emccd-detect (tools/unseen_camera.py's camera: EM gain 300, 75 DN per
              electron, read noise 12 DN, CIC 0.02 e⁻, dark 0.01 e⁻/s, hot pixels) in its fast
              gain mode without partial CIC (`--fast`: the default mode takes about a second a
              frame), calibrated with `emccd calibrate` from its own bias and flat stacks
              (--bias-frames each), counted with the `emccd count` command; also with per-pixel
              read noise (`--read-noise pixel`).

    python3 tools/count_suite.py [--camera virtual] [--levels 0.02,0.05,0.1,0.2,0.5,1] [--frames 500] [--size 128]
    python3 tools/count_suite.py --camera lowlight-a --out OUT [--levels 0.05,0.1,0.2,0.5,1]

Needs numpy, the package (`pip install ./python`) for the virtual camera, emccd-detect, tifffile
and the `emccd` binary (target/release or PATH) for lowlight-a; the scenes are the repository's
own (tests/data: an FMD confocal field and a Kodak image).
"""

import argparse
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SCENES = [ROOT / "tests/data/clean/microscopy/fmd-confocal-bpae/field2-avg50.png",
          ROOT / "tests/data/clean/natural/Kodak24/kodim03.png"]


def psnr(est, truth):
    mse = float(np.mean((est.astype(np.float64) - truth) ** 2))
    return 10 * np.log10(float(truth.max()) ** 2 / mse)


def centre(path, n):
    """The scene's central n² crop, its peak scaled to 1."""
    from PIL import Image
    img = np.asarray(Image.open(path).convert("L"), dtype=np.float64)
    y0, x0 = (img.shape[0] - n) // 2, (img.shape[1] - n) // 2
    img = img[y0:y0 + n, x0:x0 + n]
    return img / img.max()


def binary():
    local = ROOT / "target/release/emccd"
    return str(local) if local.exists() else (shutil.which("emccd") or "emccd")


def emccd_detect_camera(a):
    """The lowlight-a rows: acquisition, calibration, stacks, `emccd count`."""
    import tifffile
    sys.path.insert(0, str(ROOT / "tools"))
    import unseen_camera as uc

    out, n, exe = a.out, a.size, binary()
    acq = out / "acquisition"
    if not (acq / "calibration.toml").exists():
        subprocess.run([sys.executable, str(ROOT / "tools/unseen_camera.py"), str(acq), "--camera", a.camera,
                        "--size", str(n), "--frames", str(a.bias_frames), "--seed", str(a.seed),
                        "--scenes", str(SCENES[0]), "--mean-electrons", "0.1", "--fast"], check=True)
    profile = out / "profile"
    if not (profile / "profile.toml").exists():
        subprocess.run([exe, "calibrate", str(acq / "calibration.toml"), "-o", str(profile)], check=True)
    # The acquisition's camera: the same settings, seed and hot pixels (unseen_camera.py draws
    # them from default_rng(seed) first).
    spec = uc.CAMERAS[a.camera]
    cam = dict(uc.COMMON, **spec["camera"])
    hot = np.random.default_rng(a.seed).random((n, n)) < spec["hot_fraction"]
    np.random.seed(a.seed + 1000)
    det = uc.detector(cam, fast=True)
    t = uc.TEST_EXPOSURE
    rng = np.random.default_rng(a.seed)
    rows, totals = [], {}
    for si, path in enumerate(SCENES[:a.scenes]):
        scene = centre(path, n)
        for level in (float(v) for v in a.levels.split(",")):
            want = scene * (level / scene.mean())
            stack = out / f"{path.stem}_{level:g}.tif"
            if not stack.exists():
                flux = want / cam["qe"] / t + hot * (uc.HOT_RATE / cam["qe"])
                frames = np.stack([det.sim_sub_frame(flux, t) for _ in range(a.frames)]).astype(np.uint16)
                tifffile.imwrite(stack, frames, imagej=True)
            res = {}
            for name, extra in [("counting", ["--threshold", a.threshold]), ("analog", ["--analog"]),
                                ("per-pixel", ["--threshold", a.threshold, "--read-noise", "pixel"])]:
                dst = out / f"{path.stem}_{level:g}_{name}_{a.threshold}.tif"
                r = subprocess.run([exe, "count", str(stack), "-o", str(dst), "--profile", str(profile),
                                    "--exposure-s", str(t)] + extra, capture_output=True, text=True)
                if r.returncode != 0:
                    sys.exit(r.stderr)
                res[name] = tifffile.imread(dst).astype(np.float64)
                if name == "counting":
                    note = r.stderr.strip().splitlines()[-1]
                    threshold = note.split("threshold ", 1)[1].split(";", 1)[0]
            ideal = rng.poisson(np.broadcast_to(want, (a.frames,) + want.shape)).mean(axis=0)
            c, g, p, i = (psnr(res["counting"], want), psnr(res["analog"], want),
                          psnr(res["per-pixel"], want), psnr(ideal, want))
            totals.setdefault(level, []).append((c, g, i, p, res["counting"].mean() / want.mean(),
                                                 res["analog"].mean() / want.mean()))
            print(f"| {path.stem} | {level:g} | {c:.2f} | {g:.2f} | {c - g:+.2f} | {i:.2f} | {p:.2f} | {threshold} | "
                  f"{res['counting'].mean() / want.mean():.4f} | {res['analog'].mean() / want.mean():.4f} |", flush=True)
    print()
    print("| e⁻/px/frame | counting | analog | counting − analog | ideal − counting | per-pixel σ − camera σ | mean ratio counting / analog |")
    print("|---:|---:|---:|---:|---:|---:|---|")
    for level, rs in totals.items():
        c, g, i, p, mc, ma = (float(np.mean([r[j] for r in rs])) for j in range(6))
        print(f"| {level:g} | {c:.2f} | {g:.2f} | {c - g:+.2f} | {i - c:.2f} | {p - c:+.2f} | {mc:.4f} / {ma:.4f} |")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--camera", default="virtual", choices=["virtual", "lowlight-a", "lowlight-b", "tune"])
    ap.add_argument("--out", type=Path, help="working folder (emccd-detect cameras: kept, reused)")
    ap.add_argument("--levels", default=None)
    ap.add_argument("--frames", type=int, default=None)
    ap.add_argument("--size", type=int, default=None)
    ap.add_argument("--bias-frames", type=int, default=200)
    ap.add_argument("--scenes", type=int, default=None, help="how many of the two scenes (emccd-detect: 1)")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--threshold", default="likelihood", help="what the counting column runs: likelihood (the default), auto, <k>sigma, <n>DN")
    a = ap.parse_args()
    if a.camera != "virtual":
        a.levels = a.levels or "0.02,0.05,0.1,0.2,0.5,1"
        a.frames, a.size = a.frames or 500, a.size or 128
        a.scenes = a.scenes or 2
        if a.out is None:
            sys.exit("--out: a working folder for the emccd-detect camera's acquisition and stacks")
        a.out.mkdir(parents=True, exist_ok=True)
        print("| scene | e⁻/px/frame | counting | analog | counting − analog | ideal | counting, per-pixel σ | threshold | mean ratio (counting) | mean ratio (analog) |")
        print("|---|---:|---:|---:|---:|---:|---:|---|---:|---:|")
        return emccd_detect_camera(a)
    import emccd
    a.levels = a.levels or "0.02,0.05,0.1,0.2,0.5,1"
    a.frames, a.size = a.frames or 500, a.size or 128
    n = a.size
    profile = emccd.load_profile("default")
    prof = profile.crop(0, 0, n, n)
    k_dn = profile.slope / 2
    rng = np.random.default_rng(a.seed)
    print("| scene | e⁻/px/frame | counting | analog | counting − analog | ideal | counting's threshold | mean ratio (counting) |")
    print("|---|---:|---:|---:|---:|---:|---|---:|")
    totals = {}
    for si, path in enumerate(SCENES):
        img, _ = emccd.read(path)
        img = img[0]
        y0, x0 = (img.shape[0] - n) // 2, (img.shape[1] - n) // 2
        scene = img[y0:y0 + n, x0:x0 + n].astype(np.float32)
        scene = scene / scene.max()
        for li, level in enumerate(float(v) for v in a.levels.split(",")):
            raw, truth = emccd.simulate_pairs(scene, profile=prof, mean_electrons=level, exposure_s=0.01,
                                              frames=a.frames, seed=a.seed + 100 * si + li)
            want = truth.astype(np.float64) / k_dn
            rate, _ = emccd.count(raw, prof, exposure_s=0.01, threshold=a.threshold)
            threshold = next(t for t in emccd.count.last_notes if t.startswith("threshold"))
            analog, _ = emccd.count(raw, prof, exposure_s=0.01, analog=True)
            ideal = rng.poisson(np.broadcast_to(want, (a.frames,) + want.shape)).mean(axis=0)
            c, g, i = psnr(rate, want), psnr(analog, want), psnr(ideal, want)
            totals.setdefault(level, []).append((c, g, i))
            print(f"| {path.stem} | {level:g} | {c:.2f} | {g:.2f} | {c - g:+.2f} | {i:.2f} | "
                  f"{threshold.split(' ', 1)[1]} | {rate.mean() / want.mean():.4f} |", flush=True)
    print()
    print("| e⁻/px/frame | counting | analog | counting − analog | ideal − counting |")
    print("|---:|---:|---:|---:|---:|")
    for level, rows in totals.items():
        c, g, i = (float(np.mean([r[j] for r in rows])) for j in range(3))
        print(f"| {level:g} | {c:.2f} | {g:.2f} | {c - g:+.2f} | {i - c:.2f} |")


if __name__ == "__main__":
    sys.exit(main())
