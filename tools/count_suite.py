"""The photon-counting suite: stacks of known truth at 0.02–1 photo-electrons per pixel per frame
from emccd's virtual camera (the bundled profile's camera, through the Python package), each
counted with `emccd.count` (threshold `auto`), averaged with the analog estimate (`analog=True`,
the same preprocessing), and beside them the ideal detector: a Poisson-limited one with no excess
noise and no read noise (each frame's photo-electrons counted exactly, averaged). PSNR against the
truth (its peak as range), dB, and the mean ratio (output mean over the truth's).

    python3 tools/count_suite.py [--levels 0.02,0.05,0.1,0.2,0.5,1] [--frames 500] [--size 128]

Needs the package (`pip install ./python`) and numpy; the scenes are the repository's own
(tests/data: an FMD confocal field and a Kodak image).
"""

import argparse
import sys
from pathlib import Path

import numpy as np

import emccd

ROOT = Path(__file__).resolve().parent.parent
SCENES = [ROOT / "tests/data/clean/microscopy/fmd-confocal-bpae/field2-avg50.png",
          ROOT / "tests/data/clean/natural/Kodak24/kodim03.png"]


def psnr(est, truth):
    mse = float(np.mean((est.astype(np.float64) - truth) ** 2))
    return 10 * np.log10(float(truth.max()) ** 2 / mse)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--levels", default="0.02,0.05,0.1,0.2,0.5,1")
    ap.add_argument("--frames", type=int, default=500)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--seed", type=int, default=3)
    a = ap.parse_args()
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
            rate, _ = emccd.count(raw, prof, exposure_s=0.01)
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
