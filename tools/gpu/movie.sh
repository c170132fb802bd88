#!/usr/bin/env bash
# Issue 35 on a lent GPU, in one `device run` (prepared by tools/gpu/prepare-movie.sh; carry .gl
# and .gpu/movie):
#
#     bash tools/gpu/movie.sh [SECONDS] [STEPS]     # defaults 500 and 3000
#
# The environment changes a run's starting point and recipe (defaults: stage 1 of the `movie`
# card): INIT (a bundled name or a file carried in .gpu/movie), LOSS, LR, WARMUP, SEED.
#
# Trains the temporal network (`--inputs movie`: the frame, 2 frames each side and its noise
# level) from the bundled `lowlight` network, widened so that it starts as exactly that network,
# on movies synthesized from clean images with the low-light recipe's noise (the `lowlight`
# card's flags) and every kind of motion crates/train/src/motion.rs draws. Stops at STEPS or
# when SECONDS run out; the model (the finished run's, else the last checkpoint's) and the log
# go to $OUT.
set -uo pipefail
secs=${1:-500}
steps=${2:-3000}
T0=$(date +%s)
R=/root/gpu
OUT=${OUT:-/tmp/out}
mkdir -p "$R" "$OUT"
. tools/gpu/common.sh
vulkan_env
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$OUT/movie.log"
xz -dc .gpu/movie/emccd.xz >"$R/emccd" && chmod +x "$R/emccd"
budget=$((secs - ($(date +%s) - T0) - 25))
echo "training for at most ${budget}s" | tee -a "$OUT/movie.log"
timeout "$budget" "$R/emccd" train --inputs movie --init "${INIT:-lowlight}" --noise-model pgn \
    --mean-electrons 0.3,30 --cic 0,0.05 --read-noise-scale 0.3,6 --loss "${LOSS:-charbonnier}" \
    --lr "${LR:-3e-4}" --batch 16 --warmup "${WARMUP:-100}" --seed "${SEED:-3501}" \
    --steps "$steps" --checkpoint-every 100 \
    --clean .gpu/movie/train --val .gpu/movie/val -o "$R/movie-unet.safetensors" 2>&1 |
    stamp >"$OUT/train.log"
echo "train exit ${PIPESTATUS[0]} after $(($(date +%s) - T0))s" | tee -a "$OUT/movie.log"
if [ -f "$R/movie-unet.safetensors" ]; then
    cp "$R/movie-unet.safetensors" "$OUT/"
elif [ -f "$R/movie-unet.safetensors.ckpt/model.safetensors" ]; then
    cp "$R/movie-unet.safetensors.ckpt/model.safetensors" "$OUT/movie-unet-ckpt.safetensors"
    cp "$R/movie-unet.safetensors.ckpt/state.json" "$OUT/"
fi
tail -3 "$OUT/train.log"
ls -la "$OUT"
