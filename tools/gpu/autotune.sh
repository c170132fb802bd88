#!/usr/bin/env bash
# Issue 39 on a lent GPU, in one `device run` (prepared by tools/gpu/prepare.sh; carry .gl and
# .gpu):
#
#     bash tools/gpu/autotune.sh [SECONDS]        # default 540: the whole measurement
#     ONLY=fps bash tools/gpu/autotune.sh         # the inference timing alone
#
# Side by side on the same card: training crops per second and the loss over the first 200
# steps (batch 16, 128² crops, the default U-Net, the low-light recipe's noise) for
#   (a) the `vulkan-direct` build (burn's direct convolution kernels),
#   (b) the `vulkan` build (burn's autotuner picks im2col/implicit-GEMM kernels; the
#       choices persist under ~/.cache/burn, so the first steps include the tuning),
#   (c) the same U-Net in PyTorch (tools/gpu/torch_unet.py, the yardstick);
# and inference frames per second on 512² frames (`emccd denoise --method net`, 20 frames) for
# (a) and (b). If (b) trains to NaN it is run again with burn's autotune-checks, whose messages
# name the kernel that disagrees. Everything goes to $OUT: autotune.md (the table), the logs.
set -uo pipefail
secs=${1:-540}
T0=$(date +%s)
R=/root/gpu
OUT=${OUT:-/tmp/out}
mkdir -p "$R" "$OUT"
log() { echo "[$(($(date +%s) - T0))s] $*" | tee -a "$OUT/autotune.log"; }
left() { echo $((secs - ($(date +%s) - T0))); }

# vulkan_env, stamp
. tools/gpu/common.sh
vulkan_env
# The bundled models travel in .gpu/models when models/ is left behind (the 64 MiB carry).
[ -d .gpu/models ] && export EMCCD_MODELS=$PWD/.gpu/models
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee -a "$OUT/autotune.log"
for b in emccd emccd-autotune emccd-checks; do
    [ -f ".gpu/$b.xz" ] && xz -dc ".gpu/$b.xz" >"$R/$b" && chmod +x "$R/$b"
done

# train NAME BINARY: 200 steps, a log line every 20, each stamped.
train() {
    local name=$1 bin=$2 budget
    budget=$(($(left) - 60))
    [ "$budget" -gt 30 ] || { log "$name: no time left"; return; }
    log "$name: training 200 steps ($bin)"
    timeout "$budget" "$R/$bin" train --clean .gpu/data/train --val .gpu/data/val --steps 200 \
        --batch 16 --crop 128 --checkpoint-every 20 --mean-electrons 0.3,30 --noise-model pgn \
        -o "$R/$name.safetensors" 2>&1 | stamp >"$OUT/$name.train.log"
    log "$name: exit ${PIPESTATUS[0]} — $(tail -1 "$OUT/$name.train.log")"
}

# crops/s of a stamped training log: steps between the first and last logged lines over the
# time between them (the first line comes after 20 steps: the warm-up and, for (b), most of the
# tuning are outside the rate).
rate() {
    awk '$2 == "step" && $3 ~ /^[0-9]+\/[0-9]+:$/ { split($3, a, "/"); s = a[1] + 0; t = $1 + 0;
           if (n == 0) { s0 = s; t0 = t } n++; s1 = s; t1 = t }
         END { if (n >= 2 && t1 > t0) printf "%.1f", 16 * (s1 - s0) / (t1 - t0); else print "–" }' "$1"
}
losses() { # first and last logged loss, and whether any was not a number
    awk '$2 == "step" { for (i = 1; i <= NF; i++) if ($i == "loss") l = $(i + 1);
           if (n == 0) f = l; n++; if (l !~ /^[0-9.e+-]+$/) bad = 1 }
         END { printf "%s → %s%s", f, l, bad ? " (NaN)" : "" }' "$1"
}

# fps BINARY: 512² frames per second of the bundled default network on 20 frames (FMD field 1,
# 512²), timed on a second run: the first compiles the shaders and, for (b), tunes and persists
# its kernel choices.
fps() {
    local bin=$1
    [ -f "$R/stack/noisy/field1-avg50_p20.tif" ] || "$R/$bin" simulate pairs --clean .gpu/data/train/field1-avg50.png \
        --frames 20 -o "$R/stack" >/dev/null 2>>"$OUT/fps.log"
    local run=("$R/$bin" denoise "$R/stack/noisy/field1-avg50_p20.tif" -o "$R/$bin.den.tif" --method net
        --model default --profile default)
    "${run[@]}" >/dev/null 2>>"$OUT/fps.log" || { echo "–"; return; }
    rm -f "$R/$bin.den.tif"
    local t=$(date +%s.%N)
    "${run[@]}" >/dev/null 2>>"$OUT/fps.log" || { echo "–"; return; }
    python3 -c "import sys; print(f'{20 / (float(sys.argv[2]) - float(sys.argv[1])):.1f}')" "$t" "$(date +%s.%N)"
}

if [ "${ONLY:-}" = fps ]; then # the inference timing alone
    echo "(a) vulkan-direct: $(fps emccd) frames/s; (b) vulkan: $(fps emccd-autotune) frames/s" | tee "$OUT/fps.md"
    exit 0
fi

train a emccd
train b emccd-autotune
if grep -q "NaN" "$OUT/b.train.log" 2>/dev/null && [ -x "$R/emccd-checks" ]; then
    train b-checks emccd-checks
fi
log "c: PyTorch"
timeout $(($(left) - 40)) python3 tools/gpu/torch_unet.py --steps 200 --batch 16 --crop 128 >"$OUT/torch.json" 2>"$OUT/torch.err"
log "c: $(cat "$OUT/torch.json")"
fa=$(fps emccd)
fb=$(fps emccd-autotune)
torch_rate=$(python3 -c "import json; print(json.load(open('$OUT/torch.json'))['crops_per_s'])" 2>/dev/null || echo –)
torch_loss=$(python3 -c "import json; d = json.load(open('$OUT/torch.json')); print(f\"{d['loss_first']:.4f} → {d['loss_last']:.4f}{'' if d['finite'] else ' (NaN)'}\")" 2>/dev/null || echo –)
{
    echo "| build | training crops/s (batch 16, 128²) | loss, first → last logged | inference 512² frames/s |"
    echo "|---|---|---|---|"
    echo "| (a) vulkan-direct | $(rate "$OUT/a.train.log") | $(losses "$OUT/a.train.log") | $fa |"
    echo "| (b) vulkan (autotune) | $(rate "$OUT/b.train.log") | $(losses "$OUT/b.train.log") | $fb |"
    echo "| (c) PyTorch | $torch_rate | $torch_loss | – |"
    echo
    echo "$(nvidia-smi --query-gpu=name --format=csv,noheader | head -1), $(date -u +%F)"
} >"$OUT/autotune.md"
cat "$OUT/autotune.md"
