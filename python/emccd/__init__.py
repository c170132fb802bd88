"""emccd: calibrate an EMCCD camera's noise and denoise its recordings, from Python.

The same libraries as the ``emccd`` command, on numpy arrays::

    import emccd
    frames, meta = emccd.read("cells.sif")           # [frames, h, w] float32, header dict
    clean = emccd.denoise(frames)     # the camera characterized from the frames themselves
    emccd.write("cells_denoised.tif", clean)

Errors are :class:`EmccdError` with the message the command line prints. Long calls release the
interpreter (other threads, a napari viewer, go on) and take ``progress=callable(done, total)``.
"""

from __future__ import annotations

import json
import os
from typing import Callable, Iterator, Optional, Tuple, Union

import numpy as np

from . import _emccd
from ._emccd import EmccdError, Profile

__all__ = [
    "EmccdError",
    "Frames",
    "Profile",
    "BUNDLED_MODELS",
    "METHODS",
    "DEFAULT_METHOD",
    "DEFAULT_MOVIE_METHOD",
    "DEFAULT_WINDOW",
    "MAX_WINDOW",
    "info",
    "read",
    "frames",
    "write",
    "load_profile",
    "calibrate",
    "denoise",
    "count",
    "simulate_pairs",
    "psnr",
    "ssim",
]

__version__ = _emccd.__version__
# A temporal method's frames each side when none is given, and the most it takes.
DEFAULT_WINDOW, MAX_WINDOW = _emccd.DEFAULT_WINDOW, _emccd.MAX_WINDOW

BUNDLED_MODELS, METHODS, DEFAULT_METHOD, DEFAULT_MOVIE_METHOD = _emccd.catalog()
BUNDLED_MODELS = tuple(BUNDLED_MODELS)
METHODS = tuple(METHODS)

PathLike = Union[str, "os.PathLike[str]"]
ProfileLike = Union[str, "os.PathLike[str]", Profile]
Progress = Optional[Callable[[int, int], object]]


def info(path: PathLike) -> dict:
    """What a stack holds, without decoding frames: the keys of ``emccd info --json`` (file,
    format, width, height, frames, pixel_type, exposure_s, em_gain, temperature_c,
    camera_model, binning, accumulations, warnings; None where the header does not say)."""
    return json.loads(_emccd.info(os.fspath(path)))


def read(path: PathLike) -> Tuple[np.ndarray, dict]:
    """Every frame of a TIFF/BigTIFF, Andor SIF, FITS, PNG or Zarr stack as float32
    ``[frames, height, width]``, and its metadata (the keys of :func:`info`). For stacks too
    large for memory, iterate :func:`frames` instead."""
    data, meta = _emccd.read(os.fspath(path))
    return data, json.loads(meta)


class Frames:
    """A stack read lazily, one float32 ``[height, width]`` frame per iteration step, in
    bounded memory; ``len()`` is the frame count and ``.info`` the metadata of :func:`info`."""

    def __init__(self, path: PathLike):
        self._inner = _emccd.Frames(os.fspath(path))
        self.info = json.loads(self._inner.info_json)

    def __len__(self) -> int:
        return len(self._inner)

    def __iter__(self) -> Iterator[np.ndarray]:
        return iter(self._inner)


def frames(path: PathLike) -> Frames:
    """A lazy frame iterator over a stack (see :class:`Frames`)."""
    return Frames(path)


_SAMPLES = {np.dtype(np.float32): "float32", np.dtype(np.uint16): "uint16", np.dtype(np.uint8): "uint8"}


def write(
    path: PathLike,
    frames: np.ndarray,
    *,
    dtype: Union[str, np.dtype, type] = np.float32,
    exposure_s: Optional[float] = None,
    em_gain: Optional[float] = None,
) -> None:
    """Writes a frame ``[h, w]`` or stack ``[frames, h, w]`` by the extension: ``.tif``/``.tiff``
    (BigTIFF by itself past 4 GiB), ``.btf`` (BigTIFF) or ``.fits``; samples stored as
    ``dtype`` (float32, uint16 or uint8: rounded and clipped). Written to a temporary file and
    renamed into place, so an existing file is replaced whole or not at all. Exposure and EM
    gain go into the header where given (emccd reads them back)."""
    a = _stack(frames, "frames")
    sample = _SAMPLES.get(np.dtype(dtype))
    if sample is None:
        raise EmccdError(f"dtype {np.dtype(dtype)}: emccd writes float32, uint16 or uint8 samples")
    _emccd.write(os.fspath(path), a, sample, exposure_s, em_gain)


def load_profile(profile: ProfileLike = "default") -> Profile:
    """A profile folder (written by ``emccd calibrate``), ``"default"`` for the bundled iXon
    897 profile, or a :class:`Profile` as it is."""
    if isinstance(profile, Profile):
        return profile
    return Profile.load(os.fspath(profile))


