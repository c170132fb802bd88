"""emccd from Python, start to finish: calibrate a camera, denoise a low-light frame, look at it.

The camera is the virtual one (the bundled iXon 897 profile driving the full EMCCD chain), so
the truth is known and the calibration can be checked against it. With a real camera, replace
the simulated stacks by your own recordings and keep the rest.

    pip install ./python matplotlib
    python examples/python/quickstart.py          # writes quickstart.png here

Run as a script or cell by cell (``# %%``) in Jupyter or VS Code.
"""

# %% A calibration acquisition, as you would record it: dark frames at four exposures (shutter
# closed) and flat fields at eight light levels, 20 frames each, on a 256×256 sub-array.
import tempfile
from pathlib import Path

import numpy as np

import emccd

truth_profile = emccd.load_profile("default").crop(128, 128, 256, 256)
size = (truth_profile.height, truth_profile.width)
acq = Path(tempfile.mkdtemp(prefix="emccd-quickstart-"))
manifest = ['camera = "virtual iXon 897"', f"em_gain = {truth_profile.em_gain}"]
for i, t in enumerate([0.01, 0.03, 0.1, 0.3]):
    dark, _ = emccd.simulate_pairs(np.zeros(size), profile=truth_profile, photons=0,
                                   exposure_s=t, frames=20, seed=100 + i)
    emccd.write(acq / f"bias_{i}.tif", dark, dtype=np.uint16, exposure_s=t)
    manifest += ["[[bias]]", f'file = "bias_{i}.tif"', f"exposure_s = {t}"]
for i, electrons in enumerate([0.5, 1, 2, 5, 10, 20, 50, 100]):
    flat, _ = emccd.simulate_pairs(np.ones(size), profile=truth_profile, mean_electrons=electrons,
                                   exposure_s=0.01, frames=20, seed=200 + i)
    emccd.write(acq / f"flat_{i}.tif", flat, dtype=np.uint16, exposure_s=0.01)
    manifest += ["[[flat]]", f'file = "flat_{i}.tif"', "exposure_s = 0.01"]
(acq / "calibration.toml").write_text("\n".join(manifest) + "\n")

# %% Calibrate: the profile folder and an HTML report (open acq/report/index.html).
profile = emccd.calibrate(acq / "calibration.toml", acq / "profile", acq / "report",
                          progress=lambda done, total: print(f"\rcalibrating: {done}/{total} frames", end=""))
print(f"\nslope {profile.slope:.1f} DN (truth {truth_profile.slope:.1f}), "
      f"read noise {profile.read_noise_dn:.2f} DN (truth {truth_profile.read_noise_dn:.2f})")

# %% A scene at 2 photoelectrons per pixel on average (cells: bright rims, faint interiors).
rng = np.random.default_rng(7)
y, x = np.mgrid[0:size[0], 0:size[1]].astype(float)
scene = np.full(size, 0.05)
for cy, cx, r in zip(rng.uniform(20, 236, 14), rng.uniform(20, 236, 14), rng.uniform(10, 26, 14)):
    d = np.hypot(y - cy, x - cx)
    scene += 0.35 * np.exp(-((d - r) / 2.5) ** 2) + 0.15 * (d < r) + 0.6 * np.exp(-(d / 3) ** 2)
raw, truth = emccd.simulate_pairs(scene, profile=truth_profile, mean_electrons=2.0,
                                  exposure_s=0.03, seed=1)

# %% Denoise with the calibrated profile (the default method), and score against the truth.
denoised = emccd.denoise(raw[0], profile=profile, exposure_s=0.03)
noisy = raw[0] - profile.bias_dn  # what the camera shows, above bias
scores = {name: emccd.psnr(img, truth) for name, img in [("noisy", noisy), ("denoised", denoised)]}
print(", ".join(f"{k} {v:.1f} dB" for k, v in scores.items()))

# %% Noisy | denoised | truth, on one grey scale.
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

lo, hi = np.percentile(truth, [0.5, 99.8])
fig, axes = plt.subplots(1, 3, figsize=(12, 4.3), constrained_layout=True)
for ax, img, title in zip(axes, [noisy, denoised, truth], [
        f"noisy ({scores['noisy']:.1f} dB)",
        f"emccd.denoise, {emccd.DEFAULT_METHOD} ({scores['denoised']:.1f} dB)",
        "truth"]):
    ax.imshow(img, cmap="gray", vmin=lo, vmax=hi)
    ax.set_title(title)
    ax.axis("off")
fig.suptitle("virtual iXon 897, 2 photoelectrons per pixel on average, EM gain "
             f"{profile.em_gain:g}")
out = Path("quickstart.png").resolve()
fig.savefig(out, dpi=100)
print(f"wrote {out}")
