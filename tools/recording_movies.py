#!/usr/bin/env python3
"""Still movies from emccd-detect cameras at fixed mean photoelectrons per pixel, for
`emccd calibrate --from-recording` (docs/results.md, "Calibration from a recording").

Writes OUT/CAMERA_LEVEL.tif (FRAMES frames), OUT/CAMERA_LEVEL_one.tif (its first frame) and
OUT/CAMERA_LEVEL_clean.tif (the photoelectrons each frame's pixels expect, float32, without the
smear) for the levels 0.5, 1, 4 and 16, and OUT/CAMERA_truth.json (the simulator's slope, bias,
read noise, and the smear).

--smear X adds frame-transfer smear in its steady state: each pixel's light gains X times its
column's mean light (a frame-transfer sensor's rows move under the whole column, in the frame's
transfer out and the next one's in), before emccd-detect's photon and register physics; the
simulator's own smear (`row_read_time`) is one-sided and stays off. --scene stars: sparse point
sources on a dark sky instead of the FMD cells; --drift PX: the scene moves PX to the right a frame.

Usage: python3 tools/recording_movies.py OUT --camera lowlight-a [--size 256] [--frames 20]
           [--smear 0.05] [--scene fmd|stars] [--drift 0.5] [--levels 0.5,1,4,16]
"""
import argparse
import json
import sys
from pathlib import Path

import numpy as np
import tifffile

sys.path.insert(0, str(Path(__file__).resolve().parent))
import unseen_camera as u  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out", type=Path)
    ap.add_argument("--camera", choices=sorted(u.CAMERAS), default="lowlight-a")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--smear", type=float, default=0.0, help="share of its column's mean light each pixel gains")
    ap.add_argument("--scene", choices=["fmd", "stars"], default="fmd")
    ap.add_argument("--drift", type=float, default=0.0, help="px a frame to the right")
    ap.add_argument("--levels", type=u.numbers, default=[0.5, 1, 4, 16])
    a = ap.parse_args()
    np.random.seed(a.seed)  # emccd-detect draws from numpy's global generator
    cam = dict(u.COMMON, **u.CAMERAS[a.camera]["camera"])
    det = u.detector(cam, True)
    n = a.size
    pad = int(np.ceil(abs(a.drift) * a.frames)) + 1
    if a.scene == "fmd":
        big = u.scene_image(u.DEFAULT_SCENES[0], n + pad)
        y0, x0 = (big.shape[0] - n) // 2, (big.shape[1] - n - pad) // 2
        big = big[y0:y0 + n, x0:x0 + n + pad]
    else:
        rng = np.random.default_rng(a.seed)
        yy, xx = np.mgrid[0:n, 0:n + pad]
        big = np.full((n, n + pad), 0.01)
        for _ in range((n + pad) * n // 400):
            cx, cy, w = rng.random() * (n + pad), rng.random() * n, rng.uniform(1.0, 2.0)
            big += rng.pareto(1.5) * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * w * w))

    def at(k):
        """Frame k's scene: the wide one sampled at a shift of k·drift px (linear interpolation)."""
        s = k * a.drift
        i, f = int(np.floor(s)), s - np.floor(s)
        return (1 - f) * big[:, pad - i - 1:pad - i - 1 + n] + f * big[:, pad - i - 2:pad - i - 2 + n] if a.drift else big[:, :n]

    a.out.mkdir(parents=True, exist_ok=True)
    t = u.TEST_EXPOSURE
    frames = [at(k) for k in range(a.frames)]
    norm = np.mean(frames)
    for mean in a.levels:
        clean = np.stack([f / norm * mean for f in frames])
        lit = clean + a.smear * clean.mean(axis=1, keepdims=True)
        stack = np.stack([det.sim_sub_frame(e / cam["qe"] / t, t) for e in lit]).astype(np.uint16)
        tifffile.imwrite(a.out / f"{a.camera}_{mean}.tif", stack, imagej=True)
        tifffile.imwrite(a.out / f"{a.camera}_{mean}_one.tif", stack[:1], imagej=True)
        tifffile.imwrite(a.out / f"{a.camera}_{mean}_clean.tif", clean.astype(np.float32), imagej=True)
    g = cam["em_gain"] / cam["eperdn"]
    truth = dict(k_dn=g, slope=2 * g, bias_dn=cam["bias"] / cam["eperdn"], read_dn=cam["read_noise"] / cam["eperdn"],
                 smear=a.smear)
    (a.out / f"{a.camera}_truth.json").write_text(json.dumps(truth))
    print(truth)


if __name__ == "__main__":
    main()
