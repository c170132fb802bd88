#!/usr/bin/env bash
# What ran on a lent GPU machine (issue 11), in phases, one per `device run` call; the calls follow
# each other while the machine stays warm, and the training runs in its own process session
# (setsid) between them, under /root/gpu outside the work tree.
#
#   bash tools/gpu/session.sh start SECONDS END  # set-up, GPU check, training-speed probes, frames
#                                                # per second, then launch the runs sized to end END
#                                                # s after this call began; return after SECONDS
#   bash tools/gpu/session.sh wait  SECONDS   # follow the runs; copy their latest models to $OUT
#   bash tools/gpu/session.sh finish SECONDS  # wait for the runs (at most SECONDS), collect to $OUT
#   bash tools/gpu/session.sh levers SECONDS  # set-up, then one U-Net run per lever at once, each
#                                             # the low-light recipe with one change; then `finish`
#   bash tools/gpu/session.sh long SECONDS END # set-up, then the runs of RUNS at once: a probe of
#                                             # PROBE_S s times them, and each is launched with the
#                                             # steps that end it about END s after this call began
#                                             # (its cosine schedule then ends too); then `wait`, `finish`
#
# The work tree carries (ignored, see .git/info/exclude): .gl/ (the Vulkan loader and glvnd debs
# of the device README's recipe, all of them: NVIDIA's Vulkan ICD is libGLX_nvidia.so.0, which
# does not load without libglvnd's, and wgpu then finds no adapter), .gpu/emccd.xz (the stripped
# `--features vulkan` release binary, xz -9e: 12 MB) and .gpu/data/ (training and validation
# images: Kodak 1–24, BSD68, FMD confocal fields 1–4). The whole tree must stay under 64 MiB;
# move models/ you do not need out of it for the call.
#
# Env (long): FPS (1: the U-Net's frames per second on 512² frames first, alone), RUNS ("name:extra args;…", each with CHARB, the low-light recipe with the
# Charbonnier loss, and the training images; .gpu/models/ holds the bundled models they start from).
# Env (levers): LEVERS ("name:extra args;…"), LEVER_STEPS (steps of every run, default 1500).
# Env: PROBE_S (probe seconds, default 100), UF_SIZES (Uformer sizes to time, default "t s b").
set -uo pipefail
phase=${1:?phase}
secs=${2:-570}
end=${3:-1500}
T0=$(date +%s)
R=/root/gpu
B=$R/emccd
D=$PWD/.gpu/data
OUT=${OUT:-/tmp/out}
mkdir -p "$R" "$OUT"
log() { echo "[$(($(date +%s) - T0))s] $*" | tee -a "$R/session.log"; }
# vulkan_env, stamp
. tools/gpu/common.sh

# The set-up of a phase that starts runs: the Vulkan loader, the binary unpacked, the machine
# and the binary's version in the session log, no runs in flight.
setup() {
    vulkan_env
    rm -f "$R/pids"
    python3 -c "import lzma, shutil, sys; shutil.copyfileobj(lzma.open('.gpu/emccd.xz'), open(sys.argv[1], 'wb'))" "$B" && chmod +x "$B"
    nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee -a "$R/session.log"
    "$B" --version | tee -a "$R/session.log"
}

# launch NAME ARGS…: `emccd train ARGS` into $R/NAME.safetensors in its own process session
# (it outlives the call), its log lines stamped with the time in $R/NAME.train.log; its pid
# joins $R/pids.
launch() {
    local name=$1
    shift
    setsid nohup bash -c "'$B' train $* --checkpoint-every 250 -o '$R/$name.safetensors' 2>&1 | { while IFS= read -r l; do echo \"\$(date +%s) \$l\"; done; } > '$R/$name.train.log'" >/dev/null 2>&1 &
    echo $! >>"$R/pids"
}

# Steps per second of a run from its stamped log: (last step − first step) / time between them.
rate() {
    awk '/step [0-9]+\/[0-9]+:/ { split($3, a, "/"); s = a[1] + 0; t = $1 + 0;
           if (n == 0) { s0 = s; t0 = t } n++; s1 = s; t1 = t }
         END { if (n >= 2 && t1 > t0) printf "%.4f\n", (s1 - s0) / (t1 - t0); else print 0 }' "$1"
}

