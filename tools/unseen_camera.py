#!/usr/bin/env python3
"""Cameras emccd never saw: acquisitions from NASA JPL's `emccd-detect` simulator (pip package
emccd-detect), written in the forms `emccd calibrate` and `emccd evaluate` read.

emccd-detect models the EMCCD differently from emccd's own virtual camera: a stage-by-stage
gain register (604 stages, clock-induced charge inside the register), its own fixed-pattern
map (the Roman detector's measured map, the simulator's default `fpn_path`), and its own gain,
read noise and electrons per DN. Hot pixels are added here as a dark-current map that passes
through the simulator's EM register like any other charge. Frame-transfer smear is switched off
(`row_read_time = 0`): with it on, the expected signal of a pixel depends on its whole column
and no per-pixel ground truth exists.

Cameras (--camera):
  unseen      EM gain 150, slope 37.5 DN, read noise 10 DN (the README's "unseen camera")
  lowlight-a  EM gain 300, slope 150 DN, read noise 12 DN, CIC 0.02 e-, hot pixels 5e-4
  lowlight-b  EM gain 1000, slope 30 DN, read noise 5 DN, CIC 0.05 e-, hot pixels 2e-3
  tune        EM gain 500, slope 80 DN, read noise 8 DN, CIC 0.03 e-, hot pixels 1e-3 (validation:
              for choosing settings, on scenes outside the low-light suite)

Test pairs are either at fixed photons at a scene's brightest pixel (--photons, the default
mode) or at fixed *mean* photoelectrons per pixel (--mean-electrons, how the low-light suite
and EMCCD users quote light levels).

Writes:
  OUT/calibration.toml, OUT/bias/*.tif, OUT/flat/*.tif   acquisition for `emccd calibrate`
  OUT/pairs/pairs.toml, OUT/pairs/{noisy,clean}/*.tif    test pairs for `emccd evaluate`
  OUT/truth.toml                                         the simulator's settings

--fast: the simulator's fast gain mode (an Erlang register) without its partial CIC (charge
born inside the register, about 0.14 e⁻ per frame at G = 300, with partial gain): 25 times
faster, for the photon-counting suite's long stacks.

Usage: python3 tools/unseen_camera.py OUT [--camera unseen] [--size 256] [--frames 16] [--seed 5]
           [--scenes FILE_OR_DIR...] [--photons 20,200 | --mean-electrons 0.5,1,4,16] [--fast]
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

COMMON = dict(full_well_image=60000.0, qe=0.85, cr_rate=0.0, pixel_pitch=13e-6, nbits=16,
              numel_gain_register=604, row_read_time=0.0)
# Each differs from the bundled iXon model (G = 300, s = 20.1 DN, read noise 3 DN) and from
# the others. Read noise and bias are in electrons at the amplifier, as emccd-detect takes them.
CAMERAS = {
    "unseen": dict(camera=dict(em_gain=150.0, full_well_serial=100000.0, dark_current=0.01, cic=0.02,
                               read_noise=80.0, bias=4000.0, eperdn=8.0),
                   hot_fraction=5e-4, flat_e=[1.07, 2.67, 6.4, 16.0, 37.3, 80.0, 186.7]),
    "lowlight-a": dict(camera=dict(em_gain=300.0, full_well_serial=1e6, dark_current=0.01, cic=0.02,
                                   read_noise=48.0, bias=2000.0, eperdn=4.0),
                       hot_fraction=5e-4, flat_e=[2.0, 5.0, 12.0, 30.0, 70.0, 150.0]),
    "lowlight-b": dict(camera=dict(em_gain=1000.0, full_well_serial=2e6, dark_current=0.05, cic=0.05,
                                   read_noise=333.3, bias=6667.0, eperdn=66.67),
                       hot_fraction=2e-3, flat_e=[2.0, 5.0, 12.0, 30.0, 70.0, 150.0]),
    # For choosing settings and checkpoints (held-out validation, never a reported figure):
    # between A and B, on scenes that are not in the low-light suite.
    "tune": dict(camera=dict(em_gain=500.0, full_well_serial=1.5e6, dark_current=0.02, cic=0.03,
                             read_noise=100.0, bias=3000.0, eperdn=12.5),
                 hot_fraction=1e-3, flat_e=[2.0, 5.0, 12.0, 30.0, 70.0, 150.0]),
}
HOT_RATE = 400.0  # e-/s
BIAS_EXPOSURES = [1e-4, 1e-3, 3e-3, 0.01, 0.03, 0.1, 0.3]
TEST_EXPOSURE = 0.01
MICROSCOPY = Path(__file__).resolve().parent.parent.parent / "shared/data/clean/microscopy/fmd-confocal-bpae"
DEFAULT_SCENES = [MICROSCOPY / f"field{k}-avg50.png" for k in (4, 5, 6)]


def detector(cam, fast=False):
    """emccd-detect for `cam`; `fast`: its Erlang gain register without partial CIC."""
    if fast:
        return EMCCDDetect(**cam, gain_CIC_Q=0, fast_gain_mode=True)
    return EMCCDDetect(**cam)


def scene_files(args):
    out = []
    for p in args:
        p = Path(p)
        out += sorted(q for q in p.iterdir() if q.suffix.lower() in (".png", ".tif", ".tiff")) if p.is_dir() else [p]
    return out


def scene_image(path, n=0):
    """A scene file as gray values in [0, 1], mirrored at its edges where it is smaller than `n` px."""
    img = np.asarray(Image.open(path).convert("L"), dtype=np.float64) / 255.0
    return np.pad(img, [(0, max(0, n - img.shape[0])), (0, max(0, n - img.shape[1]))], mode="symmetric")


def numbers(text):
    return [float(v) for v in text.split(",") if v]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out", type=Path)
    ap.add_argument("--camera", choices=sorted(CAMERAS), default="unseen")
    ap.add_argument("--size", type=int, default=256, help="frame side, px (centre crop of the scenes, mirrored at their edges where smaller)")
    ap.add_argument("--frames", type=int, default=16, help="frames per calibration stack")
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--scenes", nargs="+", default=[str(p) for p in DEFAULT_SCENES], help="scene files or directories")
    lv = ap.add_mutually_exclusive_group()
    lv.add_argument("--photons", type=numbers, help="photons at a scene's brightest pixel (default 20,200)")
    lv.add_argument("--mean-electrons", type=numbers, help="mean photoelectrons per pixel, e.g. 0.5,1,4,16")
    ap.add_argument("--fast", action="store_true", help="fast gain mode, no partial CIC in the register")
    a = ap.parse_args()
    np.random.seed(a.seed)  # emccd-detect draws from numpy's global generator
    n = a.size
    spec = CAMERAS[a.camera]
    cam = dict(COMMON, **spec["camera"])
    det = detector(cam, a.fast)
    rng = np.random.default_rng(a.seed)
    hot = rng.random((n, n)) < spec["hot_fraction"]
    g_dn = cam["em_gain"] / cam["eperdn"]  # DN per electron entering the register
    qe = cam["qe"]
    name = f"emccd-detect 2.6 ({a.camera})"

    def frames(photo_e, t, count):
        """`count` frames with `photo_e` expected photo-electrons per pixel and exposure t."""
        flux = photo_e / qe / t + hot * (HOT_RATE / qe)
        return np.stack([det.sim_sub_frame(flux, t) for _ in range(count)]).astype(np.uint16)

    def write(path, stack, **kw):
        path.parent.mkdir(parents=True, exist_ok=True)
        tifffile.imwrite(path, stack, imagej=True, **kw)

    out = a.out
    manifest = [f'# Calibration acquisition of camera "{a.camera}" (emccd-detect); paths relative to this file.',
                f'camera = "{name}"', f'em_gain = {cam["em_gain"]}', '']
    zero = np.zeros((n, n))
    for t in BIAS_EXPOSURES:
        f = f"bias/bias_{t:g}s.tif"
        write(out / f, frames(zero, t, a.frames))
        manifest += ["[[bias]]", f'file = "{f}"', f"exposure_s = {t}", ""]
        print(f"{a.camera}: bias {t:g} s", file=sys.stderr)
    for k, e in enumerate(spec["flat_e"]):
        f = f"flat/flat_{k + 1:02d}.tif"
        write(out / f, frames(np.full((n, n), e), TEST_EXPOSURE, a.frames))
        manifest += ["[[flat]]", f'file = "{f}"', f"exposure_s = {TEST_EXPOSURE}", ""]
        print(f"{a.camera}: flat {e} e-", file=sys.stderr)
    (out / "calibration.toml").write_text("\n".join(manifest))

    pairs = [f'# Test pairs from camera "{a.camera}" (emccd-detect); paths relative to this file.',
             f'camera = "{name}"',
             'profile = "../profile"',
             'note = "clean: expected photo-signal in DN above bias, photo-electrons * G / (e-/DN), float32"', '']
    for sc in scene_files(a.scenes):
        img = scene_image(sc, n)
        y0, x0 = (img.shape[0] - n) // 2, (img.shape[1] - n) // 2
        img = img[y0:y0 + n, x0:x0 + n]
        if a.mean_electrons:
            levels = [(f"m{m:g}", img * (m / max(img.mean(), 1e-3)), m, None) for m in a.mean_electrons]
        else:
            levels = [(f"p{p:g}", img * p * qe, None, p) for p in (a.photons or [20.0, 200.0])]
        for tag, e, mean_e, photons in levels:
            stem = f"{sc.stem}_{tag}"
            write(out / "pairs/noisy" / f"{stem}.tif", frames(e, TEST_EXPOSURE, 1))
            write(out / "pairs/clean" / f"{stem}.tif", (e * g_dn).astype(np.float32)[None])
            pairs += ["[[pair]]", f'scene = "{sc.name}"', f'noisy = "noisy/{stem}.tif"', f'clean = "clean/{stem}.tif"',
                      f"exposure_s = {TEST_EXPOSURE}", f"photons = {photons or e.max() / qe:.6g}"]
            pairs += [f"mean_electrons = {mean_e:g}"] if mean_e is not None else []
            pairs += [""]
            print(f"{a.camera}: pair {stem}", file=sys.stderr)
    (out / "pairs/pairs.toml").write_text("\n".join(pairs))
    truth = [f"{k} = {v!r}" for k, v in cam.items()]
    truth += [f"hot_fraction = {spec['hot_fraction']}", f"hot_rate_e_per_s = {HOT_RATE}",
              f"partial_cic = {'false' if a.fast else 'true'}",
              f"# expected photon-transfer slope 2 G / (e-/DN) = {2 * g_dn:.4f} DN (ideal register)",
              f"# read noise {cam['read_noise'] / cam['eperdn']:.2f} DN"]
    (out / "truth.toml").write_text("\n".join(truth) + "\n")


if __name__ == "__main__":
    main()
