"""The README's Python example runs as written and says what it should."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "python" / "quickstart.py"


def test_quickstart_calibrates_and_denoises(tmp_path):
    pytest.importorskip("matplotlib")
    run = subprocess.run([sys.executable, str(EXAMPLE)], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    slope, truth = map(float, re.search(r"slope ([\d.]+) DN \(truth ([\d.]+)\)", run.stdout).groups())
    # 8 flat levels × 256² px × 20 frames: the slope's standard error is a fraction of a percent
    assert slope == pytest.approx(truth, rel=0.03)
    noisy, denoised = map(float, re.search(r"noisy ([\d.]+) dB, denoised ([\d.]+) dB", run.stdout).groups())
    assert denoised > noisy + 8
    assert (tmp_path / "quickstart.png").stat().st_size > 10_000
