#!/usr/bin/env python3
"""Does `emccd` refuse another camera's profile and never the right one? (issue 67's mismatch target)

For every movie that tools/movie_suite.py made under OUT (OUT/CAMERA/movies/*.tif, each camera
calibrated into OUT/CAMERA/profile), and for each movie's first frame alone, runs
`emccd denoise FILE --profile P --method none` through every camera's profile and records
whether the profile was refused as not fitting. Prints a table (refusals of the right profile:
the false alarms; of the others: the catches) and writes OUT/misfit.json.

Usage: python3 tools/misfit_check.py OUT
"""
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import tifffile

ROOT = Path(__file__).resolve().parent.parent
EXPOSURE = 0.01  # tools/unseen_camera.py's TEST_EXPOSURE


def refused(exe, path, profile, out):
    r = subprocess.run([str(exe), "denoise", str(path), "--profile", str(profile), "--method", "none",
                        "--exposure-s", str(EXPOSURE), "-o", str(out)], capture_output=True, text=True)
    if r.returncode == 0:
        return False, ""
    if "does not fit profile" in r.stderr:
        return True, " / ".join(l.strip() for l in r.stderr.splitlines() if l.strip().startswith("- "))
    sys.exit(f"{path} through {profile}: failed otherwise:\n{r.stderr}")


def main():
    out = Path(sys.argv[1])
    exe = ROOT / "target/release/emccd"
    cams = sorted(p.parent.parent.name for p in out.glob("*/profile/profile.toml"))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for cam in cams:
            for movie in sorted((out / cam / "movies").glob("*_m*.tif")):
                if movie.stem.count("_") != 1:  # truth, preprocessed and denoised files
                    continue
                one = tmp / f"{cam}_{movie.stem}_one.tif"
                tifffile.imwrite(one, tifffile.imread(movie)[:1], imagej=True)
                for what, path in (("movie", movie), ("one frame", one)):
                    for prof in cams:
                        r, why = refused(exe, path, out / prof / "profile", tmp / "o.tif")
                        rows.append(dict(camera=cam, file=movie.stem, kind=what, profile=prof,
                                         right=prof == cam, refused=r, why=why))
                        print(json.dumps(rows[-1]), file=sys.stderr)
    (out / "misfit.json").write_text(json.dumps(rows, indent=1))
    print("| recording | profile | recordings | refused |\n|---|---|---:|---:|")
    for kind in ("movie", "one frame"):
        for right in (True, False):
            sel = [r for r in rows if r["kind"] == kind and r["right"] == right]
            print(f"| {kind} | {'its own' if right else 'the other camera'} | {len(sel)} | "
                  f"{sum(r['refused'] for r in sel)} |")


if __name__ == "__main__":
    main()
