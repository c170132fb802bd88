#!/usr/bin/env python3
"""Is a denoiser's error bias or variance? For denoised frames beside their ground truth, per
light level: PSNR, the mean error (% of the truth's peak), the mean error on the darker and the
brighter half of the pixels (shrinkage toward the mean shows as + / -), and the PSNR an oracle
per-frame contrast correction m + k(d - m) would reach (k fitted against the truth, 0.9-1.3).
An oracle gain near zero means no global correction or loss re-weighting can remove the error.

Usage: python3 tools/calibration_check.py DENOISED_DIR PAIRS_DIR
  DENOISED_DIR  float32 TIFFs named like the pairs' noisy frames (emccd denoise outputs)
  PAIRS_DIR     a pairs folder with clean/ and pairs.toml (mean_electrons per pair)
Needs numpy and tifffile.
"""
import collections
import os
import sys
import tomllib

import numpy as np
import tifffile


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    den_dir, pairs = sys.argv[1], sys.argv[2]
    with open(os.path.join(pairs, "pairs.toml"), "rb") as f:
        manifest = tomllib.load(f)
    rows = collections.defaultdict(list)
    for p in manifest["pair"]:
        name = os.path.basename(p["noisy"])
        path = os.path.join(den_dir, name)
        if not os.path.exists(path):
            continue
        d = tifffile.imread(path).astype(np.float64)
        c = tifffile.imread(os.path.join(pairs, p["clean"])).astype(np.float64)
        peak = c.max()
        e = d - c
        psnr = 10 * np.log10(peak**2 / (e**2).mean())
        dark = c < np.median(c)
        m = d.mean()
        oracle = max(
            10 * np.log10(peak**2 / ((m + k * (d - m) - c) ** 2).mean())
            for k in np.linspace(0.9, 1.3, 41)
        )
        level = p.get("mean_electrons", p["photons"])
        rows[level].append(
            (psnr, 100 * e.mean() / peak, 100 * e[dark].mean() / peak,
             100 * e[~dark].mean() / peak, oracle)
        )
    print("| level | pairs | PSNR (dB) | mean error (% peak) | darker half | brighter half | oracle contrast (dB) |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for level in sorted(rows):
        a = np.array(rows[level]).mean(0)
        print(f"| {level} | {len(rows[level])} | {a[0]:.2f} | {a[1]:+.3f} | {a[2]:+.2f} | {a[3]:+.2f} | {a[4]:.2f} |")


if __name__ == "__main__":
    main()
