#!/usr/bin/env bash
# Runs deploy/slurm/submit and deploy/slurm/study.sbatch — the files themselves, not copies —
# under a real single-node Slurm started for the purpose, on a small study, and checks that
# the merge the array's dependency starts gives what one process running the whole study
# gives, and that the shards' Parquet files read back in pyarrow with the documented
# schema. CI (.ci/run) runs it; by hand:
#
#   deploy/slurm/ci-check.sh [TWINMILL]      # default: $TWINMILL, else target/release/twinmill
#
# Slurm and munge are Debian's `slurm-wlm` and `munge`, installed with apt-get when missing.
# Everything the daemons write (configuration, state, spool, logs, munge's socket and key)
# lives in a temporary folder; the daemons run as the invoking user on ports of their own
# and are stopped on exit, whatever happens. The machine may be a container: no cgroups
# (proctrack/linuxproc, task/none), no systemd.
#
# Exit status: 0 checked; 1 a check failed (Slurm installed but not starting is a failure
# too); 3 a tool is missing and could not be installed — Slurm and munge (apt-get) or
# pyarrow (pip) — so the check was not done (the reason on stderr). .ci/run installs all
# three beforehand and fails on any status but 0.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
top=$(cd "$here/../.." && pwd)
tm=${1:-${TWINMILL:-$top/target/release/twinmill}}
tm=$(cd "$(dirname "$tm")" && pwd)/$(basename "$tm")
[ -x "$tm" ] || { echo "ci-check: no twinmill binary at $tm" >&2; exit 1; }
say() { echo "slurm-check: $*" >&2; }
unavailable() { say "Slurm unavailable: $*"; exit 3; }

# 1. Slurm and munge.
if ! command -v slurmctld >/dev/null || ! command -v slurmd >/dev/null ||
   ! command -v sbatch >/dev/null || ! command -v munged >/dev/null; then
  sudo=""
  [ "$(id -u)" -eq 0 ] || sudo=sudo
  say "installing Debian's slurm-wlm and munge"
  { $sudo apt-get update -qq &&
    $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
      slurm-wlm munge >/dev/null; } || unavailable "apt-get install slurm-wlm munge failed"
fi

