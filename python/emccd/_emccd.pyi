"""Type stubs of the native module (Rust, PyO3). Use the wrappers in :mod:`emccd`: they take
path-likes, any array dtype, and turn metadata JSON into dicts."""

from typing import Callable, Iterator, List, Optional, Tuple

import numpy as np
import numpy.typing as npt

__version__: str
DEFAULT_WINDOW: int
MAX_WINDOW: int

class EmccdError(Exception):
    """Every error of the emccd libraries, with the message the command line prints."""

class Frames:
    """A stack opened for lazy reading: iterate for float32 ``[h, w]`` frames."""

    def __init__(self, path: str) -> None: ...
    @property
    def info_json(self) -> str: ...
    def __len__(self) -> int: ...
    def __iter__(self) -> Iterator[npt.NDArray[np.float32]]: ...
    def __next__(self) -> npt.NDArray[np.float32]: ...

class Profile:
    """A camera profile: the calibrated parameters and per-pixel maps."""

    @staticmethod
    def load(path: str) -> Profile:
        """Loads a profile folder, or ``"default"`` for the bundled iXon 897 profile."""
    def save(self, path: str) -> None:
        """Writes the profile folder (profile.toml + maps.safetensors), atomically."""
    def crop(self, x: int, y: int, width: int, height: int) -> Profile:
        """The same profile for a sub-array readout."""
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    @property
    def camera(self) -> str: ...
    @property
    def em_gain(self) -> float: ...
    @property
    def slope(self) -> Optional[float]:
        """Photon-transfer slope s = K·f², DN (None if not calibrated)."""
    @property
    def bias_dn(self) -> Optional[float]: ...
    @property
    def read_noise_dn(self) -> Optional[float]: ...
    @property
    def quantization_dn(self) -> float: ...
    @property
    def exposures_s(self) -> List[float]: ...
    @property
    def fingerprint(self) -> str:
        """Content fingerprint (hex) that model files record as the profile they were trained for."""
    def summary_json(self) -> str:
        """Everything ``emccd profile show --json`` prints (JSON text)."""

Progress = Optional[Callable[[int, int], object]]

def info(path: str) -> str: ...
def read(path: str) -> Tuple[npt.NDArray[np.float32], str]: ...
def write(
    path: str,
    frames: npt.NDArray[np.float32],
    sample: str,
    exposure_s: Optional[float] = None,
    em_gain: Optional[float] = None,
) -> None: ...
def calibrate(
    manifest: str, out: str, report: Optional[str] = None, progress: Progress = None
) -> Profile: ...
def denoise(
    frames: npt.NDArray[np.float32],
    profile: Profile,
    exposure_s: float,
    model: Optional[str] = None,
    method: Optional[str] = None,
    units: str = "dn",
    tile: int = 512,
    overlap: int = 32,
    ensemble: int = 1,
    extrapolate: bool = False,
    progress: Progress = None,
) -> Tuple[npt.NDArray[np.float32], List[str]]: ...
def simulate_pairs(
    clean: npt.NDArray[np.float32],
    profile: Profile,
    photons: Optional[float],
    mean_electrons: Optional[float],
    exposure_s: float,
    frames: int = 1,
    seed: int = 0,
) -> Tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]: ...
def psnr(
    test: npt.NDArray[np.float32], reference: npt.NDArray[np.float32], data_range: float
) -> float: ...
def ssim(
    test: npt.NDArray[np.float32], reference: npt.NDArray[np.float32], data_range: float
) -> float: ...
def catalog() -> Tuple[List[str], List[str], str, str]: ...
