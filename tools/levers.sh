#!/usr/bin/env bash
# One-lever learning curves for the pure low-light network (issue 11), on the CPU: the
# low-light recipe (PGN noise, mean 0.3–30 e⁻, CIC 0–0.05, read noise ×0.3–6, batch 4 of 128²,
# seed 2411) with one change per run, each from scratch (f: d with the input pixel-unshuffled,
# about 3x the steps per CPU-minute, so 3000 steps for d's 1000 steps' time; g: d with the
# paper's noise model instead of the Poisson-Gamma-Normal chain, its validation crops too, so
# compare g on the validation camera only; h: d with the per-frame scale taken from 4x4 block
# means); runs already finished are skipped,
# an interrupted one continues (--resume). Then the curves and the validation camera:
#
#   bash tools/levers.sh D OUT       # D: the training images (kodak/, bsd68/, fmd/ as in
#                                    # tools/gpu/session.sh's .gpu/data); OUT: logs and models
#   python3 tools/learning_curves.py docs/learning-curves.png "lr 5e-4=OUT/a.log" ...
#   emccd evaluate out/tune/pairs --method OUT/a.safetensors ...
set -euo pipefail
D=${1:?training images}
O=${2:?output folder}
B=${EMCCD:-$(dirname "$0")/../target/release/emccd}
mkdir -p "$O"
DATA="--clean $D/kodak/kodim0[5-9].png $D/kodak/kodim1[0-9].png $D/kodak/kodim2[0-4].png $D/bsd68 \
$(for i in 1 2 3 4; do echo $D/fmd/field{1,2,3}-avg50.png; done) --val $D/kodak/kodim0[1-4].png"
RECIPE="--mean-electrons 0.3,30 --read-noise-scale 0.3,6 --arch unet --batch 4 --warmup 100 --seed 2411"
# The noise model of every run but one that names its own (CIC is the PGN chain's alone).
PGN="--noise-model pgn --cic 0,0.05"
L2="--loss l2 --steps 1000 --checkpoint-every 100"
for r in "a:$L2 --lr 5e-4" \
         "b:$L2 --lr 5e-4 --direct" \
         "c:$L2 --lr 1e-3" \
         "d:--loss charbonnier --steps 1000 --checkpoint-every 100 --lr 1e-3" \
         "e:--loss l2 --lr 1e-3 --channels 32 --steps 300 --checkpoint-every 30" \
         "f:--loss charbonnier --steps 3000 --checkpoint-every 100 --lr 1e-3 --unshuffle 2" \
         "g:--loss charbonnier --steps 1000 --checkpoint-every 100 --lr 1e-3 --noise-model ours" \
         "h:--loss charbonnier --steps 1000 --checkpoint-every 100 --lr 1e-3 --scale binned"; do
    n=${r%%:*}
    x=${r#*:}
    [ -f "$O/$n.safetensors" ] && continue
    case "$x" in *--noise-model*) ;; *) x="$PGN $x" ;; esac
    echo "== $n: $RECIPE $x" >"$O/$n.log"
    # shellcheck disable=SC2086
    nice -n 10 "$B" train $RECIPE $x $DATA -o "$O/$n.safetensors" --resume >>"$O/$n.log" 2>&1
done
