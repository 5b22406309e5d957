"""The five mass-spring ensembles scored at their last epoch beside the best checkpoint the profile tests.

    python benchmarks/reports/lim_kasim-1000-seeds/last_vs_best.py OUT

OUT: the benchmark's ``out`` folder of this report (``RUN.md``'s command). For each cell's ensemble
``OUT/runs/mass_spring-<cell>-seeds0-1-2`` this runs ``python -m encons.evaluate RUN ckpt=last threads=1`` (every
member's weights at epoch 1000, from the ensemble's ``last.ckpt``; each member's metrics land in its own
``evaluation/test_metrics.json``), then writes ``last_vs_best.json`` beside this script: per cell and member, the
best checkpoint's epoch and its test ``energy_rmse_median`` / ``traj_rel_err`` (the member's ``test_metrics.json``,
what ``results.csv`` holds) and the same at the last epoch, with the cells' order by each.

Lim & Kasim's code (github.com/machine-discovery/research, ``constr/main.py``) keeps both checkpoints,
``ModelCheckpoint(save_last=True, save_top_k=1, monitor='val_loss/original_loss')`` (the derivative loss without
the regulariser, as ``validation.criterion=objective`` here); the paper does not say which one Table 1 scores.
"""

from __future__ import annotations

import json
import os
import re
import statistics
import subprocess
import sys
from pathlib import Path

CELLS = ["node", "node+C_H", "hnn", "lnn", "nsf"]
METRICS = ["energy_rmse_median", "traj_rel_err"]


def main() -> None:
    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    runs = Path(sys.argv[1]) / "runs"
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    result: dict = {"what": __doc__.split("\n")[0], "cells": {}}
    for cell in CELLS:
        ensemble = runs / f"mass_spring-{cell}-seeds0-1-2"
        subprocess.run(
            [sys.executable, "-m", "encons.evaluate", str(ensemble), "ckpt=last", "threads=1"],
            check=True,
            env=env,
            stdout=subprocess.DEVNULL,
        )
        members = []
        for seed in range(3):
            member = runs / f"mass_spring-{cell}-seed{seed}"
            best = json.loads((member / "test_metrics.json").read_text())
            last = json.loads((member / "evaluation" / "test_metrics.json").read_text())
            (checkpoint,) = (member / "checkpoints").glob("best-epoch*.ckpt")
            members.append(
                {
                    "seed": seed,
                    "best_epoch": int(re.search(r"epoch(\d+)", checkpoint.name).group(1)),
                    "best": {m: best[m] for m in METRICS},
                    "last": {m: last[m] for m in METRICS},
                }
            )
        result["cells"][cell] = {
            "members": members,
            **{
                f"{which} {m} mean": statistics.mean(x[which][m] for x in members)
                for which in ("best", "last")
                for m in METRICS
            },
        }
    for which in ("best", "last"):
        key = f"{which} energy_rmse_median mean"
        result[f"order by {key}"] = sorted(CELLS, key=lambda c: result["cells"][c][key])
    out = Path(__file__).with_name("last_vs_best.json")
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps(result, indent=1) + "\n")
    tmp.replace(out)
    print(json.dumps({k: v for k, v in result.items() if k.startswith("order")}, indent=1))


if __name__ == "__main__":
    main()
