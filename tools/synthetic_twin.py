#!/usr/bin/env python3
"""A synthetic twin of an emccd-detect pair set: the same scenes and photoelectrons per pixel,
with the noise drawn by emccd's own Poisson-Gamma-Normal model (`emccd synthesize --model pgn`)
through the bundled default profile. A method's gain over BM3D on the twin against its gain on
the original separates "our synthesized noise differs from the camera's" from "training and
inference differ" (the same frames, the same light, only the noise generator changes).

The twin's profile is the bundled default with a flat fixed pattern (100 DN at every exposure)
and no blooming, so that the synthesized frame plus 100 DN is exactly what the camera would
record and preprocessing returns the synthesized photo-signal.

Usage: python3 tools/synthetic_twin.py PAIRS_DIR OUT  [--seed 100]
  PAIRS_DIR  pairs written by tools/unseen_camera.py (pairs.toml with mean_electrons; its
             truth.toml beside the pairs folder gives the camera's DN per electron)
  OUT        writes OUT/prof (profile) and OUT/pairs (pairs.toml, noisy/, clean/)
Then: emccd evaluate OUT/pairs --method bm3d --method ivst --method hybrid
Needs: numpy, tifffile; the release binary (target/release/emccd, or $EMCCD).
"""

import argparse
import json
import os
import re
import shutil
import subprocess
import struct
import subprocess
from pathlib import Path

import numpy as np
import tifffile

ROOT = Path(__file__).resolve().parent.parent
EMCCD = os.environ.get("EMCCD", str(ROOT / "target/release/emccd"))
FLAT_DN = 100.0


def flat_profile(out: Path):
    """The bundled default profile with FPN = FLAT_DN everywhere and no blooming."""
    if out.exists():
        shutil.rmtree(out)
    subprocess.run([str(ROOT / "target/release/emccd"), "profile", "init-default", str(out)], check=True,
                   capture_output=True)
    t = (out / "profile.toml").read_text()
    t = re.sub(r'\nmaps_fnv1a64 = "[0-9a-f]+"', "", t)  # the maps change below
    t = re.sub(r"\n\[blooming\]\n(?:[^\[\n][^\n]*\n|\[\n(?:    [^\n]*\n)*\]\n)*", "\n", t)
    t = re.sub(r"shared_theta = \[[^\]]*\]", "shared_theta = [0.0, 0.0, 1.0, 0.0]", t)
    (out / "profile.toml").write_text(t)
    raw = (out / "maps.safetensors").read_bytes()
    n = struct.unpack("<Q", raw[:8])[0]
    header = json.loads(raw[8:8 + n])
    data = bytearray(raw[8 + n:])

    def put(name, fn):
        s, e = header[name]["data_offsets"]
        a = np.frombuffer(bytes(data[s:e]), dtype="<f4").reshape(header[name]["shape"]).copy()
        data[s:e] = fn(a).astype("<f4").tobytes()

    put("fpn_base", lambda a: np.full_like(a, FLAT_DN))

    def theta(a):  # ln FPN = θ0 + θ1·logistic: θ1 = 0 makes it constant
        a[0], a[1], a[2], a[3] = np.log(FLAT_DN), 0.0, 1.0, 0.0
        return a

    put("fpn_theta", theta)
    (out / "maps.safetensors").write_bytes(raw[:8 + n] + bytes(data))
    r = subprocess.run([EMCCD, "profile", "show", str(out), "--json"], capture_output=True, text=True)
    if r.returncode:
        raise SystemExit(f"the twin profile does not load: {r.stderr}")
    return json.loads(r.stdout)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("pairs", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--seed", type=int, default=100)
    a = ap.parse_args()
    truth = (a.pairs.parent / "truth.toml").read_text()
    g = float(re.search(r"^em_gain = ([0-9.e+-]+)", truth, re.M).group(1))
    eperdn = float(re.search(r"^eperdn = ([0-9.e+-]+)", truth, re.M).group(1))
    dn_per_e_src = g / eperdn
    prof = flat_profile(a.out / "prof")
    dn_per_e = prof["ptc_slope_dn"] / 2.0  # K = s/2 for the PGN register (f² = 2)
    text = (a.pairs / "pairs.toml").read_text()
    _, *blocks = text.split("[[pair]]")
    dst = a.out / "pairs"
    for sub in ("noisy", "clean", "tmp"):
        (dst / sub).mkdir(parents=True, exist_ok=True)
    entries = [f'camera = "synthetic twin (pgn, {a.pairs})"', 'profile = "../prof"', ""]
    for k, b in enumerate(blocks):
        clean = re.search(r'clean = "([^"]+)"', b).group(1)
        noisy = re.search(r'noisy = "([^"]+)"', b).group(1)
        c = tifffile.imread(a.pairs / clean).astype(np.float64).squeeze()
        c = (c / dn_per_e_src * dn_per_e).astype(np.float32)  # same electrons, the twin's DN
        tifffile.imwrite(dst / clean, c[None])
        tifffile.imwrite(dst / "tmp/c.tif", c)
        subprocess.run([EMCCD, "synthesize", str(dst / "tmp/c.tif"), "-o", str(dst / "tmp/n.tif"),
                        "--model", "pgn", "--profile", str(a.out / "prof"),
                        "--signal-dn", str(float(c.max())), "--seed", str(a.seed + k)],
                       check=True, capture_output=True)
        n = tifffile.imread(dst / "tmp/n.tif").astype(np.float32).squeeze() + FLAT_DN
        tifffile.imwrite(dst / noisy, n[None])
        entries.append("[[pair]]" + b.rstrip() + "\n")
    shutil.rmtree(dst / "tmp")
    (dst / "pairs.toml").write_text("\n".join(entries))
    print(f"{len(blocks)} pairs in {dst}")


if __name__ == "__main__":
    main()