# 2. A single-node cluster in a temporary folder.
t=$(mktemp -d "${TMPDIR:-/tmp}/twinmill-slurm.XXXXXX")
pids=()
cleanup() {
  local rc=$?
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  for p in "${pids[@]}"; do
    for _ in $(seq 50); do kill -0 "$p" 2>/dev/null || break; sleep 0.1; done
    kill -9 "$p" 2>/dev/null || true
  done
  if [ "$rc" -ne 0 ] && [ "$rc" -ne 3 ]; then
    for f in "$t"/slurmctld.log "$t"/slurmd.log "$t"/study/*.out; do
      [ -f "$f" ] && { say "--- $f"; tail -n 30 "$f" >&2; }
    done
  fi
  rm -rf "$t"
  exit "$rc"
}
trap cleanup EXIT
trap 'exit 1' INT TERM
mkdir -p "$t/munge" "$t/state" "$t/spool" "$t/study"
chmod 700 "$t/munge"
user=$(id -un)
host=$(hostname -s)
# Ports of this run's own (two CI runs on one machine must not meet).
base=$((20000 + ($$ % 20000) * 2))
ctl_port=$base
d_port=$((base + 1))

# munge: a key of this run's, a daemon on a socket of this run's.
dd if=/dev/urandom of="$t/munge/munge.key" bs=1024 count=1 status=none
chmod 400 "$t/munge/munge.key"
sock="$t/munge/munge.socket"
munged --force --foreground --key-file="$t/munge/munge.key" --socket="$sock" \
  --pid-file="$t/munge/munged.pid" --log-file="$t/munge/munged.log" \
  --seed-file="$t/munge/munged.seed" >"$t/munge/out.log" 2>&1 &
pids+=($!)
for _ in $(seq 50); do [ -S "$sock" ] && break; sleep 0.1; done
[ -S "$sock" ] || { cat "$t/munge/out.log" >&2; say "munged did not start"; exit 1; }

mem=$(awk '/MemTotal/ { print int($2 / 1024 * 0.9) }' /proc/meminfo)
cpus=$(nproc)
cat >"$t/slurm.conf" <<EOF
ClusterName=twinmillci
SlurmctldHost=$host(127.0.0.1)
SlurmUser=$user
SlurmdUser=$user
SlurmctldPort=$ctl_port
SlurmdPort=$d_port
AuthType=auth/munge
AuthInfo=socket=$sock
CredType=cred/munge
StateSaveLocation=$t/state
SlurmdSpoolDir=$t/spool
SlurmctldPidFile=$t/slurmctld.pid
SlurmdPidFile=$t/slurmd.pid
SlurmctldLogFile=$t/slurmctld.log
SlurmdLogFile=$t/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SwitchType=switch/none
MpiDefault=none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
JobCompType=jobcomp/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
ReturnToService=2
MinJobAge=600
NodeName=$host NodeAddr=127.0.0.1 CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=ci Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
export SLURM_CONF="$t/slurm.conf"
slurmctld -D -i -f "$SLURM_CONF" >"$t/slurmctld.out" 2>&1 &
pids+=($!)
slurmd -D -f "$SLURM_CONF" >"$t/slurmd.out" 2>&1 &
pids+=($!)
up=""
for _ in $(seq 150); do
  if sinfo -h -o '%T' 2>/dev/null | grep -Eq '^(idle|mixed|allocated)'; then up=1; break; fi
  sleep 0.2
done
if [ -z "$up" ]; then
  tail -n 20 "$t/slurmctld.log" "$t/slurmd.log" "$t/slurmctld.out" "$t/slurmd.out" >&2 2>/dev/null || true
  say "the node did not come up (sinfo: $(sinfo -h 2>&1 | head -1))"; exit 1
fi
say "single-node Slurm up: $(sinfo -h -o '%P %D %T %c')"

# 3. A CI-sized study: the built-in step scene, coarse, identifying dy_AY over 6 machines.
s="$t/study"
cp "$top/scenes/mdx50-step.ngc" "$s/"
sed -e '/^known = {} /a parameters = ["dy_AY"]' \
    -e 's/^pitch_mm = 0\.1 /pitch_mm = 0.2 /' \
    -e 's/^pitch_mm = 0\.185 /pitch_mm = 0.3 /' "$top/scenes/mdx50-step.toml" >"$s/scene.toml"
grep -q '^parameters = \["dy_AY"\]' "$s/scene.toml" && grep -q '^pitch_mm = 0\.3 ' "$s/scene.toml" ||
  { say "scenes/mdx50-step.toml changed: update the CI study's edits"; exit 1; }
cat >"$s/ci.toml" <<EOF
scene = "scene.toml"
trials = 6
seed = 11
[vary]
scanner_noise_sigma_mm = { uniform = [0.01, 0.03] }
[vary.deviations]
dy_AY = { uniform = [-0.6, -0.4] }
gamma_AY = { normal = [0.0, 1e-4] }
EOF
cd "$s"
"$tm" study plan ci.toml --shards 3 --out ci.manifest.json >/dev/null

# 4. The array and its merge, submitted by the repository's own script, waited for.
export TWINMILL="$tm"
line=$("$here/submit" ci.manifest.json 3 --time=00:10:00)
say "$line"
shards_job=$(printf '%s\n' "$line" | sed -n 's/^shards: job \([0-9]*\) .*/\1/p')
merge_job=$(printf '%s\n' "$line" | sed -n 's/.*merge: job \([0-9]*\) .*/\1/p')
[ -n "$shards_job" ] && [ -n "$merge_job" ] || { say "cannot read the job ids"; exit 1; }
deadline=$((SECONDS + ${TWINMILL_SLURM_TIMEOUT:-300}))
wait_for() {
  while squeue -h -j "$1" 2>/dev/null | grep -q .; do
    [ "$SECONDS" -lt "$deadline" ] || { squeue >&2; say "job $1 still queued after the timeout"; exit 1; }
    sleep 1
  done
}
# Final states, one "JobId State" line per job and array task (MinJobAge keeps them).
states() {
  scontrol -o show job "$1" 2>/dev/null | sed -nE 's/^JobId=([0-9]+) .*JobState=([A-Z_]+) .*/\1 \2/p'
}
wait_for "$shards_job"
tasks=$(states "$shards_job")
say "array tasks: $(printf '%s' "$tasks" | tr '\n' ' ')"
if [ "$(printf '%s\n' "$tasks" | grep -c ' COMPLETED$')" -ne 3 ]; then
  scancel "$merge_job" 2>/dev/null || true
  say "the 3 array tasks did not all complete"; exit 1
fi
wait_for "$merge_job"
merge_state=$(states "$merge_job")
say "merge job: $merge_state"
[ "$merge_state" = "$merge_job COMPLETED" ] || { say "the merge job did not complete"; exit 1; }
for i in 0 1 2; do
  [ -f "shard-0000$i-of-00003.parquet" ] || { say "shard $i's file is missing"; exit 1; }
done
[ -f ci.summary.json ] || { say "the merge job wrote no summary"; exit 1; }

# 5. One process, the whole study: the same summary (the study id, shard count and timings
# aside), and a merge by hand agrees with the merge job's.
mkdir one
"$tm" study plan ci.toml --shards 1 --out one/ci.manifest.json >/dev/null
"$tm" study run one/ci.manifest.json --shard 0 >/dev/null
"$tm" study merge one/ci.manifest.json --out one/summary.json >/dev/null
"$tm" study merge ci.manifest.json --out by-hand.json >/dev/null
cmp -s ci.summary.json by-hand.json || { say "the merge job's summary differs from a merge by hand"; exit 1; }
strip() { grep -Ev '^  "(study|shards|trial_seconds)":' "$1"; }
if ! diff <(strip ci.summary.json) <(strip one/summary.json) >&2; then
  say "3 shards under Slurm and one process disagree"; exit 1
fi
grep -q '"failed": 0,' ci.summary.json || { say "trials failed"; cat ci.summary.json >&2; exit 1; }

# 6. The Parquet files in pyarrow: the documented schema, and the rows of the 3 shards equal
# the one process's (shard and timing aside).
# pyarrow is the one Parquet reader here independent of the arrow crate that wrote them:
# without it the check is not done, which is exit 3 (unavailable), never a pass.
python3 -c 'import pyarrow' 2>/dev/null ||
  python3 -m pip install -q pyarrow >/dev/null 2>&1 ||
  unavailable "no pyarrow, and pip install pyarrow failed: the Parquet files cannot be read in Python"
python3 "$top/tools/parquet_check.py" ci.manifest.json one/ci.manifest.json ||
  { say "the Parquet check failed"; exit 1; }
say "ok: 3 array tasks under Slurm, merged, equal to one process"
