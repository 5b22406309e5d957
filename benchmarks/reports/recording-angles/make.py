"""Issue #37's observations on a simulated lab recording, and the after state.

    python benchmarks/reports/recording-angles/make.py OUT [steps]

Writes two whitespace recordings of the simulated one-link pendulum (``pendulum1``: q(0) = 2.8 rad,
q̇(0) = 1 rad/s, dt 0.03 s, 1201 samples with samples 300, 301 and 700 dropped) whose first line is
``% time theta omega``: ``lab.txt`` as simulated (q in [−3.03, 3.03]) and ``lab_shift.txt`` with q
shifted by −4π (as unwrapping from a first sample on another branch gives). Trains NODE on each for
``steps`` Adam steps (default 300; n_steps 10, test windows of 40 steps, angles marked) and writes
``OUT/metrics.json`` (test metrics per file) beside each run folder (figures under ``<run>/figures``).
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import torch

from encons import api
from encons.data.simulate import simulate
from encons.systems.pendulum import NPendulum


def write(path: Path, shift: float) -> Path:
    t = torch.arange(1201, dtype=torch.float64) * 0.03
    s = simulate(NPendulum(1), torch.tensor([[2.8, 1.0]], dtype=torch.float64), t, substeps=10)[0].numpy()
    keep = np.ones(len(t), bool)
    keep[[300, 301, 700]] = False
    rows = [f"{a:.6f} {q + shift:.9f} {w:.9f}" for a, (q, w) in zip(t.numpy()[keep], s[keep])]
    path.write_text("% time theta omega\n" + "\n".join(rows) + "\n")
    return path


def main(out: Path, steps: int = 300) -> None:
    out.mkdir(parents=True, exist_ok=True)
    results = {}
    for name, shift in (("lab", 0.0), ("lab_shift", -4 * math.pi)):
        path = write(out / f"{name}.txt", shift)
        cfg = api.compose("system=from_file", f"system.path={path}", "model=node", "logger=csv",
                          "data.recording.comment='%'", "data.recording.columns={t: time, q: [theta], qdot: [omega]}",
                          "data.recording.angles=true", "data.n_steps=10", "data.test_steps=40",
                          "trainer.max_epochs=null", f"trainer.max_steps={steps}", output_dir=out / name)
        results[name] = api.train(cfg).metrics
    (out / "metrics.json").write_text(json.dumps(results, indent=1, sort_keys=True))
    for key in ("test/traj_rel_err", "test/traj_rel_err_window", "test/geom_rel_err", "test/state_mse",
                "test/baseline_constant/traj_rel_err", "test/baseline_linear_ode/traj_rel_err"):
        print(f"{key:<40}" + "".join(f"{results[n].get(key, float('nan')):>12.4g}" for n in results))


if __name__ == "__main__":
    main(Path(sys.argv[1]), *(int(a) for a in sys.argv[2:]))
