#!/usr/bin/env bash
# The workflow on a real Slurm cluster, as a user runs it: snakemake --profile profiles/slurm.
#
# As root on Debian: installs slurm-wlm and munge when absent (apt) and the executor plugin
# (pip install -e ".[slurm]", the project's own extra), starts a single-node cluster on 127.0.0.1
# (munged, slurmctld, slurmd from tests/slurm/slurm.conf.in: no cgroups, no accounting), then
#   1. runs the small configuration (tests/test_workflow.py's SMALL; the geometric variant's outputs
#      up to its libraries, see TARGETS) locally, as the reference;
#   2. runs the same targets under --profile profiles/slurm, cancels one solve_chunk job while it
#      runs (scancel: what a preemption, an admin or a dying node does to a job), and checks that
#      Snakemake resubmitted it as a new Slurm job with twice the memory and time (retries and
#      `attempt` in the profile), that the run completed, and that every result file equals the
#      local run's byte for byte (tests/workflow_helpers.py says why that is the right "equal");
#   3. stops the daemons it started, by PID, and removes the configuration it wrote.
# Prints both wall times and the Slurm job list. Exit 0 on success.
#
# Slurm's client commands inside a job (srun) read /etc/slurm/slurm.conf: the executor's job step
# drops SLURM_CONF from the environment, so the test writes the default location and refuses to
# run on a machine that already has one (a real cluster's). Run it with the project's Python
# environment active, one at a time (fixed ports 16817-16818). Options (environment): SLURM_TEST_DIR
# (work folder, default a new /tmp one; kept on failure), SLURM_TEST_KEEP=1 (keep it on success too).
set -euo pipefail

HERE="$(cd "$(dirname "$0")" && pwd)"
ROOT="$(cd "$HERE/../.." && pwd)"
CONF=/etc/slurm/slurm.conf
MARKER="written by tests/slurm/run_slurm_test.sh (hybridtwin)"
INJECT_COMMENT=rule_solve_chunk_wildcards_geometric_000   # the job cancelled on its first attempt
# the small configuration's whole default pipeline (offline.scope: run): the measured runs, each variant's
# scenarios in zarr chunks, POD, a sPGD library per run, the fits per run and joint on the libraries with the
# polish on the full solver, the diagnosis, the reports and the ledger (issue 50, item 5): the ledger and every
# other result must equal the local run's byte for byte
TARGETS=(results/ledger.tsv results/summary.tsv results/geometric/diagnosis.tsv)

say() { printf '[slurm-test] %s\n' "$*"; }
die() { say "FAILED: $*"; exit 1; }

[[ $(id -u) -eq 0 ]] || die "needs root (it installs packages and starts slurmctld/slurmd)"
command -v python >/dev/null || die "no python on PATH: activate the project's environment"

# --- 1. packages --------------------------------------------------------------------------------
if ! command -v slurmctld >/dev/null || ! command -v slurmd >/dev/null || ! command -v sbatch >/dev/null \
        || ! command -v munged >/dev/null; then
    command -v apt-get >/dev/null || die "slurm-wlm/munge missing and no apt-get to install them"
    say "installing slurm-wlm and munge (apt)"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq >/dev/null
    apt-get install -y -qq --no-install-recommends slurm-wlm munge >/dev/null
fi
if ! python -c "import snakemake_executor_plugin_slurm" 2>/dev/null; then
    say "installing the Slurm executor plugin: pip install -e \".[slurm]\""
    python -m pip install -q -e "$ROOT[slurm]"
fi

# --- 2. the cluster -----------------------------------------------------------------------------
if [[ -e $CONF ]] && ! grep -q "$MARKER" "$CONF"; then
    die "$CONF exists and is not this test's: not touching a real cluster's configuration"
