#!/usr/bin/env bash
# make test-cluster: the workflow on a real one-node SLURM on this machine.
#
# Brings up munge, slurmctld and slurmd (Debian's packages, installed when
# missing; daemons started directly, no systemd), runs a trimmed small config
# (tests/cluster/config.yaml on top of config/test.yaml) once locally and once
# through `--workflow-profile profiles/slurm`, then checks with
# check_cluster_run.py that every job Snakemake sent to the cluster went
# through sbatch (SLURM's job completion log and squeue) and that the tables
# equal the local run's. The daemons it started are stopped on any exit.
#
# Needs root: it installs packages, writes /etc/slurm/slurm.conf (restored
# afterwards) and starts the daemons. Refuses to run beside a running SLURM.
#
# Environment: SNAKEMAKE (default: snakemake on PATH), SHAPE_MODEL_FILE (a local
# copy of the shape model, passed as shape_model_path), CLUSTER_TEST_DIR (the
# temporary folder; default: a new one under /tmp, removed after a pass, kept
# after a failure), CLUSTER_TEST_CORES (cores of the local run, default 2).
set -euo pipefail

cd "$(dirname "${BASH_SOURCE[0]}")/../.."
REPO=$PWD
HERE=$REPO/tests/cluster
SNAKEMAKE=${SNAKEMAKE:-snakemake}
PYTHON=$(command -v python3)
if [[ -x "$(dirname "$(command -v "$SNAKEMAKE")")/python" ]]; then
    PYTHON=$(dirname "$(command -v "$SNAKEMAKE")")/python
fi
PARTITION=ci
SLURM_CONF=/etc/slurm/slurm.conf
PACKAGES=(munge slurmctld slurmd slurm-client slurm-wlm-basic-plugins)

say() { printf '\n==> %s\n' "$*"; }
fail() { echo "test-cluster: error: $*" >&2; exit 1; }
# Whether a process of that name runs (no pgrep: procps is not in a minimal Debian).
running() { grep -sqx "$1" /proc/[0-9]*/comm; }

if [[ $(id -u) != 0 ]]; then
    fail "needs root (installs ${PACKAGES[*]}, writes $SLURM_CONF, starts the SLURM daemons)"
fi
for daemon in slurmctld slurmd; do
    if running "$daemon"; then
        fail "$daemon is already running on this machine; this test brings up its own one-node SLURM"
    fi
done

missing=()
for package in "${PACKAGES[@]}"; do
    dpkg -s "$package" >/dev/null 2>&1 || missing+=("$package")
