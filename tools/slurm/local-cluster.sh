#!/usr/bin/env bash
# A real one-node SLURM cluster on this machine (Debian's slurm-wlm and munge, controller and node
# daemon on localhost), used to test sharded denoising the way a facility runs it:
#
#   1. a 64-frame raw stack from the virtual camera (a 128×128 region of the default profile,
#      `emccd profile crop`, so that the test takes about a minute), in two files (one stack);
#   2. one process denoises it into ref.zarr (the reference);
#   3. a 4-task job array (tools/slurm/denoise-array.sbatch) denoises it into array.zarr;
#   4. task 1 is cancelled once 2 or more of its 16 frames are complete (not all) and submitted
#      again on its own; it must denoise exactly the frames it had left;
#   5. the merged store must equal the reference bit for bit (every chunk), and read back the
#      same through zarr-python where it is installed.
#
# Usage: tools/slurm/local-cluster.sh [EMCCD_BINARY]   (run as root: it starts the daemons;
# it installs slurm-wlm and munge with apt-get where they are missing). Exit status 0 = passed.
set -euo pipefail
cd "$(dirname "$0")/../.."
REPO=$PWD
EMCCD=$(realpath "${1:-target/release/emccd}")
SBATCH_SCRIPT=$(realpath tools/slurm/denoise-array.sbatch)
[ -x "$EMCCD" ] || { echo "error: $EMCCD is not built (cargo build --release)" >&2; exit 1; }
[ "$(id -u)" = 0 ] || { echo "error: run as root (it starts slurmctld, slurmd and munged)" >&2; exit 1; }
if ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null; then
    (apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends slurm-wlm munge) >/dev/null
fi