fi
WORK="${SLURM_TEST_DIR:-$(mktemp -d /tmp/hybridtwin-slurm.XXXXXX)}"
mkdir -p "$WORK"
STATE="$WORK/state"
rm -rf "$STATE" "$WORK/local" "$WORK/cluster"
mkdir -p "$STATE/slurmctld" "$STATE/slurmd"
chmod 755 "$WORK" "$STATE"
PIDS=()
SMK_PID=""
WROTE_CONF=""
OK=""

cleanup() {
    set +e
    if [[ -n $SMK_PID ]] && kill -0 "$SMK_PID" 2>/dev/null; then
        kill -TERM "$SMK_PID"; wait "$SMK_PID"   # Snakemake cancels its Slurm jobs on SIGTERM
    fi
    if [[ ${#PIDS[@]} -gt 0 ]]; then
        squeue -h --format=%i 2>/dev/null | xargs -r scancel 2>/dev/null   # the test's own cluster only
        for ((i = ${#PIDS[@]} - 1; i >= 0; i--)); do
            kill -TERM "${PIDS[i]}" 2>/dev/null && wait "${PIDS[i]}" 2>/dev/null
        done
        say "stopped the daemons it started (PIDs ${PIDS[*]})"
    fi
    [[ -n $WROTE_CONF ]] && rm -f "$CONF"
    if [[ -n $OK && -z ${SLURM_TEST_KEEP:-} && -z ${SLURM_TEST_DIR:-} ]]; then
        rm -rf "$WORK"
    else
        say "work folder kept: $WORK (logs: $WORK/*.log, $STATE/*.log)"
    fi
}
trap cleanup EXIT
trap 'exit 130' INT TERM   # a signal exits through cleanup too

CPUS=$(nproc)
MEMORY_MB=$(awk '/MemTotal/ {m = int($2 / 1024 * 0.75); print (m > 16000 ? 16000 : m)}' /proc/meminfo)
((MEMORY_MB >= 8000)) || die "needs 8 GB for the node (the profile asks up to 4 GB per job, 2 at a time)"
sed -e "s|@STATE@|$STATE|g" -e "s|@CTLD_PORT@|16817|" -e "s|@SLURMD_PORT@|16818|" \
    -e "s|@CPUS@|$CPUS|" -e "s|@MEMORY_MB@|$MEMORY_MB|" "$HERE/slurm.conf.in" > "$STATE/slurm.conf"
mkdir -p "$(dirname "$CONF")"
cp "$STATE/slurm.conf" "$CONF"
WROTE_CONF=1

if command -v mungekey >/dev/null; then
    mungekey --create --keyfile="$STATE/munge.key"
else
    dd if=/dev/urandom of="$STATE/munge.key" bs=1 count=1024 status=none
fi
chmod 600 "$STATE/munge.key"
munged --foreground --force --socket="$STATE/munge.socket" --key-file="$STATE/munge.key" \
    --pid-file="$STATE/munged.pid" --seed-file="$STATE/munged.seed" --log-file="$STATE/munged.log" \
    > "$STATE/munged.out" 2>&1 &
PIDS+=($!)
for _ in $(seq 50); do [[ -S $STATE/munge.socket ]] && break; sleep 0.1; done
[[ -S $STATE/munge.socket ]] || die "munged did not start: $(cat "$STATE/munged.out")"
slurmctld -D -i > "$STATE/slurmctld.out" 2>&1 &
PIDS+=($!)
slurmd -D -N localhost > "$STATE/slurmd.out" 2>&1 &
PIDS+=($!)
for _ in $(seq 60); do
    [[ $(sinfo -h -o %t 2>/dev/null) == idle ]] && break
    sleep 0.5
done
[[ $(sinfo -h -o %t 2>/dev/null) == idle ]] || die "the node did not come up: $(tail -5 "$STATE/slurmctld.log" "$STATE/slurmd.log")"
say "cluster up: munged, slurmctld, slurmd (PIDs ${PIDS[*]}); node localhost, $CPUS CPUs, $MEMORY_MB MB"

# --- 3. the local reference ---------------------------------------------------------------------
now() { date +%s.%N; }
python "$ROOT/tests/workflow_helpers.py" copy "$WORK/local"
python "$ROOT/tests/workflow_helpers.py" copy "$WORK/cluster"
start=$(now)
(cd "$WORK/local" && python -m snakemake --cores 2 "${TARGETS[@]}") > "$WORK/local.log" 2>&1 \
    || die "local run failed: $(tail -20 "$WORK/local.log")"
LOCAL_S=$(python -c "print(f'{$(now) - $start:.0f}')")
say "local run (--cores 2): ${LOCAL_S} s"

# --- 4. the cluster run, one job cancelled mid-way ------------------------------------------------
start=$(now)
(cd "$WORK/cluster" && exec python -m snakemake --profile profiles/slurm \
    --slurm-init-seconds-before-status-checks 1 "${TARGETS[@]}") > "$WORK/cluster.log" 2>&1 &
SMK_PID=$!
CANCELLED=""
while kill -0 "$SMK_PID" 2>/dev/null; do
    CANCELLED=$(squeue -h --states=RUNNING --format='%i|%k' | awk -F'|' -v c="$INJECT_COMMENT" '$2 == c {print $1; exit}')
    if [[ -n $CANCELLED ]]; then
        sleep 1   # well inside the job (start-up and solve take several seconds)
        scancel "$CANCELLED"
        say "cancelled Slurm job $CANCELLED ($INJECT_COMMENT) while it ran"
        break
    fi
    sleep 0.2
done
status=0
wait "$SMK_PID" || status=$?
SMK_PID=""
CLUSTER_S=$(python -c "print(f'{$(now) - $start:.0f}')")
((status == 0)) || die "the run under --profile profiles/slurm failed (exit $status): $(tail -30 "$WORK/cluster.log")"
[[ -n $CANCELLED ]] || die "no running $INJECT_COMMENT job was seen: nothing was cancelled"
say "cluster run (--profile profiles/slurm): ${CLUSTER_S} s, exit 0"

# --- 5. checks ----------------------------------------------------------------------------------
JOBS=$(squeue -h --states=all --sort=i --format='%i|%T|%m|%l|%k')
say "Slurm job list (id|state|memory|time limit|rule and wildcards):"
printf '    %s\n' $JOBS
first=$(awk -F'|' -v id="$CANCELLED" '$1 == id' <<< "$JOBS")
again=$(awk -F'|' -v id="$CANCELLED" -v c="$INJECT_COMMENT" '$1 > id && $5 == c' <<< "$JOBS")
[[ $first == "$CANCELLED|CANCELLED|2000M|2:00:00|$INJECT_COMMENT" ]] \
    || die "the cancelled job is listed as '$first', expected CANCELLED with 2000M and 2:00:00 (attempt 1)"
[[ $again =~ ^[0-9]+\|COMPLETED\|4000M\|4:00:00\|$INJECT_COMMENT$ ]] \
    || die "no resubmission of $INJECT_COMMENT completed with 4000M and 4:00:00 (attempt 2): '$again'"
others=$(awk -F'|' -v id="$CANCELLED" '$1 != id && $2 != "COMPLETED"' <<< "$JOBS")
[[ -z $others ]] || die "other jobs did not complete: $others"
grep -q "Trying to restart job" "$WORK/cluster.log" || die "Snakemake's log does not show the restart"
grep -q "CANCELLED" "$WORK/cluster/.snakemake/slurm_logs/rule_solve_chunk/geometric_000/$CANCELLED.log" \
    || die "the cancelled job's Slurm log does not say it was cancelled"
say "resubmitted: Slurm job $CANCELLED (attempt 1) cancelled, job ${again%%|*} (attempt 2, twice the memory and time) completed"
python "$ROOT/tests/workflow_helpers.py" compare "$WORK/local" "$WORK/cluster" \
    || die "the cluster's results differ from the local run's"
say "PASSED: local ${LOCAL_S} s, cluster ${CLUSTER_S} s (${#TARGETS[@]} targets of the small configuration)"
OK=1
echo "slurm: 1 passed, 0 failed"
