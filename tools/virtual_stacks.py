#!/usr/bin/env python3
"""Recordings for measuring `emccd adapt` from emccd's own virtual camera (the bundled iXon 897
model, its top-left 256x256 sub-array): per scene and mean light level, a stack of noisy frames
of a static scene to adapt on, and separate held-out frames of the same scene with its ground
truth (pairs for `emccd evaluate`). The same layout as tools/adapt_stacks.py (emccd-detect), so
tools/adapt_bench.sh runs on either. The frames come from `emccd simulate pairs` (one run per
scene and level: frames 1..N the stack, the rest held out), so the camera — its hot pixels and
fixed pattern — is the same in every stack; the profile to adapt and denoise with is the
bundled default cut to the sub-array (`emccd profile crop`), written to OUT/profile.

Writes, for each scene S and level m:
  OUT/S_mM/stack.tif                      --frames frames to adapt on (ImageJ TIFF, uint16)
  OUT/S_mM/pairs/pairs.toml, noisy/, clean/  --held-out frames never used for adaptation
  OUT/profile/                            the profile of the sub-array

Usage: python3 tools/virtual_stacks.py OUT --scenes FILE... [--frames 20] [--held-out 4]
           [--mean-electrons 1,4,16] [--size 256] [--seed 5] [--emccd PATH]
"""

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import tifffile

ROOT = Path(__file__).resolve().parent.parent
EXPOSURE = 0.01


def numbers(s):
    return [float(v) for v in s.split(",")]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out", type=Path)
    ap.add_argument("--scenes", nargs="+", required=True)
    ap.add_argument("--frames", type=int, default=20, help="frames to adapt on")
    ap.add_argument("--held-out", type=int, default=4, help="held-out frames scored per scene and level")
    ap.add_argument("--mean-electrons", type=numbers, default=[1.0, 4.0, 16.0])
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--seed", type=int, default=5, help="the camera's seed (hot pixels) and the noise's")
    ap.add_argument("--emccd", default=str(ROOT / "target/release/emccd"))
    a = ap.parse_args()
    if a.frames < 1 or a.held_out < 1:
        sys.exit("--frames and --held-out must be at least 1")
    n = a.size

    def emccd(*args):
        r = subprocess.run([a.emccd, *map(str, args)], capture_output=True, text=True)
        if r.returncode != 0:
            sys.exit(f"emccd {' '.join(map(str, args))} failed:\n{r.stderr}")

    profile = a.out / "profile"
    if not (profile / "profile.toml").exists():
        emccd("profile", "crop", "default", profile, "--roi", f"0,0,{n}x{n}")
    common = ["--crop", f"{n}x{n}", "--seed", a.seed, "--exposure-s", EXPOSURE]
    for sc in a.scenes:
        sc = Path(sc)
        with tempfile.TemporaryDirectory() as tmp:
            # One photon level first, to learn the scene's mean as the camera sees it (its
            # centre crop, luminance, through the quantum efficiency and K).
            probe = Path(tmp) / "probe"
            emccd("simulate", "pairs", "--clean", sc, "--photons", 1000, "-o", probe, *common)
            m_probe = float(tifffile.imread(next((probe / "clean").glob("*.tif"))).mean())
            k = float(next(line.split("=")[1] for line in (probe / "pairs.toml").read_text().splitlines()
                           if line.startswith("k_dn_per_e")))
            for m in a.mean_electrons:
                photons = 1000 * m / (m_probe / k)
                run = Path(tmp) / f"m{m:g}"
                emccd("simulate", "pairs", "--clean", sc, "--photons", f"{photons:.6g}",
                      "--frames", a.frames + a.held_out, "-o", run, *common)
                noisy = tifffile.imread(next((run / "noisy").glob("*.tif")))
                clean = tifffile.imread(next((run / "clean").glob("*.tif"))).astype(np.float32)
                d = a.out / f"{sc.stem}_m{m:g}"
                (d / "pairs/noisy").mkdir(parents=True, exist_ok=True)
                (d / "pairs/clean").mkdir(parents=True, exist_ok=True)
                tifffile.imwrite(d / "stack.tif", noisy[: a.frames], imagej=True,
                                 metadata={"exposure_s": EXPOSURE})
                tifffile.imwrite(d / "pairs/clean/truth.tif", clean[None], imagej=True)
                pairs = [f"# Held-out frames of {sc.name} at {m:g} mean e-/pixel, emccd's virtual camera.",
                         'camera = "virtual-897"', 'profile = "../../profile"', ""]
                for j, f in enumerate(noisy[a.frames:]):
                    tifffile.imwrite(d / f"pairs/noisy/{j + 1:02d}.tif", f[None], imagej=True,
                                     metadata={"exposure_s": EXPOSURE})
                    pairs += ["[[pair]]", f'scene = "{sc.name}"', f'noisy = "noisy/{j + 1:02d}.tif"',
                              'clean = "clean/truth.tif"', f"exposure_s = {EXPOSURE}",
                              f"photons = {photons:.6g}", f"mean_electrons = {m:g}", ""]
                (d / "pairs/pairs.toml").write_text("\n".join(pairs))
                print(f"virtual: {d.name}: {a.frames} frames + {a.held_out} held out "
                      f"(mean {clean.mean() / k:.3f} e-/pixel)", file=sys.stderr)


if __name__ == "__main__":
    main()
