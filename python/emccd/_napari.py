"""The napari plugin: readers for Andor SIF and EMCCD FITS recordings, and the "Denoise EMCCD"
dock widget (declared in napari.yaml; napari imports this module only when it needs them)."""

from __future__ import annotations

import os
from typing import Any, Callable, List, Optional, Tuple

import numpy as np

import emccd

LayerData = Tuple[Any, dict, str]


def get_reader(path: Any) -> Optional[Callable[[Any], List[LayerData]]]:
    """The reader for a SIF or FITS file emccd can open, else None (napari tries others)."""
    if isinstance(path, (list, tuple)):
        if len(path) != 1:
            return None
        path = path[0]
    path = os.fspath(path)
    if not path.lower().endswith((".sif", ".fits", ".fit", ".fts")):
        return None
    try:
        emccd.info(path)
    except emccd.EmccdError:
        return None
    return read_layers


def read_layers(path: Any) -> List[LayerData]:
    """One image layer: the stack as float32 [frames, h, w] (one frame as [h, w]) with the
    header (exposure, EM gain, camera, temperature, binning) in the layer's metadata."""
    if isinstance(path, (list, tuple)):
        path = path[0]
    path = os.fspath(path)
    data, meta = emccd.read(path)
    if data.shape[0] == 1:
        data = data[0]
    name = os.path.splitext(os.path.basename(path))[0]
    return [(data, {"name": name, "metadata": {"emccd": meta, "source": path}}, "image")]


def _make_widget_class():
    from magicgui.widgets import (
        CheckBox,
        ComboBox,
        Container,
        FloatSpinBox,
        Label,
        LineEdit,
        ProgressBar,
        PushButton,
        SpinBox,
        create_widget,
    )
    from napari.layers import Image
    from napari.qt.threading import thread_worker
    from qtpy.QtCore import QObject, Signal

    class _Relay(QObject):
        # Emitted from the worker thread; Qt queues it to the widget's thread.
        advanced = Signal(int, int)

    class DenoiseWidget(Container):
        """Denoise the selected EMCCD recording with a camera profile (a calibrated profile
        folder, the bundled default, or none: the camera characterized from the recording), the method and model of ``emccd denoise``, and the
        exposure from the file's header; runs in a worker thread and adds a new layer."""

        def __init__(self, napari_viewer):
            self.viewer = napari_viewer
            self.image = create_widget(annotation=Image, label="recording")
            self.profile = LineEdit(value="", label="profile",
                                    tooltip="A profile folder from `emccd calibrate`, `default` (bundled iXon 897), "
                                            "or empty: the camera characterized from the recording itself")
            default = f"(default: {emccd.DEFAULT_METHOD}; {emccd.DEFAULT_MOVIE_METHOD} on a time series)"
            self.method = ComboBox(choices=[default] + list(emccd.METHODS), label="method")
            self.model = ComboBox(choices=["(method's own)"] + list(emccd.BUNDLED_MODELS), label="model")
            self.exposure = FloatSpinBox(value=0.01, min=1e-6, max=1e4, step=0.001, label="exposure (s)")
            self.units = ComboBox(choices=["dn", "electrons"], label="units")
            self.window = SpinBox(value=emccd.DEFAULT_WINDOW, min=0, max=emccd.MAX_WINDOW, label="window",
                                  tooltip="Temporal methods on a time series: the frames before and after "
                                          "each frame it also uses (0: each frame alone)")
            self.extrapolate = CheckBox(value=False, text="outside the calibrated exposures")
            self.run_button = PushButton(text="Denoise")
            self.cancel_button = PushButton(text="Cancel", enabled=False)
            self.bar = ProgressBar(value=0, min=0, max=1, label="frames")
            self.status = Label(value="")
            super().__init__(widgets=[
                self.image, self.profile, self.method, self.model, self.exposure, self.units,
                self.window, self.extrapolate, self.run_button, self.cancel_button, self.bar, self.status,
            ])
            self.status.native.setWordWrap(True)  # long messages wrap instead of widening the dock
            self._relay = _Relay()
            self._relay.advanced.connect(self._advanced)
            self._cancel = False
            self.worker = None
            self.image.changed.connect(self._layer_changed)
            self.run_button.clicked.connect(self.run)
            self.cancel_button.clicked.connect(self._request_cancel)
            self._layer_changed(self.image.value)

        def _layer_changed(self, layer):
            meta = getattr(layer, "metadata", {}).get("emccd", {}) if layer is not None else {}
            t = meta.get("exposure_s")
            if t and t > 0:
                self.exposure.value = t
                self.status.value = f"exposure {t} s from the header"

        def _advanced(self, done, total):
            self.bar.max = total
            self.bar.value = done

        def _request_cancel(self):
            self._cancel = True

        def request(self) -> dict:
            """The emccd.denoise arguments the widget's fields say."""
            method = self.method.value
            model = self.model.value
            method = None if method.startswith("(") else method
            req = {
                "profile": self.profile.value.strip() or None,
                "method": method,
                "model": None if model.startswith("(") else model,
                "exposure_s": float(self.exposure.value),
                "units": self.units.value,
                "extrapolate": bool(self.extrapolate.value),
            }
            # The window is the classical temporal method's (the default's too: it runs it on a
            # time series, unless a model picks its own method); the temporal network's is its own.
            if method == "temporal" or (method is None and req["model"] is None):
                req["window"] = int(self.window.value)
            return req

        def run(self):
            layer = self.image.value
            if layer is None:
                self.status.value = "open a recording first"
                return
            req = self.request()
            data = np.asarray(layer.data)
            relay = self._relay
            self._cancel = False

            def progress(done, total):
                if self._cancel:
                    raise InterruptedError("cancelled")
                relay.advanced.emit(done, total)

            # errors are shown in the widget (failed), not raised into Qt's event loop
            @thread_worker(ignore_errors=True)
            def work():
                import warnings

                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    out = emccd.denoise(data, progress=progress, **req)
                return out, [str(w.message) for w in caught]

            def done(result):
                out, notes = result
                meta = {"emccd_denoise": dict(req, source=layer.name), "warnings": notes}
                self.viewer.add_image(out, name=f"{layer.name} denoised", metadata=meta,
                                      colormap=getattr(layer.colormap, "name", "gray"))
                self.status.value = "done" + "".join(f"\nwarning: {n}" for n in notes)

            def failed(e):
                if self._cancel:
                    self.status.value = "cancelled"
                else:
                    self.status.value = "error: " + " — ".join(l.strip() for l in str(e).splitlines())

            def finished():
                self.run_button.enabled = True
                self.cancel_button.enabled = False
                self.worker = None

            self.run_button.enabled = False
            self.cancel_button.enabled = True
            self.status.value = f"denoising {layer.name}…"
            self.bar.value = 0
            worker = work()
            worker.returned.connect(done)
            worker.errored.connect(failed)
            worker.finished.connect(finished)
            self.worker = worker
            worker.start()

    return DenoiseWidget


def __getattr__(name):
    # Qt and napari are imported only when napari asks for the widget.
    if name == "DenoiseWidget":
        cls = _make_widget_class()
        globals()["DenoiseWidget"] = cls
        return cls
    raise AttributeError(name)
