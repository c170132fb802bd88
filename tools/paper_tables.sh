#!/usr/bin/env bash
# The paper's Tables 1 and 2 on the virtual camera (README, "The paper's experiments").
#
# Test pairs: McMaster (never used in training), 256×256 crops of the default virtual camera
# (exposure-dependent FPN and blooming on), short exposures at the paper's exposure ratios
# 30–1600 to a 1.6 s reference. Networks: one architecture and budget for every noise model and
# ablation (U-Net, 8 channels, 4 levels, STEPS steps of 4 × 64² crops from Kodak24 + BSD68).
# Ablations III (FPN) and IV (blooming) change the preprocessing, not the synthesized pairs, so
# they reuse network `ours` with that correction switched off. ELD and PGN are evaluated twice:
# with their own preprocessing (as in the paper) and with ours (the noise model alone).
#
# Usage: tools/paper_tables.sh [OUT]   (STEPS=2500 by default; about 1 h on 2 cores)
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/paper}
STEPS=${STEPS:-2500}
cargo build --release --quiet
E=./target/release/emccd
NAT=../shared/data/clean/natural
mkdir -p "$OUT"
[ -f "$OUT/pairs/pairs.toml" ] || $E simulate pairs --clean $NAT/McMaster --crop 256x256 \
    --exposure-ratio 30,100,300,1000,1600 -o "$OUT/pairs" > "$OUT/pairs.log"
common=(--profile default --clean $NAT/Kodak24 $NAT/BSD68 --channels 8 --levels 4 --crop 64 --batch 4
        --steps "$STEPS" --warmup 150 --checkpoint-every 500 --seed 11)
train() {
    local name=$1; shift
    [ -f "$OUT/$name.safetensors" ] || $E train "${common[@]}" "$@" -o "$OUT/$name.safetensors" 2> "$OUT/$name.log"
}
train ours
train eld --noise-model eld
train pgn --noise-model pgn
train no-multiplicative --ablate multiplicative
train no-readout --ablate readout
for a in fpn blooming; do
    [ -f "$OUT/no-$a.safetensors" ] || $E train --clean $NAT/Kodak24 --steps 0 --init "$OUT/ours.safetensors" \
        --ablate $a -o "$OUT/no-$a.safetensors" 2> /dev/null
done
# The comparison models as the paper ran them: their noise model and their own preprocessing,
# which knows neither the exposure-dependent FPN (a bias frame is subtracted) nor blooming.
for m in eld pgn; do
    [ -f "$OUT/$m-own.safetensors" ] || $E train --clean $NAT/Kodak24 --steps 0 --init "$OUT/$m.safetensors" \
        --noise-model $m --ablate fpn,blooming -o "$OUT/$m-own.safetensors" 2> /dev/null
done
# The self-supervised baseline (the paper's SRDTrans row): a network of the same size and budget
# (STEPS steps of 4 × 64², lr 2e-4, seed 11) trained from scratch on the 90 noisy test frames
# alone, with SRDTrans's spatial-redundancy sampling (`adapt --method neighbors`). The frames are
# 256² crops at the sensor's origin: the profile of that region.
[ -f "$OUT/profile-256/profile.toml" ] || $E profile crop default --roi 0,0,256x256 "$OUT/profile-256" > /dev/null
[ -f "$OUT/arch-8x4.safetensors" ] || $E train --profile default --clean $NAT/Kodak24 --channels 8 --levels 4 \
    --crop 64 --steps 0 --seed 11 -o "$OUT/arch-8x4.safetensors" 2> /dev/null
[ -f "$OUT/selfsup.safetensors" ] || $E adapt "$OUT"/pairs/noisy/*.tif --profile "$OUT/profile-256" \
    --init "$OUT/arch-8x4.safetensors" --from-scratch --method neighbors --crop 64 --batch 4 \
    --steps "$STEPS" --lr 2e-4 --seed 11 --augment -o "$OUT/selfsup.safetensors" 2> "$OUT/selfsup.log"
methods=(--method input --method bm3d)
for m in ours eld-own pgn-own eld pgn selfsup no-multiplicative no-readout no-fpn no-blooming; do
    methods+=(--method "$OUT/$m.safetensors")
done
# The bundled model (16 channels, 3000 steps of 4 × 128²) for scale.
methods+=(--method default)
$E evaluate "$OUT/pairs" --profile default "${methods[@]}" --out "$OUT/eval" | tee "$OUT/table.md"