TRAIN_DATA() {
    echo --clean "$D"/kodak/kodim{05..24}.png "$D"/bsd68 \
        "$D"/fmd/field{1,2,3}-avg50.png "$D"/fmd/field{1,2,3}-avg50.png \
        "$D"/fmd/field{1,2,3}-avg50.png "$D"/fmd/field{1,2,3}-avg50.png \
        --val "$D"/kodak/kodim0{1..4}.png
}
# The low-light recipe (the hybrid's, for a pure network): exact EMCCD chain, mean 0.3–30 e⁻.
RECIPE="--noise-model pgn --mean-electrons 0.3,30 --cic 0,0.05 --read-noise-scale 0.3,6 --loss l2"
# The same with the loss that moved the network (lever d in the README): what `lowlight` was trained on.
CHARB="--noise-model pgn --mean-electrons 0.3,30 --cic 0,0.05 --read-noise-scale 0.3,6 --loss charbonnier"
UNET="--arch unet --batch 16 --lr 5e-4 --warmup 500 --seed 2411"
UFORMER="--arch uformer-t --batch 8 --lr 2e-4 --warmup 500 --seed 2412"

# Frames per second of `emccd denoise` on 512² frames: (t(n2) − t(n1)) / (n2 − n1), which
# leaves out start-up, model load and the GPU's kernel compilation.
fps() {
    local model=$1 n1=$2 n2=$3 extra=${4:-}
    local t=()
    for n in "$n1" "$n2"; do
        local s=$(date +%s.%N)
        "$B" denoise "$R/fps/s$n.tif" -o "$R/fps/o-$n-$RANDOM.tif" --method net --model "$model" \
            --exposure-s 0.01 $extra >>"$R/fps.log" 2>&1 || { log "denoise failed ($model $extra)"; return; }
        t+=("$(awk -v a="$(date +%s.%N)" -v b="$s" 'BEGIN { printf "%.2f", a - b }')")
    done
    log "fps $(basename "$model") $extra: $(awk -v n=$((n2 - n1)) -v a="${t[0]}" -v b="${t[1]}" 'BEGIN { printf "%.2f", n / (b - a) }') frames/s (512², ${n1}-frame run ${t[0]} s, ${n2}-frame run ${t[1]} s)"
}

running() {
    local p
    for p in $(cat "$R/pids" 2>/dev/null); do kill -0 "$p" 2>/dev/null && return 0; done
    return 1
}

