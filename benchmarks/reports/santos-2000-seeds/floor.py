"""The floor of Santos §7's one-step MSE on this report's cart-pole data: the true physics through each model's own
discretisation, scored as ``encons.evaluators.santos`` scores the models.

    python benchmarks/reports/santos-2000-seeds/floor.py [CACHE]

The §7 metrics roll out by the training integrator, as the paper tests, so the true field's floor differs by
model: NODE and L-NODE step by RK4 or the explicit midpoint rule, SyMo and E2E-SyMo solve the midpoint DEL
equations (eqs. (12)–(15)) by Newton. This script scores, on the train and test trajectories the profile's
cart-pole at N_train = 8 draws (``CACHE``: the benchmark's ``cache_dir``, where they are kept; default: a fresh
folder, which simulates them again, the same draws), the one-step configuration MSE of

- the midpoint DEL with the system's true M(q) and V(q) in place of the networks (a SyMo model whose ``mass``
  and ``potential`` are the true ones, in float64), at §7's evaluation tolerance (RMS residual 1e-4, here with
  up to 50 iterations) and at 1e-10;
- the true vector field stepped by RK4 and by the explicit midpoint rule (what NODE/L-NODE-RK4 and -midpoint
  would score with the true dynamics),

and writes ``floor.json`` beside this script.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import torch
from torch import Tensor, nn

from encons.entry import api
from encons.entry.api import build
from encons.evaluators.santos import one_step_windows, q_angles
from encons.numerics import metrics
from encons.numerics.evaluation import TrueField
from encons.numerics.integrators import rollout

# the profile's cart-pole cell at N_train = 8 (conf/profile/santos.yaml; the model is set per floor)
SANTOS = [
    "experiment=symo_paper",
    "system=cartpole",
    "optimizer.lr=1e-3",
    "model.hidden=256",
    "data.n_train=8",
    "data.batch_size=1",
    "logger=none",
]


class TrueMass(nn.Module):
    """The system's M(q) with the ``CholeskyMass`` methods the DEL equations call."""

    def __init__(self, system):
        super().__init__()
        self.system = system

    def cholesky(self, q: Tensor) -> Tensor:
        return torch.linalg.cholesky(self.system.mass_matrix(q))

    def forward(self, q: Tensor) -> Tensor:
        return self.system.mass_matrix(q)

    def solve(self, q: Tensor, p: Tensor) -> Tensor:
        return torch.linalg.solve(self.system.mass_matrix(q), p.unsqueeze(-1)).squeeze(-1)


class TruePotential(nn.Module):
    """The system's V(q) as the ``Potential`` network's call."""

    def __init__(self, system):
        super().__init__()
        self.system = system

    def forward(self, q: Tensor) -> Tensor:
        return self.system.potential(q)


def setup(cache: str, *overrides: str):
    cfg = api.compose(*SANTOS, *overrides, output_dir=tempfile.mkdtemp(), cache_dir=cache)
    data, module = build(cfg)
    data.prepare_data()
    data.setup("test")
    return data, module


def one_step_mse(module, model, arrays: dict[str, Tensor]) -> float:
    """``SantosMetrics.one_step_mse`` of ``model`` in float64 by ``module``'s integrator."""
    states, u, history, n = arrays["states"], arrays.get("u"), model.history, model.n
    windows = one_step_windows(states, history).double()
    inputs = None if u is None else one_step_windows(u, history).double()
    start = windows[:, 0] if history == 1 else windows[:, :history]
    t = torch.arange(windows.shape[1], dtype=torch.float64) * module.dt
    pred = rollout(model, start, t, module.integrator, inputs)[:, -1, :n]
    return metrics.configuration_mse(pred, windows[:, -1, :n], q_angles(module)).item()


def main() -> None:
    torch.set_num_threads(1)
    cache = sys.argv[1] if len(sys.argv) > 1 else tempfile.mkdtemp()
    out: dict = {"what": __doc__.split("\n")[0], "one_step_mse": {}}
    data, module = setup(cache, "model=e2e_symo")
    model = module.model.double().eval()
    model.mass, model.potential = TrueMass(module.system), TruePotential(module.system)
    model.input_matrix = model.input_matrix.double()
    for split in ("train", "test"):
        for tol in (1e-4, 1e-10):
            model.eval_tol, model.eval_iters = tol, 50
            model.reset_diagnostics()
            key = f"midpoint DEL, true M and V, Newton tol {tol:g}"
            value = one_step_mse(module, model, data.arrays[split])
            out["one_step_mse"].setdefault(key, {})[split] = value
            out["one_step_mse"][key][f"{split}_newton_unconverged"] = model.diagnostics()["newton_unconverged"]
    for integrator in ("rk4", "midpoint"):
        data, module = setup(cache, "model=lnode", f"integrator={integrator}")
        true = TrueField(module.system, module.model.chart).double()
        key = f"true field by {integrator}"
        out["one_step_mse"][key] = {split: one_step_mse(module, true, data.arrays[split]) for split in ("train", "test")}
    for key, values in out["one_step_mse"].items():
        print(f"{key}: " + ", ".join(f"{k} {v:.3g}" for k, v in values.items()))
    Path(__file__).with_name("floor.json").write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
