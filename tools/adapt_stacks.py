#!/usr/bin/env python3
"""Recordings for measuring `emccd adapt`: per scene and light level, a stack of noisy frames of a
static scene to adapt on, and separate held-out frames of the same scene with their ground truth
(pairs for `emccd evaluate`), from one of tools/unseen_camera.py's emccd-detect cameras. The
camera (gain, read noise, fixed pattern, hot-pixel map for the same --seed and --size) is the one
unseen_camera.py acquires for calibration, so the profile `emccd calibrate` made from that
acquisition applies.

Writes, for each scene S and level m:
  OUT/S_mM/stack.tif                      --frames frames to adapt on (ImageJ TIFF, uint16)
  OUT/S_mM/pairs/pairs.toml, noisy/, clean/  --held-out frames never used for adaptation

Usage: python3 tools/adapt_stacks.py OUT --camera lowlight-a [--frames 20] [--held-out 4]
           [--mean-electrons 1,4,16] [--scenes FILE...] [--size 256] [--seed 5]
"""

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np
import tifffile
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parent))
warnings.filterwarnings("ignore")
from unseen_camera import CAMERAS, COMMON, HOT_RATE, TEST_EXPOSURE, numbers, scene_files  # noqa: E402
from emccd_detect.emccd_detect import EMCCDDetect  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out", type=Path)
    ap.add_argument("--camera", choices=sorted(CAMERAS), default="lowlight-a")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--seed", type=int, default=5, help="the acquisition's seed (same hot pixels)")
    ap.add_argument("--frames", type=int, default=20, help="frames to adapt on")
    ap.add_argument("--held-out", type=int, default=4, help="held-out frames scored per scene and level")
    ap.add_argument("--mean-electrons", type=numbers, default=[1.0, 4.0, 16.0])
    ap.add_argument("--scenes", nargs="+", required=True)
    a = ap.parse_args()
    if a.frames < 1 or a.held_out < 1:
        sys.exit("--frames and --held-out must be at least 1")
    n = a.size
    spec = CAMERAS[a.camera]
    cam = dict(COMMON, **spec["camera"])
    # The hot-pixel map exactly as unseen_camera.py draws it for this seed and size.
    hot = np.random.default_rng(a.seed).random((n, n)) < spec["hot_fraction"]
    np.random.seed(a.seed + 1000)  # the noise: other draws than the acquisition's
    det = EMCCDDetect(**cam)
    g_dn = cam["em_gain"] / cam["eperdn"]
    qe = cam["qe"]
    name = f"emccd-detect 2.6 ({a.camera})"

    def frames(photo_e, count):
        flux = photo_e / qe / TEST_EXPOSURE + hot * (HOT_RATE / qe)
        return np.stack([det.sim_sub_frame(flux, TEST_EXPOSURE) for _ in range(count)]).astype(np.uint16)

    def write(path, stack, **kw):
        path.parent.mkdir(parents=True, exist_ok=True)
        tifffile.imwrite(path, stack, imagej=True, **kw)

    for sc in scene_files(a.scenes):
        img = np.asarray(Image.open(sc).convert("L"), dtype=np.float64) / 255.0
        y0, x0 = (img.shape[0] - n) // 2, (img.shape[1] - n) // 2
        img = img[y0:y0 + n, x0:x0 + n]
        for m in a.mean_electrons:
            e = img * (m / max(img.mean(), 1e-3))
            d = a.out / f"{sc.stem}_m{m:g}"
            write(d / "stack.tif", frames(e, a.frames), metadata={"exposure_s": TEST_EXPOSURE})
            pairs = [f'# Held-out frames of {sc.name} at {m:g} mean e-/pixel, camera "{a.camera}".',
                     f'camera = "{name}"', ""]
            write(d / "pairs/clean/truth.tif", (e * g_dn).astype(np.float32)[None])
            for k, f in enumerate(frames(e, a.held_out)):
                write(d / f"pairs/noisy/{k + 1:02d}.tif", f[None])
                pairs += ["[[pair]]", f'scene = "{sc.name}"', f'noisy = "noisy/{k + 1:02d}.tif"',
                          'clean = "clean/truth.tif"', f"exposure_s = {TEST_EXPOSURE}",
                          f"photons = {e.max() / qe:.6g}", f"mean_electrons = {m:g}", ""]
            (d / "pairs/pairs.toml").write_text("\n".join(pairs))
            print(f"{a.camera}: {d.name}: {a.frames} frames + {a.held_out} held out", file=sys.stderr)


if __name__ == "__main__":
    main()