done
if ((${#missing[@]})); then
    say "Installing ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update
    apt-get install -y --no-install-recommends "${missing[@]}"
fi

WORK=${CLUSTER_TEST_DIR:-$(mktemp -d /tmp/asteroid-cluster-test.XXXXXX)}
mkdir -p "$WORK"
WORK=$(cd "$WORK" && pwd)
STATE=$WORK/slurm
rm -rf "$STATE"
mkdir -p "$STATE/slurmctld" "$STATE/slurmd"
started_munge=false
conf_backup=""
passed=false

stop_daemon() {  # name, pid file
    local pid
    [[ -s $2 ]] || return 0
    pid=$(cat "$2")
    kill "$pid" 2>/dev/null || return 0
    for _ in $(seq 50); do
        kill -0 "$pid" 2>/dev/null || return 0
        sleep 0.2
    done
    echo "$1 (pid $pid) did not stop in 10 s; killing it" >&2
    kill -9 "$pid" 2>/dev/null || true
}

cleanup() {
    local status=$?
    set +e
    say "Stopping SLURM"
    if [[ -s $STATE/slurmctld.pid ]]; then
        scancel --partition="$PARTITION" 2>/dev/null
        sleep 1
    fi
    stop_daemon slurmd "$STATE/slurmd.pid"
    stop_daemon slurmctld "$STATE/slurmctld.pid"
    if $started_munge; then
        /etc/init.d/munge stop >/dev/null
    fi
    if [[ -n $conf_backup ]]; then
        mv -f "$conf_backup" "$SLURM_CONF"
    else
        rm -f "$SLURM_CONF"
    fi
    if $passed && [[ -z ${CLUSTER_TEST_DIR:-} ]]; then
        rm -rf "$WORK"
    elif ! $passed; then
        echo "test-cluster: FAILED (exit $status); logs and both runs kept in $WORK" >&2
        for log in "$STATE/slurmctld.log" "$STATE/slurmd.log"; do
            [[ -s $log ]] && { echo "--- last lines of $log" >&2; tail -n 20 "$log" >&2; }
        done
    fi
    exit "$status"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

say "Configuring a one-node SLURM in $STATE"
cpus=$(nproc)
# Below what slurmd detects, or the node is drained for having less memory
# than configured.
memory=$(slurmd -C | sed -n 's/.*RealMemory=\([0-9]*\).*/\1/p')
memory=$((memory * 9 / 10))
if [[ -e $SLURM_CONF ]]; then
    conf_backup=$WORK/slurm.conf.before-test
    cp -p "$SLURM_CONF" "$conf_backup"
fi
mkdir -p "$(dirname "$SLURM_CONF")"
sed -e "s|@STATE_DIR@|$STATE|g" -e "s|@CPUS@|$cpus|g" -e "s|@MEMORY_MB@|$memory|g" \
    -e "s|@PARTITION@|$PARTITION|g" "$HERE/slurm.conf.in" >"$SLURM_CONF"
echo "node: $cpus CPUs, $memory MB; partition $PARTITION"

if ! running munged; then
    # munged refuses a key directory or key that others can read.
    [[ -s /etc/munge/munge.key ]] || mungekey --create --keyfile /etc/munge/munge.key
    chown -R munge:munge /etc/munge
    chmod 0700 /etc/munge
    chmod 0400 /etc/munge/munge.key
    /etc/init.d/munge start
    started_munge=true
fi
munge -n | unmunge >/dev/null || fail "munge does not work (munge -n | unmunge)"

slurmctld
slurmd -N localhost
say "Waiting for the node"
for _ in $(seq 60); do
    state=$(sinfo --noheader --partition="$PARTITION" --format=%T 2>/dev/null || true)
    [[ $state == idle ]] && break
    sleep 1
done
sinfo --partition="$PARTITION"
[[ $state == idle ]] || fail "node not idle after 60 s (state: '${state:-none}')"

# The run's configuration: the small config trimmed (tests/cluster/config.yaml).
config_args=(--configfile "$REPO/config/test.yaml" "$HERE/config.yaml")
if [[ -n ${SHAPE_MODEL_FILE:-} ]]; then
    config_args+=(--config "shape_model_path=$(realpath "$SHAPE_MODEL_FILE")")
fi

say "Local run (the reference)"
start=$SECONDS
"$SNAKEMAKE" --cores "${CLUSTER_TEST_CORES:-2}" -d "$WORK/local" "${config_args[@]}" >"$WORK/local.log" 2>&1 \
    || { tail -n 40 "$WORK/local.log"; fail "the local run failed (log: $WORK/local.log)"; }
echo "local run: $((SECONDS - start)) s"

# The partition reaches sbatch only through the profile, which reads it from
# the environment; status from squeue (there is no accounting database for
# sacct); the first status check after 5 s rather than 40 (one machine).
cluster_args=(--workflow-profile "$REPO/profiles/slurm" -d "$WORK/cluster" "${config_args[@]}"
    --slurm-status-command squeue --slurm-init-seconds-before-status-checks 5)
say "The cluster run's plan"
SBATCH_PARTITION=$PARTITION "$SNAKEMAKE" --dry-run "${cluster_args[@]}" >"$WORK/cluster-dry-run.log" 2>&1 \
    || { tail -n 40 "$WORK/cluster-dry-run.log"; fail "the cluster dry run failed"; }

say "Cluster run (--workflow-profile profiles/slurm)"
start=$SECONDS
SBATCH_PARTITION=$PARTITION "$SNAKEMAKE" "${cluster_args[@]}" >"$WORK/cluster.log" 2>&1 \
    || { tail -n 60 "$WORK/cluster.log"; fail "the cluster run failed (log: $WORK/cluster.log)"; }
echo "cluster run: $((SECONDS - start)) s"

say "Checking SLURM's record and the tables"
squeue --states=all --noheader --partition="$PARTITION" --format='%i|%j|%T|%k' >"$WORK/squeue.txt"
"$PYTHON" "$HERE/check_cluster_run.py" --dry-run-log "$WORK/cluster-dry-run.log" --cluster-log "$WORK/cluster.log" \
    --jobcomp "$STATE/jobcomp.log" --squeue "$WORK/squeue.txt" --partition "$PARTITION" \
    --profile "$REPO/profiles/slurm/config.v8+.yaml" \
    --local "$WORK/local" --cluster "$WORK/cluster"
passed=true
say "test-cluster passed in $SECONDS s"
