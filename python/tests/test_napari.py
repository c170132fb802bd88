"""The napari plugin, headless: the SIF reader and the Denoise EMCCD widget on a real frame."""

import os

import numpy as np
import pytest

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
napari = pytest.importorskip("napari") if not os.environ.get("EMCCD_REQUIRE_NAPARI") else __import__("napari")

import emccd  # noqa: E402

SIF = ("emccd-real", "andor-sif", "ixon897_avg20.sif")


def test_manifest_is_valid():
    from npe2 import PluginManager

    pm = PluginManager.instance()
    pm.discover()
    m = pm.get_manifest("emccd")
    assert {c.id for c in m.contributions.commands} == {"emccd.get_reader", "emccd.denoise_widget"}


def test_reader_puts_the_header_in_the_layer(data, make_napari_viewer):
    from emccd._napari import get_reader

    path = data.joinpath(*SIF)
    assert get_reader(str(data / "emccd-real" / "andor-sif" / "LICENSE")) is None
    viewer = make_napari_viewer()
    layers = viewer.open(str(path), plugin="emccd")
    (layer,) = layers
    assert layer.data.shape == (512, 512)
    meta = layer.metadata["emccd"]
    assert meta["camera_model"] == "DU897_BV" and meta["exposure_s"] == 1.0 and meta["em_gain"] == 1000.0


def test_denoise_widget_adds_a_denoised_layer(data, make_napari_viewer, qtbot):
    viewer = make_napari_viewer()
    (layer,) = viewer.open(str(data.joinpath(*SIF)), plugin="emccd")
    _, widget = viewer.window.add_plugin_dock_widget("emccd", "Denoise EMCCD")
    assert widget.exposure.value == pytest.approx(1.0)  # from the SIF header
    # By default the camera is characterized from the recording: this real iXon 897 runs at EM
    # gain 1000 with a bias of 861 DN, not the bundled model's.
    assert widget.request()["profile"] is None
    widget.method.value = "bm3d"
    widget.run_button.clicked()
    qtbot.waitUntil(lambda: len(viewer.layers) == 2, timeout=300_000)
    out = viewer.layers[-1]
    assert out.name == f"{layer.name} denoised"
    assert out.data.shape == (512, 512) and np.isfinite(out.data).all()
    assert widget.bar.value == widget.bar.max == 1
    with pytest.warns(UserWarning, match="camera characterized from the frames"):
        expected = emccd.denoise(layer.data, method="bm3d", exposure_s=1.0)
    assert "camera characterized from the frames" in widget.status.value  # the widget says so
    np.testing.assert_array_equal(out.data, expected)
    # The bundled profile does not fit this camera: refused in the widget, nothing added.
    widget.profile.value = "default"
    widget.run_button.clicked()
    qtbot.waitUntil(lambda: widget.status.value.startswith("error"), timeout=60_000)
    assert "does not fit profile" in widget.status.value and len(viewer.layers) == 2
    # a bad request reports in the widget and adds nothing
    widget.profile.value = str(data)
    widget.run_button.clicked()
    qtbot.waitUntil(lambda: widget.status.value.startswith("error"), timeout=60_000)
    assert "loading profile" in widget.status.value and len(viewer.layers) == 2


def test_cancel_stops_the_worker_and_adds_nothing(profile, scene, tmp_path, make_napari_viewer, qtbot):
    raw, _ = emccd.simulate_pairs(scene, profile=profile, mean_electrons=4.0, exposure_s=0.01, frames=3, seed=3)
    h, w = scene.shape
    profile.crop(0, 0, w, h).save(tmp_path / "profile")  # the sub-array the scene was recorded on
    viewer = make_napari_viewer()
    viewer.add_image(raw, name="stack", metadata={"emccd": {"exposure_s": 0.01}})
    _, widget = viewer.window.add_plugin_dock_widget("emccd", "Denoise EMCCD")
    widget.profile.value = str(tmp_path / "profile")
    widget.method.value = "bm3d"
    widget.run_button.clicked()
    widget.cancel_button.clicked()  # before the first frame is done: the worker stops there
    qtbot.waitUntil(lambda: widget.worker is None, timeout=120_000)
    assert widget.status.value == "cancelled" and len(viewer.layers) == 1
    assert widget.run_button.enabled and not widget.cancel_button.enabled


def test_a_time_series_is_denoised_with_its_neighbours(profile, scene, tmp_path, make_napari_viewer, qtbot):
    raw, _ = emccd.simulate_pairs(scene, profile=profile, mean_electrons=2.0, exposure_s=0.01, frames=3, seed=5)
    h, w = scene.shape
    profile.crop(0, 0, w, h).save(tmp_path / "profile")
    viewer = make_napari_viewer()
    viewer.add_image(raw, name="movie", metadata={"emccd": {"exposure_s": 0.01}})
    _, widget = viewer.window.add_plugin_dock_widget("emccd", "Denoise EMCCD")
    widget.profile.value = str(tmp_path / "profile")
    assert widget.window.value == emccd.DEFAULT_WINDOW  # the CLI's default
    widget.method.value = "temporal"
    widget.window.value = 1
    assert widget.request()["window"] == 1
    widget.run_button.clicked()
    qtbot.waitUntil(lambda: len(viewer.layers) == 2, timeout=300_000)
    expected = emccd.denoise(raw, profile=str(tmp_path / "profile"), method="temporal", window=1, exposure_s=0.01)
    np.testing.assert_array_equal(viewer.layers[-1].data, expected)
    # A method that denoises frames alone is not given the window.
    widget.method.value = "bm3d"
    assert "window" not in widget.request()
