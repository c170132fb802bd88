#!/usr/bin/env python3
"""Still movies from emccd-detect cameras at fixed mean photoelectrons per pixel, for
`emccd calibrate --from-recording` (docs/results.md, "Calibration from a recording").

Writes OUT/CAMERA_LEVEL.tif (FRAMES frames) and OUT/CAMERA_LEVEL_one.tif (its first frame) for
the levels 0.5, 1, 4 and 16, and OUT/CAMERA_truth.json (the simulator's slope, bias, read noise).

Usage: python3 tools/recording_movies.py OUT --camera lowlight-a [--size 256] [--frames 20]
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
    a = ap.parse_args()
    np.random.seed(a.seed)  # emccd-detect draws from numpy's global generator
    cam = dict(u.COMMON, **u.CAMERAS[a.camera]["camera"])
    det = u.detector(cam, True)
    n = a.size
    scene = u.scene_image(u.DEFAULT_SCENES[0], n)
    y0, x0 = (scene.shape[0] - n) // 2, (scene.shape[1] - n) // 2
    scene = scene[y0:y0 + n, x0:x0 + n]
    a.out.mkdir(parents=True, exist_ok=True)
    t = u.TEST_EXPOSURE
    for mean in [0.5, 1, 4, 16]:
        e = scene / scene.mean() * mean
        stack = np.stack([det.sim_sub_frame(e / cam["qe"] / t, t) for _ in range(a.frames)]).astype(np.uint16)
        tifffile.imwrite(a.out / f"{a.camera}_{mean}.tif", stack, imagej=True)
        tifffile.imwrite(a.out / f"{a.camera}_{mean}_one.tif", stack[:1], imagej=True)
    g = cam["em_gain"] / cam["eperdn"]
    truth = dict(k_dn=g, slope=2 * g, bias_dn=cam["bias"] / cam["eperdn"], read_dn=cam["read_noise"] / cam["eperdn"])
    (a.out / f"{a.camera}_truth.json").write_text(json.dumps(truth))
    print(truth)


if __name__ == "__main__":
    main()
