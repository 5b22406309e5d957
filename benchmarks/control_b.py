"""Why the learned cart-pole gets the input's effect wrong: b_rel_err of one trained run per setting.

    python benchmarks/control_b.py OUT.jsonl [name=overrides ...]

Each argument ``name=o1;o2;...`` trains ``model=lnode system=cartpole`` (plus the overrides, separated by ";")
and appends one JSON line: the relative errors of the linearisation at upright (A, B: the LQR's model,
``encons.tools.control.linearise``) of the trained model and of its initialisation, ∂θ̈/∂u at upright, the
training wall time and the closed-loop success rate on 40 seeded starts (``encons.tools.control.compare``).
"""

from __future__ import annotations

import copy
import json
import sys
import tempfile
import time
from pathlib import Path

import torch

from encons.entry import api
from encons.tools import control


def linear_errors(model, system) -> dict[str, float]:
    plant, truth = control.learned_plant(model, system, "model"), control.true_plant(system)
    (a, b), (ta, tb) = control.linearise(plant, 1), control.linearise(truth, 1)
    return {
        "a_rel_err": float(torch.linalg.norm(a - ta) / torch.linalg.norm(ta)),
        "b_rel_err": float(torch.linalg.norm(b - tb) / torch.linalg.norm(tb)),
        "dthetadd_du": float(b[-1, 0]),
        "dthetadd_du_true": float(tb[-1, 0]),
    }


def main() -> None:
    out = Path(sys.argv[1])
    for spec in sys.argv[2:]:
        name, _, overrides = spec.partition("=")
        extra = [o for o in overrides.split(";") if o]
        with tempfile.TemporaryDirectory() as tmp:
            cfg = api.compose(
                "logger=none",
                "trainer.enable_progress_bar=false",
                "~evaluators/santos",
                "model=lnode",
                "system=cartpole",
                "data.n_test=16",
                *extra,
                output_dir=Path(tmp) / "run",
                cache_dir=Path(tmp) / "cache",
            )
            from encons.entry.api import build

            _, module = build(cfg)
            init_model, system = copy.deepcopy(module.model), module.system
            started = time.perf_counter()
            run = api.train(cfg, summary=False)
            wall = time.perf_counter() - started
            row = {
                "name": name,
                "overrides": extra,
                "train_wall_s": round(wall, 1),
                **{f"init_{k}": v for k, v in linear_errors(init_model, system).items()},
                **linear_errors(run.model, system),
            }
            row["control_success"] = control.compare(run, starts=40, seed=0).metrics["control/success_rate"]
        print(json.dumps(row), flush=True)
        with out.open("a") as f:
            f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
