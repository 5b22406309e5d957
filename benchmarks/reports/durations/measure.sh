#!/usr/bin/env bash
# Re-times the commands a new user runs first (README, docs/data.md), one after another, each in a fresh process,
# from the repository root with an empty data cache; writes CSV rows (command, wall_s, load_start, load_end, utc)
# to stdout. Usage: bash benchmarks/reports/durations/measure.sh > new.csv   (PY: the interpreter, default python)
set -euo pipefail
cd "$(dirname "$0")/../../.."
PY=${PY:-python}
export OMP_NUM_THREADS=1 WANDB_MODE=offline WANDB_SILENT=true
export ENCONS_ROOT=$(mktemp -d)
scratch=$(mktemp -d)
load() { cut -d' ' -f1 /proc/loadavg; }
timed() {  # label, then the command
  local label=$1; shift
  local l0 t0 t1
  l0=$(load); t0=$(date +%s.%N)
  "$@" > /dev/null 2>&1
  t1=$(date +%s.%N)
  printf '"%s",%.1f,%s,%s,%s\n' "$label" "$(echo "$t1 - $t0" | bc)" "$l0" "$(load)" "$(date -u '+%F %H:%M')"
}
echo "command,wall_s,load_start,load_end,utc"
timed "python -m encons.train model=hnn_angle system=pendulum1 debug=fast" \
  $PY -m encons.train model=hnn_angle system=pendulum1 debug=fast
run=$(ls -td "$ENCONS_ROOT"/outputs/*/* | head -1)
timed "python -m encons.evaluate RUN (the debug=fast run)" $PY -m encons.evaluate "$run"
timed "python -m encons.benchmark profile=smoke" $PY -m encons.benchmark profile=smoke out="$scratch/smoke"
cp -r examples/results/smoke "$scratch/smoke-copy"
timed "python -m encons.report examples/results/smoke" $PY -m encons.report "$scratch/smoke-copy"
timed "python -m encons.train -m model=node;hnn_angle system=pendulum1 debug=fast" \
  $PY -m encons.train -m model=node,hnn_angle system=pendulum1 debug=fast
timed "python -m encons.data.recording example.npz" $PY -m encons.data.recording "$scratch/example.npz"
timed "the recording's encons.train ... model=glnn (docs/data.md)" $PY -m encons.train system=from_file \
  system.path="$scratch/example.npz" data.recording.angles=true model=glnn model.angular=true data.n_steps=50 \
  data.test_steps=200
timed "python -m encons.train model=hnn_angle system=pendulum2" $PY -m encons.train model=hnn_angle system=pendulum2
timed "python -m encons.train model=chnn system=gyroscope" $PY -m encons.train model=chnn system=gyroscope
timed "python -m encons.train model=node system=pendulum2 'seeds=[0,1,2]'" \
  $PY -m encons.train model=node system=pendulum2 'seeds=[0,1,2]'
timed "python -m encons.train model=node system=pendulum2" $PY -m encons.train model=node system=pendulum2
