"""Cart-pole / pendulum swing-up success per seed of a seed ensemble, per training setting (issue 38).

    python benchmarks/reports/control-c/control_c.py OUT.jsonl RUNS_DIR [name=o1;o2;... ...]

Each argument ``name=o1;o2;...`` trains ``python -m encons.train seeds=[0,1,2] <overrides>`` (``model=lnode
system=cartpole`` unless the overrides name a model / system; overrides separated by ";") as one seed
ensemble (``encons.ensemble``), then scores every member's best checkpoint with ``encons.control.compare``
(runs kept in ``RUNS_DIR/<name>``; 100 starts, seed 0: the starts ``python -m encons.control RUN`` scores) and appends one JSON line per
setting: per seed the success rate, a_rel_err, b_rel_err (the learned linearisation at upright the LQR is
built from), time to upright and effort; their means; the oracle's success rate; the training wall time.
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from pathlib import Path

from encons import api, control

KEYS = ("success_rate", "a_rel_err", "b_rel_err", "time_to_upright_s", "effort")


def main() -> None:
    out, runs = Path(sys.argv[1]), Path(sys.argv[2])
    for spec in sys.argv[3:]:
        name, _, overrides = spec.partition("=")
        extra = [o for o in overrides.split(";") if o]
        defaults = [d for d in ("model=lnode", "system=cartpole") if not any(o.startswith(d.split("=")[0] + "=")
                                                                            for o in extra)]
        cfg = api.compose("logger=none", "trainer.enable_progress_bar=false", "~evaluators/santos",
                          "data.n_test=16", "seeds=[0,1,2]", *defaults, *extra,
                          output_dir=runs / name, cache_dir=runs / "cache")
        started = time.perf_counter()
        ensemble = api.train(cfg, summary=False)
        wall = time.perf_counter() - started
        row = {"name": name, "overrides": [*defaults, *extra], "seeds": ensemble.seeds,
               "epochs": int(cfg.trainer.max_epochs), "n_train": int(cfg.data.n_train),
               "train_wall_s": round(wall, 1), "diverged": {str(k): v for k, v in ensemble.diverged.items()}}
        for seed, member in zip(ensemble.seeds, ensemble.members):
            if member.checkpoint is None:
                continue
            metrics = control.compare(member, starts=100, seed=0).metrics
            row[f"seed{seed}"] = {k: metrics[f"control/{k}"] for k in KEYS}
            row["oracle_success_rate"] = metrics["oracle/success_rate"]
        scored = [row[f"seed{s}"] for s in ensemble.seeds if f"seed{s}" in row]
        for k in ("success_rate", "b_rel_err", "a_rel_err"):
            row[f"mean_{k}"] = statistics.fmean(m[k] for m in scored) if scored else None
        print(json.dumps(row), flush=True)
        with out.open("a") as f:
            f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