collect() {
    local tag=$1
    cp "$R/session.log" "$OUT/session.log" 2>/dev/null
    tail -n +1 "$R"/*.train.log >"$OUT/train.log" 2>/dev/null
    [ -f "$R/unet.safetensors" ] && cp "$R/unet.safetensors" "$OUT/unet.safetensors" ||
        cp "$R/unet.safetensors.ckpt/model.safetensors" "$OUT/unet-$tag.safetensors" 2>/dev/null
    local l n
    for l in "$R"/lever-*.train.log; do
        [ -f "$l" ] || continue
        n=$(basename "$l" .train.log)
        # Files come back up to 16 MiB: larger models are only evaluated there (`finish`).
        if [ "$(stat -c %s "$R/$n.safetensors.ckpt/model.safetensors" 2>/dev/null || echo 0)" -gt 16000000 ]; then
            continue
        elif [ -f "$R/$n.safetensors" ]; then
            cp "$R/$n.safetensors" "$OUT/$n.safetensors"
        else
            cp "$R/$n.safetensors.ckpt/model.safetensors" "$OUT/$n-$tag.safetensors" 2>/dev/null
        fi
    done
    for l in "$R"/run-*.train.log; do
        [ -f "$l" ] || continue
        n=$(basename "$l" .train.log)
        local m=$R/$n.safetensors
        [ -f "$m" ] || m=$R/$n.safetensors.ckpt/model.safetensors
        [ -f "$m" ] || continue
        # Files come back up to 16 MiB: larger ones in parts (`cat` joins them).
        if [ "$(stat -c %s "$m")" -gt 16000000 ]; then
            split -b 15M -d "$m" "$OUT/$n-$tag.safetensors.part"
        else
            cp "$m" "$OUT/$n-$tag.safetensors"
        fi
    done
    local uf=$R/uformer.safetensors
    [ -f "$uf" ] || uf=$R/uformer.safetensors.ckpt/model.safetensors
    [ -f "$uf" ] && split -b 15M -d "$uf" "$OUT/uformer-$tag.safetensors.part"
    ls -la "$OUT"
}

case $phase in
start)
    setup
    # Correctness on the GPU: the same pairs as on the CPU, the same PSNR expected.
    "$B" simulate pairs --clean "$D"/fmd/field4-avg50.png --photons 20 --denoise models/default-unet.safetensors -o "$R/demo" 2>&1 | tail -4 | tee -a "$R/session.log"
    # Training-speed probes, both runs at once as they will run.
    for r in unet uformer; do
        a=$UNET; [ $r = uformer ] && a=$UFORMER
        timeout "${PROBE_S:-100}" "$B" train $RECIPE $a $(TRAIN_DATA) --steps 100000 --checkpoint-every "${PROBE_EVERY:-25}" \
            -o "$R/probe-$r.safetensors" 2>&1 | stamp >"$R/probe-$r.log" &
    done
    wait
    ru=$(rate "$R/probe-unet.log"); rf=$(rate "$R/probe-uformer.log")
    log "probe (both at once): unet $ru steps/s, uformer-t $rf steps/s"
    tail -n 3 "$R/probe-unet.log" "$R/probe-uformer.log" | tee -a "$R/session.log"
    # Frames per second (nothing else on the GPU).
    mkdir -p "$R/fps"
    python3 - "$R/fps" <<'EOF'
import sys, numpy as np, tifffile
rng = np.random.default_rng(1)
for n in (4, 12, 36):
    x = 177 + rng.poisson(30, size=(n, 512, 512)) + rng.normal(0, 3, size=(n, 512, 512))
    tifffile.imwrite(f"{sys.argv[1]}/s{n}.tif", np.clip(x, 0, 65535).astype(np.uint16), photometric="minisblack")
EOF
    fps models/default-unet.safetensors 12 36
    fps models/default-unet.safetensors 4 12 "--ensemble 8"
    for a in ${UF_SIZES:-t s b}; do
        m=$R/probe-uformer-$a.safetensors
        [ $a = t ] && m=$R/probe-uformer.safetensors.ckpt/model.safetensors
        [ -f "$m" ] || timeout 120 "$B" train $RECIPE --arch uformer-$a --batch 2 --steps 1 --checkpoint-every 1 $(TRAIN_DATA) -o "$m" >>"$R/fps.log" 2>&1
        [ -f "$m" ] && fps "$m" 4 12
        [ $(($(date +%s) - T0)) -gt 330 ] && break
    done
    # The runs: steps sized so both end about END s after this call began.
    TRAIN_SECONDS=$((end - ($(date +%s) - T0)))
    nu=$(awk -v r="$ru" -v t=$TRAIN_SECONDS 'BEGIN { printf "%d", r * t * 0.9 }')
    nf=$(awk -v r="$rf" -v t=$TRAIN_SECONDS 'BEGIN { printf "%d", r * t * 0.9 }')
    log "launching: unet $nu steps, uformer-t $nf steps, to end in about $TRAIN_SECONDS s"
    if [ "${nu:-0}" -gt "${MIN_STEPS:-1000}" ]; then
        launch unet $RECIPE $UNET $(TRAIN_DATA) --steps $nu
    fi
    if [ "${nf:-0}" -gt "${MIN_STEPS:-500}" ]; then
        launch uformer $RECIPE $UFORMER $(TRAIN_DATA) --steps $nf
    fi
    sleep 20
    while running && [ $(($(date +%s) - T0)) -lt $((secs - 25)) ]; do sleep 15; done
    tail -n 2 "$R"/*.train.log
    collect a
    ;;
levers)
    setup
    IFS=';' read -ra runs <<<"${LEVERS:?LEVERS}"
    for r in "${runs[@]}"; do
        name=${r%%:*}
        extra=${r#*:}
        log "lever $name: $RECIPE $UNET $extra --steps ${LEVER_STEPS:-1500}"
        launch "lever-$name" $RECIPE $UNET $extra $(TRAIN_DATA) --steps ${LEVER_STEPS:-1500}
    done
    sleep 20
    while running && [ $(($(date +%s) - T0)) -lt $((secs - 25)) ]; do sleep 15; done
    tail -n 2 "$R"/*.train.log
    collect a
    ;;
long)
    setup
    export EMCCD_MODELS=$PWD/.gpu/models
    # FPS=1: first the frames per second of the bundled networks' U-Net on 512² frames, alone on
    # the GPU (a one-step model of the same architecture: the weights do not change the time).
    if [ -n "${FPS:-}" ]; then
        mkdir -p "$R/fps"
        python3 - "$R/fps" <<'EOF2'
import sys, numpy as np, tifffile
rng = np.random.default_rng(1)
for n in (12, 36):
    x = 177 + rng.poisson(30, size=(n, 512, 512)) + rng.normal(0, 3, size=(n, 512, 512))
    tifffile.imwrite(f"{sys.argv[1]}/s{n}.tif", np.clip(x, 0, 65535).astype(np.uint16), photometric="minisblack")
EOF2
        timeout 180 "$B" train $CHARB --arch unet --batch 2 --steps 1 --checkpoint-every 1 $(TRAIN_DATA) \
            -o "$R/fps-unet.safetensors" >>"$R/fps.log" 2>&1
        fps "$R/fps-unet.safetensors" 12 36
    fi
    IFS=';' read -ra runs <<<"${RUNS:?RUNS}"
    # Probe: all runs at once, as they will run.
    for r in "${runs[@]}"; do
        name=${r%%:*}
        timeout "${PROBE_S:-75}" "$B" train $CHARB ${r#*:} $(TRAIN_DATA) --steps 100000 --checkpoint-every "${PROBE_EVERY:-25}" \
            -o "$R/probe-$name.safetensors" 2>&1 | stamp >"$R/probe-$name.log" &
    done
    wait
    left=$((end - ($(date +%s) - T0)))
    for r in "${runs[@]}"; do
        name=${r%%:*}
        rt=$(rate "$R/probe-$name.log")
        n=$(awk -v r="$rt" -v t=$left 'BEGIN { printf "%d", r * t * 0.92 }')
        tail -n 2 "$R/probe-$name.log" | tee -a "$R/session.log"
        log "run $name: $rt steps/s in the probe; launching $CHARB ${r#*:} --steps $n (about $left s)"
        [ "${n:-0}" -gt 100 ] || continue
        launch "run-$name" $CHARB ${r#*:} $(TRAIN_DATA) --steps $n
    done
    sleep 20
    while running && [ $(($(date +%s) - T0)) -lt $((secs - 25)) ]; do sleep 15; done
    tail -n 2 "$R"/*.train.log
    collect a
    ;;
chain)
    # CHAIN="name:extra args", CHAIN_STEPS: launched once the runs in flight have ended (e.g. a
    # continuation that starts from one of them: --init $R/run-NAME.safetensors).
    vulkan_env
    export EMCCD_MODELS=$PWD/.gpu/models
    while running && [ $(($(date +%s) - T0)) -lt $((secs - 60)) ]; do sleep 5; done
    tail -n 2 "$R"/*.train.log
    name=${CHAIN%%:*}
    log "chain $name: $CHARB ${CHAIN#*:} --steps $CHAIN_STEPS"
    rm -f "$R/pids"
    launch "run-$name" $CHARB ${CHAIN#*:} $(TRAIN_DATA) --steps $CHAIN_STEPS
    while [ $(($(date +%s) - T0)) -lt $((secs - 25)) ]; do sleep 15; done
    tail -n 3 "$R"/*.train.log
    collect b
    ;;
wait)
    while [ $(($(date +%s) - T0)) -lt $((secs - 25)) ]; do sleep 15; done
    tail -n 3 "$R"/*.train.log
    nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv,noheader
    collect b
    ;;
finish)
    while [ $(($(date +%s) - T0)) -lt $((secs - ${EVAL_S:-40})) ] && running; do sleep 10; done
    tail -n 3 "$R"/*.train.log
    # The lever models on the validation camera (.gpu/tune.tar.xz: out/tune's pairs and profile).
    if [ -f .gpu/tune.tar.xz ] && ls "$R"/lever-*.train.log >/dev/null 2>&1; then
        mkdir -p "$R/tune" && tar xJf .gpu/tune.tar.xz -C "$R/tune"
        ms=()
        for l in "$R"/lever-*.train.log; do
            n=${l%.train.log}
            m=$n.safetensors
            [ -f "$m" ] || m=$n.safetensors.ckpt/model.safetensors
            [ -f "$m" ] && ms+=(--method "$m")
        done
        "$B" evaluate "$R/tune/pairs" "${ms[@]}" 2>&1 | tee "$OUT/eval.md"
    fi
    collect c
    ;;
esac
