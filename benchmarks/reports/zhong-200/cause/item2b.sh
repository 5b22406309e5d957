#!/usr/bin/env bash
# Item 2b of ../cause.md as committed rows: HNN-structure and HNN-structure-angle on the gyroscope (profile=zhong's
# data, every start kept), 150 epochs, seed 0, on encons' data and on the offset data of cause/offset_data.py.
# Usage: bash benchmarks/reports/zhong-200/cause/item2b.sh OUT [CACHE] (OUT outside the work tree; a rerun skips
# finished runs). Then `python -m encons.report OUT/encons` and `OUT/offset`, and copy their summary.csv, summary.md
# and results.csv into cause/item2b/encons/ and cause/item2b/offset/.
set -euo pipefail
OUT=${1:?usage: item2b.sh OUT [CACHE]}
CACHE=${2:-$OUT/cache}
HERE=$(cd "$(dirname "$0")" && pwd)
mkdir -p "$OUT"
python "$HERE/offset_data.py" --system gyroscope --out "$OUT/zhong-offset-gyroscope.npz" --cache "$CACHE"
ONLY='only=[gyroscope/hnn_structure,gyroscope/hnn_structure_angle]'
python -m encons.benchmark profile=zhong 'seeds=[0]' 'n_train=[]' threads=1 'train=["trainer.max_epochs=150"]' \
  "$ONLY" out="$OUT/encons" cache_dir="$CACHE"
python -m encons.benchmark profile=zhong 'seeds=[0]' 'n_train=[]' threads=1 \
  "train=[\"trainer.max_epochs=150\",\"data.path=$OUT/zhong-offset-gyroscope.npz\"]" \
  "$ONLY" out="$OUT/offset" cache_dir="$CACHE"
