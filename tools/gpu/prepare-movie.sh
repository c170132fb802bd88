#!/usr/bin/env bash
# Before a GPU loan for issue 35: what `tools/gpu/movie.sh` needs on the lent machine, in ignored
# folders of the work tree that `device run` carries (`carry: [".gl", ".gpu/movie"]`; 64 MiB at
# most with the tracked files, so move models/ and tests/data aside for the call — the bundled
# models are built into the binary):
#   .gl/                    the Vulkan loader and glvnd packages (as tools/gpu/prepare.sh)
#   .gpu/movie/emccd.xz     the `vulkan` release build (burn's autotuner, no fusion)
#   .gpu/movie/train, val   the `lowlight` model's images: Kodak 5–24, BSD68, FMD fields 1–3
#                           (four copies each, as its card lists them); Kodak 1–4 held out
# Run it from the repository root with ../shared beside it.
set -euo pipefail
cd "$(dirname "$0")/../.."
D=../shared/data/clean
[ -d .gl ] && ls .gl/*.deb >/dev/null 2>&1 || { echo "run tools/gpu/prepare.sh once for .gl/" >&2; exit 1; }
grep -qx '/.gpu/' .git/info/exclude 2>/dev/null || echo /.gpu/ >>.git/info/exclude
rm -rf .gpu/movie && mkdir -p .gpu/movie/train .gpu/movie/val
for k in $(seq -w 5 24); do cp "$D/natural/Kodak24/kodim$(printf %02d "$((10#$k))").png" .gpu/movie/train/; done
cp "$D"/natural/BSD68/*.png .gpu/movie/train/
for f in 1 2 3; do for c in a b c d; do
    cp "$D/microscopy/fmd-confocal-bpae/field$f-avg50.png" ".gpu/movie/train/fmd$f$c.png"
done; done
for k in 1 2 3 4; do cp "$D/natural/Kodak24/kodim0$k.png" .gpu/movie/val/; done
CARGO_TARGET_DIR=target/gpu cargo build --release --locked --features vulkan
strip -o .gpu/movie/emccd target/gpu/release/emccd
xz -6 -T2 -f .gpu/movie/emccd
du -sh .gl .gpu/movie
