#!/usr/bin/env bash
# Measures `emccd adapt` on recordings the models never saw (issue 13): for every stack that
# tools/adapt_stacks.py wrote under DIR, adapt INIT on the stack, then score on the held-out
# frames: INIT un-adapted, INIT adapted, BM3D + GAT and iterative BM3D (`ivst`). The ground
# truth is used only to score.
#
# Usage: tools/adapt_bench.sh DIR PROFILE [INIT] [STEPS] [METHOD] [LR] [FLAGS]
#   DIR      tools/adapt_stacks.py's output (one folder per scene and level)
#   PROFILE  the camera's profile (emccd calibrate of tools/unseen_camera.py's acquisition)
#   INIT     the model to adapt (default: default), or `scratch` (a new network of
#            `lowlight`'s architecture: the self-supervised baseline; no un-adapted column)
#   STEPS    adaptation steps (default 200)
#   METHOD   adapt --method (default resynthesis)
#   LR       adapt --lr (default: adapt's own; `-` for the default with FLAGS)
#   FLAGS    further adapt flags, one word (e.g. --augment; named in the tag)
# Writes DIR/*/adapted-TAG.safetensors, DIR/*/eval-TAG.json and prints a per-level table.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
dir="$1"; profile="$2"; init="${3:-default}"; steps="${4:-200}"; method="${5:-resynthesis}"; lr="${6:-}"; flags="${7:-}"
[ "$lr" != - ] || lr=""
E="${EMCCD:-$root/target/release/emccd}"
tag="$(basename "${init%.safetensors}")"
[ "$method" = resynthesis ] || tag="$tag-$method"
[ "$steps" = 200 ] || tag="$tag-s$steps"
rate=()
[ -z "$lr" ] || { rate=(--lr "$lr"); tag="$tag-lr$lr"; }
extra=()
[ -z "$flags" ] || { extra=("$flags"); tag="$tag${flags#-}"; }
base=(--method "$init"); from=(--init "$init")
[ "$init" = scratch ] && base=() && from=(--init lowlight --from-scratch)
# The lowest light levels first (where adaptation gains least), then the rest, each once.
declare -A seen=()
for d in "$dir"/*_m1/ "$dir"/*_m4/ "$dir"/*/; do
    [ -d "$d" ] && [ -z "${seen[$d]:-}" ] || continue
    seen[$d]=1
    d="${d%/}"
    [ -f "$d/stack.tif" ] || continue
    m="$d/adapted-$tag.safetensors"
    [ -f "$m" ] || "$E" adapt "$d/stack.tif" --profile "$profile" --exposure-s 0.01 "${from[@]}" \
        --method "$method" --steps "$steps" ${rate[@]+"${rate[@]}"} ${extra[@]+"${extra[@]}"} -o "$m" 2>&1 | tail -1
    # Written under a temporary name: a failed evaluation leaves no empty result behind.
    [ -s "$d/eval-$tag.json" ] || { "$E" evaluate "$d/pairs" --profile "$profile" ${base[@]+"${base[@]}"} \
        --method "$m" --method bm3d --method ivst --json > "$d/eval-$tag.json.tmp" &&
        mv "$d/eval-$tag.json.tmp" "$d/eval-$tag.json"; }
done
python3 - "$dir" "$tag" <<'PY'
import json, sys, glob, collections
d, tag = sys.argv[1], sys.argv[2]
acc = collections.defaultdict(list)
for f in sorted(glob.glob(f"{d}/*/eval-{tag}.json")):
    for p in json.load(open(f))["pairs"]:
        meth = p["method"]
        name = "adapted" if meth.endswith(f"adapted-{tag}.safetensors") else ("un-adapted" if meth not in ("bm3d", "ivst") else meth)
        acc[(p["mean_electrons"], name)].append(p["psnr_db"])
        acc[("all", name)].append(p["psnr_db"])
cols = ["un-adapted", "adapted", "bm3d", "ivst"]
print(f"| mean e-/px | {tag} | {tag} adapted | BM3D + GAT | ivst |")
print("|---:|---:|---:|---:|---:|")
for lv in sorted({k[0] for k in acc}, key=lambda v: (v == "all", 0 if v == "all" else float(v))):
    cell = lambda v: f"{sum(v) / len(v):.2f}" if v else "—"
    print(f"| {lv} | " + " | ".join(cell(acc[(lv, c)]) for c in cols) + " |")
PY
