#!/usr/bin/env bash
# Item 2 of ../cause.md as committed rows: the six forms of the Fig. 2 pairs on the 2-pendulum's offset data
# (cause/offset_data.py), 200 epochs, seed 0, as zhong-200's own runs on encons' data (../README.md's command
# plus data.path). Usage: bash benchmarks/reports/zhong-200/cause/item2.sh OUT [CACHE]
# (OUT outside the work tree; a rerun skips finished runs and resumes an interrupted one). Then
# `python -m encons.report OUT` and copy OUT's summary.csv, summary.md and results.csv into cause/item2/.
set -euo pipefail
OUT=${1:?usage: item2.sh OUT [CACHE]}
CACHE=${2:-$OUT/cache}
HERE=$(cd "$(dirname "$0")" && pwd)
mkdir -p "$OUT"
python "$HERE/offset_data.py" --system pendulum2 --out "$OUT/zhong-offset-pendulum2.npz" --cache "$CACHE"
python -m encons.benchmark profile=zhong 'seeds=[0]' 'n_train=[]' threads=1 \
  "train=[\"trainer.max_epochs=200\",\"data.path=$OUT/zhong-offset-pendulum2.npz\"]" \
  'only=[pendulum2/hnn,pendulum2/hnn_angle,pendulum2/hnn_structure,pendulum2/hnn_structure_angle,pendulum2/lnn_structure,pendulum2/lnn_structure_angle]' \
  out="$OUT" cache_dir="$CACHE"
