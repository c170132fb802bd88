#!/usr/bin/env python3
"""A camera emccd never saw: acquisitions from NASA JPL's `emccd-detect` simulator (pip package
emccd-detect), written in the forms `emccd calibrate` and `emccd evaluate` read.

emccd-detect models the EMCCD differently from emccd's own virtual camera: a stage-by-stage
gain register (604 stages, clock-induced charge inside the register), its own fixed-pattern
map (the Roman detector's measured map, the simulator's default `fpn_path`), a different gain,
read noise and electrons per DN. Hot pixels are added here as a dark-current map that passes
through the simulator's EM register like any other charge. Frame-transfer smear is switched off
(`row_read_time = 0`): with it on, the expected signal of a pixel depends on its whole column
and no per-pixel ground truth exists.

Writes:
  OUT/calibration.toml, OUT/bias/*.tif, OUT/flat/*.tif   acquisition for `emccd calibrate`
  OUT/pairs/pairs.toml, OUT/pairs/{noisy,clean}/*.tif    test pairs for `emccd evaluate`
  OUT/truth.toml                                         the simulator's settings

Usage: python3 tools/unseen_camera.py OUT [--size 256] [--frames 16] [--seed 5]
"""

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np
import tifffile
from PIL import Image

warnings.filterwarnings("ignore")
from emccd_detect.emccd_detect import EMCCDDetect  # noqa: E402

# The unseen camera. Gain, read noise and conversion differ from the bundled iXon model
# (G = 300, s = 20.1 DN, read noise 3 DN).
CAMERA = dict(
    em_gain=150.0,
    full_well_image=60000.0,
    full_well_serial=100000.0,
    dark_current=0.01,  # e-/pix/s
    cic=0.02,  # e-/pix/frame
    read_noise=80.0,  # e- rms at the amplifier: 10 DN
    bias=4000.0,  # e-: 500 DN
    qe=0.85,
    cr_rate=0.0,
    pixel_pitch=13e-6,
    eperdn=8.0,
    nbits=16,
    numel_gain_register=604,
    row_read_time=0.0,
)
HOT_FRACTION = 5e-4
HOT_RATE = 400.0  # e-/s
BIAS_EXPOSURES = [1e-4, 1e-3, 3e-3, 0.01, 0.03, 0.1, 0.3]
FLAT_DN = [20, 50, 120, 300, 700, 1500, 3500]  # DN above bias at 10 ms
TEST_EXPOSURE = 0.01
PHOTONS = [20.0, 200.0]  # photons at a scene's brightest pixel
SCENES = ["field4-avg50.png", "field5-avg50.png", "field6-avg50.png"]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out", type=Path)
    ap.add_argument("--size", type=int, default=256, help="frame side, px (centre crop of the scenes)")
    ap.add_argument("--frames", type=int, default=16, help="frames per calibration stack")
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--scenes", type=Path, default=Path(__file__).resolve().parent.parent.parent / "shared/data/clean/microscopy/fmd-confocal-bpae")
    a = ap.parse_args()
    np.random.seed(a.seed)  # emccd-detect draws from numpy's global generator
    n = a.size
    det = EMCCDDetect(**CAMERA)
    rng = np.random.default_rng(a.seed)
    hot = rng.random((n, n)) < HOT_FRACTION
    g_dn = CAMERA["em_gain"] / CAMERA["eperdn"]  # DN per electron entering the register
    qe = CAMERA["qe"]

    def frames(photo_e, t, count):
        """`count` frames with `photo_e` expected photo-electrons per pixel and exposure t."""
        flux = photo_e / qe / t + hot * (HOT_RATE / qe)
        return np.stack([det.sim_sub_frame(flux, t) for _ in range(count)]).astype(np.uint16)

    def write(path, stack, **kw):
        path.parent.mkdir(parents=True, exist_ok=True)
        tifffile.imwrite(path, stack, imagej=True, **kw)

    out = a.out
    manifest = ['# Calibration acquisition of the unseen camera (emccd-detect); paths relative to this file.',
                'camera = "emccd-detect 2.6 (unseen camera)"', f'em_gain = {CAMERA["em_gain"]}', '']
    zero = np.zeros((n, n))
    for t in BIAS_EXPOSURES:
        name = f"bias/bias_{t:g}s.tif"
        write(out / name, frames(zero, t, a.frames))
        manifest += ["[[bias]]", f'file = "{name}"', f"exposure_s = {t}", ""]
        print(f"bias {t:g} s", file=sys.stderr)
    for k, dn in enumerate(FLAT_DN):
        name = f"flat/flat_{k + 1:02d}.tif"
        write(out / name, frames(np.full((n, n), dn / g_dn), TEST_EXPOSURE, a.frames))
        manifest += ["[[flat]]", f'file = "{name}"', f"exposure_s = {TEST_EXPOSURE}", ""]
        print(f"flat {dn} DN", file=sys.stderr)
    (out / "calibration.toml").write_text("\n".join(manifest))

    pairs = ['# Test pairs from the unseen camera; paths relative to this file.',
             'camera = "emccd-detect 2.6 (unseen camera)"',
             'note = "clean: expected photo-signal in DN above bias, QE * photons * G / (e-/DN), float32"', '']
    for sc in SCENES:
        img = np.asarray(Image.open(a.scenes / sc).convert("L"), dtype=np.float64) / 255.0
        y0, x0 = (img.shape[0] - n) // 2, (img.shape[1] - n) // 2
        img = img[y0:y0 + n, x0:x0 + n]
        for p in PHOTONS:
            e = img * p * qe
            stem = f"{Path(sc).stem}_p{p:g}"
            write(out / "pairs/noisy" / f"{stem}.tif", frames(e, TEST_EXPOSURE, 1))
            write(out / "pairs/clean" / f"{stem}.tif", (e * g_dn).astype(np.float32)[None])
            pairs += ["[[pair]]", f'scene = "{sc}"', f'noisy = "noisy/{stem}.tif"', f'clean = "clean/{stem}.tif"',
                      f"exposure_s = {TEST_EXPOSURE}", f"photons = {p}", ""]
            print(f"pair {stem}", file=sys.stderr)
    (out / "pairs/pairs.toml").write_text("\n".join(pairs))
    truth = [f"{k} = {v!r}" for k, v in CAMERA.items()]
    truth += [f"hot_fraction = {HOT_FRACTION}", f"hot_rate_e_per_s = {HOT_RATE}",
              f"# expected photon-transfer slope 2 G / (e-/DN) = {2 * g_dn:.4f} DN (ideal register)",
              f"# read noise {CAMERA['read_noise'] / CAMERA['eperdn']:.2f} DN"]
    (out / "truth.toml").write_text("\n".join(truth) + "\n")


if __name__ == "__main__":
    main()
