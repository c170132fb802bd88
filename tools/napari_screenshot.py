"""The README's napari screenshot: a real Andor SIF frame opened with the emccd reader, denoised
with the "Denoise EMCCD" dock widget (bundled default profile, default method), raw and
denoised side by side.

    xvfb-run -a -s "-screen 0 1600x1000x24" python3 tools/napari_screenshot.py [SIF] [-o docs/napari-denoise-sif.png]
"""

import argparse
import time
from pathlib import Path

import napari
import numpy as np
from qtpy.QtWidgets import QApplication

ROOT = Path(__file__).resolve().parents[1]
ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
ap.add_argument("sif", nargs="?", default=ROOT.parent / "shared/data/emccd-real/andor-sif/ixon897_avg20.sif")
ap.add_argument("-o", "--out", default=ROOT / "docs/napari-denoise-sif.png")
args = ap.parse_args()

viewer = napari.Viewer(title="emccd in napari")
viewer.window.resize(1500, 820)
(raw,) = viewer.open(str(args.sif), plugin="emccd")
_, widget = viewer.window.add_plugin_dock_widget("emccd", "Denoise EMCCD")
widget.extrapolate.value = True  # the frame's 1 s exposure lies past the bundled profile's calibration
t0 = time.time()
widget.run_button.clicked()
while len(viewer.layers) < 2:
    QApplication.processEvents()
    if widget.status.value.startswith("error"):
        raise SystemExit(widget.status.value)
    time.sleep(0.05)
print(f"denoised in {time.time() - t0:.1f} s: {widget.status.value}")
# the same percentile window on each (raw is in DN with bias, denoised in DN above bias)
for layer in (raw, viewer.layers[-1]):
    layer.contrast_limits = tuple(float(v) for v in np.percentile(layer.data, [1, 99.7]))
viewer.grid.enabled = True
# napari's start-up toasts (a PyQt5 deprecation note) would cover the canvas
from napari._qt.dialogs.qt_notification import NapariQtNotification

for toast in viewer.window._qt_window.findChildren(NapariQtNotification):
    toast.close()
viewer.reset_view()
for _ in range(20):
    QApplication.processEvents()
    time.sleep(0.05)
viewer.screenshot(str(args.out), canvas_only=False, flash=False)
print(f"wrote {args.out}")
viewer.close()
