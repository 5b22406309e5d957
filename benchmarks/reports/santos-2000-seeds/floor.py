"""The floor of Santos §7's one-step MSE on this report's cart-pole data: the true physics through each model's own
discretisation, scored as ``encons.evaluators.santos`` scores the models.

    PYTHONPATH=. python benchmarks/reports/santos-2000-seeds/floor.py [CACHE]

The §7 metrics roll out by the training integrator, as the paper tests, so the true field's floor differs by
model: NODE and L-NODE step by RK4 or the explicit midpoint rule, SyMo and E2E-SyMo solve the midpoint DEL
equations (eqs. (12)–(15)) by Newton. This script scores, on the train and test trajectories the profile's
cart-pole at N_train = 8 draws (``CACHE``: the benchmark's ``cache_dir``, where they are kept; default: a fresh
folder, which simulates them again, the same draws), the one-step configuration MSE of

- the midpoint DEL with the system's true M(q) and V(q) in place of the networks (E2E-SyMo's
  ``true_counterpart``, in float64), at §7's evaluation tolerance (RMS residual 1e-4, here with up to 50
  iterations) and at 1e-10;
- the true vector field stepped by RK4 and by the explicit midpoint rule (what NODE/L-NODE-RK4 and -midpoint
  would score with the true dynamics),

and writes ``floor.json`` beside this script. Runs report the test floors themselves now (``mse_test_floor``,
``encons.evaluators.santos``); this script also gives the train split and both tolerances.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import torch

from benchmarks.ensemble_speed import SANTOS  # the profile's cart-pole cell at N_train = 8
from encons.entry import api
from encons.entry.api import build
from encons.evaluators.santos import SantosMetrics


def setup(cache: str, *overrides: str):
    cfg = api.compose(*SANTOS, "logger=none", *overrides, output_dir=tempfile.mkdtemp(), cache_dir=cache)
    data, module = build(cfg)
    data.prepare_data()
    data.setup("test")
    return data, module


def main() -> None:
    torch.set_num_threads(1)
    cache = sys.argv[1] if len(sys.argv) > 1 else tempfile.mkdtemp()
    out: dict = {"what": __doc__.split("\n")[0], "one_step_mse": {}}
    data, module = setup(cache, "model=e2e_symo")
    model = module.model.true_counterpart(module.system).double().eval()
    for split in ("train", "test"):
        for tol in (1e-4, 1e-10):
            model.eval_tol, model.eval_iters = tol, 50
            model.reset_diagnostics()
            key = f"midpoint DEL, true M and V, Newton tol {tol:g}"
            value = SantosMetrics.one_step_mse(module, data.arrays[split], model)
            out["one_step_mse"].setdefault(key, {})[split] = value
            out["one_step_mse"][key][f"{split}_newton_unconverged"] = model.diagnostics()["newton_unconverged"]
    for integrator in ("rk4", "midpoint"):
        data, module = setup(cache, "model=lnode", f"integrator={integrator}")
        true = module.model.true_counterpart(module.system).double()
        key = f"true field by {integrator}"
        out["one_step_mse"][key] = {
            split: SantosMetrics.one_step_mse(module, data.arrays[split], true) for split in ("train", "test")
        }
    for key, values in out["one_step_mse"].items():
        print(f"{key}: " + ", ".join(f"{k} {v:.3g}" for k, v in values.items()))
    Path(__file__).with_name("floor.json").write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
