#!/usr/bin/env bash
# The low-light suite: two cameras emccd never saw (NASA JPL's emccd-detect simulator with two
# very different parameter sets, see tools/unseen_camera.py), at a mean of 0.5, 1, 4 and 16
# photoelectrons per pixel, on natural scenes never trained on (McMaster 1, 4, 7, 10, 13, 16) and
# microscopy scenes (FMD fields 4-6), 256x256 centre crops. Each camera is calibrated with
# `emccd calibrate` from its own bias and flat stacks, and every method runs through that
# profile; the ground truth is used only to score.
#
# Usage: tools/lowlight.sh [OUT] [METHOD...]
#   OUT      where the acquisitions, profiles and results go (default out/lowlight; the
#            acquisitions are made once, ~10 min, and reused)
#   METHOD   as `emccd evaluate --method` takes them (default: input bm3d blend ivst hybrid lowlight default microscopy)
# Needs: python3 with emccd-detect, tifffile, pillow (pip install emccd-detect tifffile pillow).
# Writes OUT/table.md (per light level and per camera, with seconds per 512x512 frame) and
# OUT/eval/ (results.json, results.csv, input | methods | truth panels).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
out="${1:-out/lowlight}"
shift || true
methods=("$@")
[ ${#methods[@]} -gt 0 ] || methods=(input bm3d blend ivst hybrid lowlight default microscopy)
data="$root/../shared/data/clean"
M="$data/natural/McMaster"
F="$data/microscopy/fmd-confocal-bpae"
E="${EMCCD:-$root/target/release/emccd}"
[ -x "$E" ] || (cd "$root" && cargo build --release --locked)
dirs=()
for cam in lowlight-a lowlight-b; do
    d="$out/$cam"
    if [ ! -f "$d/pairs/pairs.toml" ]; then
        python3 "$root/tools/unseen_camera.py" "$d" --camera "$cam" --mean-electrons 0.5,1,4,16 \
            --scenes "$M/1.tif" "$M/4.tif" "$M/7.tif" "$M/10.tif" "$M/13.tif" "$M/16.tif" \
                     "$F/field4-avg50.png" "$F/field5-avg50.png" "$F/field6-avg50.png"
    fi
    [ -f "$d/profile/profile.toml" ] || "$E" calibrate "$d/calibration.toml" -o "$d/profile" --report "$d/report"
    dirs+=("$d/pairs")
done
args=()
for m in "${methods[@]}"; do args+=(--method "$m"); done
"$E" evaluate "${dirs[@]}" "${args[@]}" --out "$out/eval" | tee "$out/table.md"
