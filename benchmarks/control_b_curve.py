"""b_rel_err of the cart-pole's learned linearisation against optimiser steps, per data/model setting.

    python benchmarks/control_b_curve.py OUT.jsonl STEPS [name=o1;o2;... ...]

Each setting is composed like ``python -m encons.train model=lnode system=cartpole <overrides>`` and built
by ``encons.training.build.build`` (the same data, model, objective and optimiser as a run); then the module's own
training loss (``TrainingModule.loss``) is minimised for STEPS optimiser steps over the training windows
(epochs drawn by the data module's sampler, no validation or checkpoints: the last weights). At steps
0, 100, 300, 1000, 3000, ... ≤ STEPS it appends one JSON line per setting with a_rel_err, b_rel_err (the
linearisation at upright that the LQR is built from, ``encons.tools.control.linearise``) and ∂θ̈/∂u at upright,
and the learned M(q) at upright beside the true one; after the last step one more line (``"final": true``)
with the swing-up controller's success rate on 40 seeded starts (``swing_up``).
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import torch

from encons.entry import api
from encons.entry.api import build
from encons.tools import control


def errors(model, system) -> dict[str, float]:
    plant, truth = control.learned_plant(model, system, "model"), control.true_plant(system)
    (a, b), (ta, tb) = control.linearise(plant, system.n_controls), control.linearise(truth, system.n_controls)
    q0 = torch.zeros(1, system.n, dtype=torch.float64)
    return {
        "a_rel_err": float(torch.linalg.norm(a - ta) / torch.linalg.norm(ta)),
        "b_rel_err": float(torch.linalg.norm(b - tb) / torch.linalg.norm(tb)),
        "dthetadd_du": float(b[-1, 0]),
        "dthetadd_du_true": float(tb[-1, 0]),
        "mass_upright": plant.mass(q0)[0].tolist(),
        "mass_upright_true": truth.mass(q0)[0].tolist(),
    }


def swing_up(model, system, h: float, starts: int = 40) -> dict[str, float]:
    """The swing-up controller built from ``model`` on the true system: ``encons.tools.control.score`` of its closed
    loop from ``starts`` seeded (0) starts of the system's declared ``controller``, as ``encons.tools.control.compare``
    runs it."""
    settings = control.controller_settings(system)
    plant = control.learned_plant(model, system, "model")
    states, inputs = control.closed_loop(
        system, control.SwingUp(plant, system, h), settings.starts(starts, 0), h, round(settings.duration / h)
    )
    return control.score(control.true_plant(system), states, inputs, settings, h)[0]


def main() -> None:
    out, total = Path(sys.argv[1]), int(sys.argv[2])
    marks = sorted({0, total} | {m for m in (100, 300, 1000, 3000, 10000, 30000) if m <= total})
    for spec in sys.argv[3:]:
        name, _, overrides = spec.partition("=")
        extra = [o for o in overrides.split(";") if o]
        with tempfile.TemporaryDirectory() as tmp:
            cfg = api.compose(
                "logger=none",
                "model=lnode",
                "system=cartpole",
                *extra,
                output_dir=Path(tmp) / "run",
                cache_dir=Path(tmp) / "cache",
            )
            data, module = build(cfg)
            torch.manual_seed(int(cfg.seed))
            optimizer = module.optimizer(module.parameters())
            loader, started = data.train_dataloader(), time.perf_counter()

            def batches():
                for epoch in range(10**9):
                    loader.sampler.set_epoch(epoch)
                    for batch in loader:
                        yield epoch, batch

            stream, epoch = batches(), 0
            for step in range(total + 1):
                if step in marks:
                    row = {
                        "name": name,
                        "overrides": extra,
                        "step": step,
                        "epoch": epoch,
                        "wall_s": round(time.perf_counter() - started, 1),
                        **errors(module.model, module.system),
                    }
                    print(json.dumps(row), flush=True)
                    with out.open("a") as f:
                        f.write(json.dumps(row) + "\n")
                if step == total:
                    row["control"] = swing_up(module.model, module.system, data.dt)
                    print(json.dumps({"name": name, "step": step, "control": row["control"]}), flush=True)
                    with out.open("a") as f:
                        f.write(
                            json.dumps({"name": name, "overrides": extra, "step": step, "final": True, **row}) + "\n"
                        )
                    break
                epoch, batch = next(stream)
                optimizer.zero_grad()
                module.loss(batch).backward()
                optimizer.step()


if __name__ == "__main__":
    main()
