#!/usr/bin/env bash
# Runs every fuzz target for EXECS executions (default 1 000 000) from seeds/ (make_seeds.sh),
# then prints each target's executions, corpus, coverage, crashes and hangs.
#   cargo install cargo-afl && cargo afl config --build   # once
#   bash make_seeds.sh && cargo afl build --release && bash run.sh
set -uo pipefail
cd "$(dirname "$0")"
export AFL_SKIP_CPUFREQ=1 AFL_NO_UI=1 AFL_I_DONT_CARE_ABOUT_MISSING_CRASHES=1 AFL_NO_AFFINITY=1
mkdir -p out
for t in ${TARGETS:-tiff sif fits manifest profile model}; do
    rm -rf "out/$t"
    cargo afl fuzz -i "seeds/$t" -o "out/$t" -E "${EXECS:-1000000}" -t 2000 "target/release/$t" >"out/$t.log" 2>&1
    s=out/$t/default/fuzzer_stats
    printf '%-9s %s\n' "$t" "$(grep -E '^(execs_done|execs_per_sec|corpus_count|bitmap_cvg|saved_crashes|saved_hangs) ' "$s" | awk '{printf "%s=%s ", $1, $3}')"
done
