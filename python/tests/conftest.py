"""Shared fixtures: the test data folder (the repository's tests/data) and scenes."""

import os
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(os.environ.get("EMCCD_DATA", ROOT / "tests" / "data"))


@pytest.fixture(scope="session")
def data() -> Path:
    if not DATA.is_dir():
        pytest.fail(f"{DATA}: the test data folder is missing (set EMCCD_DATA)")
    return DATA


@pytest.fixture(scope="session")
def scene(data) -> np.ndarray:
    """A 96×128 crop of a McMaster image (never trained on), as 0–1 luminance."""
    import emccd

    files = sorted((data / "clean" / "natural" / "McMaster").glob("*"))
    img, _ = emccd.read(files[0])
    img = img[0]
    return img[:96, :128] / img.max()


@pytest.fixture(scope="session")
def profile():
    """The bundled default profile (the virtual camera's truth)."""
    import emccd

    return emccd.load_profile("default")