def calibrate(
    manifest: PathLike,
    out: PathLike,
    report: Optional[PathLike] = None,
    *,
    progress: Progress = None,
    force: bool = False,
) -> Profile:
    """Calibrates a camera from a calibration manifest (the TOML ``emccd calibrate`` takes),
    writes the profile folder ``out`` (and a self-contained HTML report into ``report``) and
    returns the profile. ``progress(frames_read, frames_total)`` is called as stacks are read.
    A profile already in ``out`` is replaced only with ``force=True``."""
    return _emccd.calibrate(
        os.fspath(manifest), os.fspath(out), None if report is None else os.fspath(report), progress, force
    )


def denoise(
    frames: np.ndarray,
    profile: Optional[ProfileLike] = None,
    model: Optional[str] = None,
    method: Optional[str] = None,
    exposure_s: Optional[float] = None,
    *,
    units: str = "dn",
    ensemble: int = 1,
    tile: int = 512,
    overlap: int = 32,
    extrapolate: bool = False,
    progress: Progress = None,
    window: Optional[int] = None,
    cic: Optional[float] = None,
    dark: Optional[float] = None,
    force: bool = False,
) -> np.ndarray:
    """Denoises raw EMCCD frames (DN as the camera wrote them; 2-D or 3-D, any integer or float
    dtype) as ``emccd denoise`` does: blooming and the fixed pattern are removed with the
    profile, then the method runs. ``profile``: a profile folder, ``"default"`` (the bundled
    iXon 897) or a :class:`Profile`; checked against the frames, which are refused where they
    disagree with it (another bias, gain or read noise) unless ``force=True``. Without one the
    camera is characterized from the frames themselves (their dark pixels' zero-electron peak
    and EM tail, a stack's mean–variance), and its numbers are issued as a warning; the
    clock-induced charge and dark current cannot be told from light there, so they stay in the
    output unless ``cic`` (e⁻ per pixel per frame) and ``dark`` (e⁻ per pixel per second), from
    the camera's data sheet, are given (no profile only). Returns float32 of the input's shape,
    in DN above bias (``units="dn"``) or photoelectrons (``"electrons"``).

    ``method``: ``blend`` (the default with no model on a single frame: iterative BM3D and the
    ``lowlight`` network averaged, the most accurate at low light; a 3-D stack of more than one
    frame runs ``temporal`` by default, unless ``window=0``), ``ivst`` (iterative BM3D), ``bm3d``, ``hybrid`` (BM3D refined by a network), ``net`` (a network alone, the
    fastest), ``temporal`` (each frame of a 3-D stack estimated from the ``window`` frames
    before and after it too), ``temporal-net`` (a network on each frame and the 2 before and
    after it: bundled model ``movie``) or ``none`` (preprocessing only). ``model``: a bundled
    model (``default``, ``microscopy``, ``lowlight``, ``hybrid``, ``movie``) or a model file; a model alone picks the method it was trained
    for. ``exposure_s`` is required with a calibrated profile (arrays carry no header;
    :func:`read` returns it in the metadata). ``progress(done, total)`` is called after each frame; an exception it raises
    stops the work and is raised here. The CLI's warnings are issued as ``UserWarning``.
    """
    import warnings

    a = np.asarray(frames)
    two_d = a.ndim == 2
    stack = _stack(a, "frames")
    out, notes = _emccd.denoise(
        stack,
        None if profile is None else load_profile(profile),
        None if exposure_s is None else float(exposure_s),
        model,
        method,
        units,
        int(tile),
        int(overlap),
        int(ensemble),
        bool(extrapolate),
        progress,
        None if window is None else int(window),
        None if cic is None else float(cic),
        None if dark is None else float(dark),
        bool(force),
    )
    for n in notes:
        warnings.warn(n, stacklevel=2)
    return out[0] if two_d else out


def count(
    frames: np.ndarray,
    profile: Optional[ProfileLike] = None,
    exposure_s: Optional[float] = None,
    *,
    threshold: str = "likelihood",
    per: Optional[int] = None,
    analog: bool = False,
    extrapolate: bool = False,
    cic: Optional[float] = None,
    dark: Optional[float] = None,
    read_noise: str = "auto",
    force: bool = False,
) -> Tuple[np.ndarray, np.ndarray]:
    """Photon counting of raw EMCCD frames (a 3-D stack in DN as the camera wrote them), as
    ``emccd count`` does: each frame preprocessed with the profile, each pixel thresholded, and
    the events turned into photo-electrons per pixel per frame, unbiased, with their standard
    error. Returns ``(rate, uncertainty)``: 2-D arrays for the whole stack, or 3-D with one frame
    per ``per`` input frames. ``threshold``: ``"likelihood"`` (no single threshold: each value
    binned and the rate the most likely under the camera's model), ``"auto"`` (k times each
    pixel's read noise, k chosen for the stack's light level), ``"<k>sigma"`` or ``"<n>DN"``. ``analog=True`` gives
    the plain mean instead, to compare. ``cic`` (e⁻ per frame) and ``dark`` (e⁻/s), both or
    neither, replace the profile's where its calibration did not measure them. ``read_noise``:
    ``"camera"`` (one read noise for every pixel, the calibration's fit beneath the spurious
    charge), ``"pixel"`` (each pixel's std map) or ``"auto"`` (``"pixel"`` where the profile's
    maps at two exposures agree pixel by pixel, else ``"camera"``). ``profile``, ``exposure_s``
    and ``force`` as for :func:`denoise`: without a profile the camera is characterized from the
    frames, and the rate then includes the spurious charge unless ``cic`` and ``dark`` are given.
    The threshold chosen and what it predicts (false events, missed photo-electrons) are kept
    in ``emccd.count.last_notes``."""
    stack = _stack(np.asarray(frames), "frames")
    rate, se, notes = _emccd.count(
        stack,
        None if profile is None else load_profile(profile),
        None if exposure_s is None else float(exposure_s),
        str(threshold),
        None if per is None else int(per),
        bool(analog),
        bool(extrapolate),
        None if cic is None else float(cic),
        None if dark is None else float(dark),
        str(read_noise),
        bool(force),
    )
    count.last_notes = list(notes)
    if per is None:
        return rate[0], se[0]
    return rate, se


