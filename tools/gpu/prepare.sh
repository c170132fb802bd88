#!/usr/bin/env bash
# Before a GPU loan (issue 39): everything `tools/gpu/autotune.sh` needs on the lent machine, in
# ignored folders of the work tree that `device run` carries (`carry: [".gl", ".gpu"]`, 64 MiB
# at most with the tracked files; the bundled models are built into the binary from models/, so
# the build needs them: move tests/data and, unless (b) needs it, emccd-checks.xz aside for the
# call):
#   .gl/                    the Vulkan loader and glvnd packages (the device README's recipe)
#   .gpu/emccd.xz           (a) --features vulkan-direct (burn's direct convolution kernels)
#   .gpu/emccd-autotune.xz  (b) --features vulkan (burn's autotuner, no fusion: the GPU build)
#   .gpu/emccd-checks.xz    (b) with burn's autotune-checks, for a run of (b) that goes to NaN
#   .gpu/data/train, val    clean images: FMD confocal fields 1–4 and Kodak 1–8; BSD68 1–4
#   .gpu/models             the bundled `default` network, for the inference timing
# Run it from the repository root with ../shared beside it; a second run rebuilds only what
# changed. The first release build takes about 15 minutes on 2 cores, the other two less.
set -euo pipefail
cd "$(dirname "$0")/../.."
D=../shared/data/clean
grep -qx '/.gl/' .git/info/exclude 2>/dev/null || echo /.gl/ >>.git/info/exclude
grep -qx '/.gpu/' .git/info/exclude 2>/dev/null || echo /.gpu/ >>.git/info/exclude
mkdir -p .gl .gpu/data/train .gpu/data/val
if ! ls .gl/*.deb >/dev/null 2>&1; then
    o='-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64'
    mkdir -p /tmp/amd64/partial
    # shellcheck disable=SC2086
    apt-get $o update -q >/dev/null
    # shellcheck disable=SC2086
    (cd .gl && apt-get $o download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2)
fi
cp "$D"/microscopy/fmd-confocal-bpae/field[1-4]-avg50.png .gpu/data/train/
for k in 01 02 03 04 05 06 07 08; do cp "$D"/natural/Kodak24/kodim$k.png .gpu/data/train/ 2>/dev/null || true; done
ls "$D"/natural/BSD68 | head -4 | while read -r f; do cp "$D/natural/BSD68/$f" .gpu/data/val/; done
build() { # FEATURES NAME (one target folder: cargo keeps each feature set's burn beside the
    # others, and the crates the features do not touch are built once)
    CARGO_TARGET_DIR=target/gpu cargo build --release --locked --features "$1"
    strip -o ".gpu/$2" target/gpu/release/emccd
    xz -9e -T2 -f ".gpu/$2"
    echo "built .gpu/$2.xz ($1): $(du -h ".gpu/$2.xz" | cut -f1)"
}
build vulkan-direct emccd
build vulkan emccd-autotune
build autotune-checks emccd-checks
# The model the inference timing runs (models/ itself stays behind: the carry is 64 MiB in all).
mkdir -p .gpu/models && cp models/default-unet.safetensors .gpu/models/
du -sh .gl .gpu