W=$(mktemp -d /tmp/emccd-slurm.XXXXXX)
chmod 755 "$W"
log() { echo "[local-cluster] $*"; }
cleanup() {
    local rc=$?
    scontrol shutdown >/dev/null 2>&1 || true
    sleep 1
    [ -f "$W/munged.pid" ] && kill "$(cat "$W/munged.pid")" 2>/dev/null || true
    if [ $rc -ne 0 ]; then
        log "FAILED (exit $rc); daemon logs:"
        tail -n 20 "$W"/slurmctld.log "$W"/slurmd.log "$W"/*.log 2>/dev/null || true
    fi
    [ -n "${KEEP:-}" ] || rm -rf "$W"
}
trap cleanup EXIT

# --- munge (authentication between the SLURM daemons and clients) ---
mkdir -p "$W/munge"
if [ ! -s /etc/munge/munge.key ]; then
    mungekey --create --keyfile=/etc/munge/munge.key 2>/dev/null || dd if=/dev/urandom of=/etc/munge/munge.key bs=1 count=128 2>/dev/null
    chown munge:munge /etc/munge/munge.key 2>/dev/null || true
    chmod 400 /etc/munge/munge.key
fi
munged --force --socket="$W/munge/munge.socket" --pid-file="$W/munged.pid" \
    --log-file="$W/munged.log" --seed-file="$W/munge/munged.seed" --key-file=/etc/munge/munge.key

# --- SLURM: controller and one node daemon on localhost ---
host=$(hostname -s)
cpus=$(nproc)
mkdir -p "$W/state" "$W/spool"
cat > "$W/slurm.conf" <<CONF
ClusterName=emccdtest
SlurmctldHost=$host(127.0.0.1)
AuthType=auth/munge
AuthInfo=socket=$W/munge/munge.socket
CredType=cred/munge
SlurmUser=root
SlurmdUser=root
SlurmctldPort=16817
SlurmdPort=16818
StateSaveLocation=$W/state
SlurmdSpoolDir=$W/spool
SlurmctldPidFile=$W/slurmctld.pid
SlurmdPidFile=$W/slurmd.pid
SlurmctldLogFile=$W/slurmctld.log
SlurmdLogFile=$W/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SwitchType=switch/none
MpiDefault=none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
JobCompType=jobcomp/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
NodeName=$host NodeAddr=127.0.0.1 CPUs=$cpus State=UNKNOWN
PartitionName=main Nodes=$host Default=YES MaxTime=INFINITE State=UP
CONF
export SLURM_CONF="$W/slurm.conf"
slurmctld -i
slurmd
for _ in $(seq 60); do
    state=$(sinfo -h -o %T 2>/dev/null || true)
    [ "$state" = idle ] && break
    sleep 1
done
[ "$state" = idle ] || { echo "error: the node did not come up (state '$state')" >&2; exit 1; }
log "SLURM is up: node $host, $cpus CPUs, partition main"

# --- data: 64 raw frames in two files, and the single-process reference ---
cd "$W"
clean=$REPO/tests/data/clean/microscopy/fmd-confocal-bpae
"$EMCCD" profile crop default roi --roi 192,192,128x128 2>/dev/null
"$EMCCD" simulate pairs --profile roi --clean "$clean/field1-avg50.png" "$clean/field2-avg50.png" \
    --frames 32 --photons 20 -o pairs >/dev/null 2>&1
inputs=(pairs/noisy/field1-avg50_p20.tif pairs/noisy/field2-avg50_p20.tif)
opts=(--profile roi --method bm3d)
log "reference: one process denoises 64 frames"
"$EMCCD" denoise "${inputs[@]}" "${opts[@]}" -o ref.zarr 2>/dev/null

# --- the job array, one task cancelled mid-way and resubmitted ---
submit() { sbatch --parsable --chdir="$W" --export=ALL,EMCCD="$EMCCD" "$@"; }
wait_job() {
    for _ in $(seq 900); do
        [ -z "$(squeue -h -j "$1" 2>/dev/null)" ] && return 0
        sleep 1
    done
    echo "error: job $1 did not finish" >&2
    return 1
}
done_in() { # markers present among frames [$1, $2)
    local n=0 k
    for ((k = $1; k < $2; k++)); do [ -e "array.zarr/0/.emccd-done/$k" ] && n=$((n + 1)); done
    echo $n
}
job=$(submit --array=0-3 "$SBATCH_SCRIPT" 4 array.zarr "${inputs[@]}" "${opts[@]}")
log "submitted array job $job (4 tasks, shards of 16 frames)"
for _ in $(seq 600); do
    n=$(done_in 16 32)
    [ "$n" -ge 2 ] && break
    sleep 0.2
done
scancel "${job}_1"
log "cancelled task ${job}_1 with $n of its 16 frames complete"
wait_job "$job"
left=$(done_in 16 32)
[ "$left" -lt 16 ] || { echo "error: task 1 finished before it was cancelled; nothing was tested" >&2; exit 1; }
total=$(done_in 0 64)
log "array finished: $total of 64 frames complete; resubmitting task 1"
job2=$(submit --array=1 "$SBATCH_SCRIPT" 4 array.zarr "${inputs[@]}" "${opts[@]}")
wait_job "$job2"
line=$(grep -h "shard 1/4" "emccd-denoise-${job2}_1.log" || true)
echo "    $line"
# The resubmitted task must have denoised exactly the frames the cancelled one left.
echo "$line" | grep -q "frames 17–32 ($((16 - left)) denoised now, $left were already done); 64 of 64 frames" \
    || { echo "error: the resubmitted task did not resume where the cancelled one stopped ($left of 16 done)" >&2; exit 1; }

# --- the merged store equals the single-process one ---
[ "$(done_in 0 64)" = 64 ] || { echo "error: $(done_in 0 64) of 64 frames complete after the resubmission" >&2; exit 1; }
diff -r ref.zarr/0/c array.zarr/0/c >/dev/null || { echo "error: the array's chunks differ from the single-process run" >&2; exit 1; }
cmp -s ref.zarr/0/zarr.json array.zarr/0/zarr.json || { echo "error: array metadata differs" >&2; exit 1; }
if python3 -c "import zarr, numpy" 2>/dev/null; then
    python3 - <<'PY'
import numpy as np, zarr
a = zarr.open_group("array.zarr", mode="r")["0"][:]
r = zarr.open_group("ref.zarr", mode="r")["0"][:]
assert a.shape == (64, 128, 128) and np.isfinite(a).all() and np.array_equal(a, r), "zarr-python reads different data"
print("[local-cluster] zarr-python reads both stores identically:", a.shape, a.dtype)
PY
fi
log "PASSED: the 4-task array with a cancelled and resubmitted task equals one process bit for bit"