def simulate_pairs(
    clean: np.ndarray,
    *,
    profile: ProfileLike = "default",
    photons: Optional[float] = None,
    mean_electrons: Optional[float] = None,
    exposure_s: float = 0.01,
    frames: int = 1,
    seed: int = 0,
) -> Tuple[np.ndarray, np.ndarray]:
    """Noisy/clean training or test pairs from the virtual camera (the full EMCCD chain:
    Poisson photons, dark current and clock-induced charge, the EM register's Gamma gain, the
    profile's fixed pattern, blooming, read noise and the ADC).

    ``clean``: a 2-D scene (any dtype; normalized by its maximum), at most the profile's size
    (a smaller scene uses the sensor's top-left sub-array). Its brightest pixel collects
    ``photons`` photons per exposure, or give ``mean_electrons`` (the mean photoelectrons per
    pixel, 0.5–16 is where EMCCDs are used); ``photons=0`` gives dark frames (bias, dark
    current and clock-induced charge), as a calibration acquisition records. Returns ``(raw, truth)``: raw frames
    ``[frames, h, w]`` in DN as the camera records them (denoise them with the same profile,
    cropped to the scene: ``profile.crop(0, 0, w, h)``) and the ground truth ``[h, w]``, the
    photo-signal in DN above bias.
    """
    img = np.asarray(clean, dtype=np.float64)
    if img.ndim != 2:
        raise EmccdError(f"clean: a 2-D scene, not an array of shape {img.shape}")
    if photons == 0 or mean_electrons == 0:
        img = np.zeros_like(img)  # dark frames: only the shape of the scene matters
    else:
        peak = float(np.nanmax(img)) if img.size else 0.0
        if not np.isfinite(peak) or peak <= 0:
            raise EmccdError("clean: the scene has no positive, finite brightest value")
        img = img / peak
    return _emccd.simulate_pairs(
        np.ascontiguousarray(img, dtype=np.float32),
        load_profile(profile),
        None if photons is None else float(photons),
        None if mean_electrons is None else float(mean_electrons),
        float(exposure_s),
        int(frames),
        int(seed),
    )


def psnr(test: np.ndarray, reference: np.ndarray, data_range: Optional[float] = None) -> float:
    """PSNR in dB of ``test`` against ``reference`` (2-D); ``data_range`` defaults to the
    reference's maximum (the convention of the emccd tables for signals above bias)."""
    t, r = _pair(test, reference)
    return _emccd.psnr(t, r, _range(r, data_range))


def ssim(test: np.ndarray, reference: np.ndarray, data_range: Optional[float] = None) -> float:
    """SSIM of ``test`` against ``reference`` (2-D), Gaussian window σ = 1.5 (as scikit-image
    with ``gaussian_weights=True``); ``data_range`` defaults to the reference's maximum."""
    t, r = _pair(test, reference)
    return _emccd.ssim(t, r, _range(r, data_range))


def _stack(a: np.ndarray, name: str) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim == 2:
        a = a[np.newaxis]
    if a.ndim != 3:
        raise EmccdError(f"{name}: a frame [h, w] or a stack [frames, h, w], not an array of shape {a.shape}")
    if a.dtype.kind not in "uifb":
        raise EmccdError(f"{name}: numbers, not {a.dtype}")
    if 0 in a.shape:
        raise EmccdError(f"{name}: an empty array of shape {a.shape}")
    return np.ascontiguousarray(a, dtype=np.float32)


def _pair(test: np.ndarray, reference: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    t = np.ascontiguousarray(test, dtype=np.float32)
    r = np.ascontiguousarray(reference, dtype=np.float32)
    if t.ndim != 2 or r.ndim != 2:
        raise EmccdError(f"2-D images, not arrays of shapes {t.shape} and {r.shape}")
    return t, r


def _range(reference: np.ndarray, data_range: Optional[float]) -> float:
    if data_range is None:
        data_range = float(np.max(reference))
    if not (np.isfinite(data_range) and data_range > 0):
        raise EmccdError(f"data_range {data_range}: a positive number (the reference's maximum is not)")
    return float(data_range)
