"""Is a learned pendulum energy 2π-periodic?  Per member of a pendulum_control seed ensemble (issue 38).

    python benchmarks/reports/control-c/periodicity.py RUN_DIR [RUN_DIR ...]

For each member ``RUN_DIR/seed<k>`` (its best checkpoint) prints, for the learned potential V and the mass M
of the plant the controller is built from (``encons.control.learned_plant``), against the true ones:
- ``gap``: |V(π) − V(−π)| / (V(π) − V(0))_true — the bottom reached on either side (0 for a periodic V);
- ``shape``: max over q in [−π, π] of |ΔV_learned(q) − ΔV_true(q)| / (V(π) − V(0))_true, ΔV(q) = V(q) − V(0);
- ``shape_out``: the same over q in [π, 2π] ∪ [−2π, −π], the angles a swing past the bottom reaches
  when the angle is not wrapped;
- ``mass``: max relative error of M(q) over q in [−2π, 2π].
"""

import sys
from pathlib import Path

import torch

from encons import control, runs

torch.set_num_threads(1)
print("run,seed,gap,shape,shape_out,mass")
for folder in map(Path, sys.argv[1:]):
    for member in sorted(folder.glob("seed*")):
        run = runs.load(member)
        system = run.module.system
        learned = control.learned_plant(run.model, system, run.config.model._target_)
        true = control.true_plant(system)
        q = torch.linspace(-2 * torch.pi, 2 * torch.pi, 801, dtype=torch.float64)[:, None]
        zero = torch.zeros(1, 1, dtype=torch.float64)
        v_l, v_t = learned.potential(q).reshape(-1), true.potential(q).reshape(-1)
        dl, dt = v_l - learned.potential(zero).reshape(()), v_t - true.potential(zero).reshape(())
        pi = torch.tensor([[torch.pi]], dtype=torch.float64)
        scale = float(true.potential(pi).reshape(()) - true.potential(zero).reshape(()))
        inside = q[:, 0].abs() <= torch.pi + 1e-9
        gap = float((learned.potential(pi) - learned.potential(-pi)).abs().reshape(())) / abs(scale)
        shape = float((dl - dt)[inside].abs().max()) / abs(scale)
        shape_out = float((dl - dt)[~inside].abs().max()) / abs(scale)
        m_l, m_t = learned.mass(q).reshape(len(q), -1), true.mass(q).reshape(len(q), -1)
        mass = float(((m_l - m_t).norm(dim=-1) / m_t.norm(dim=-1)).max())
        print(f"{folder.name},{member.name.removeprefix('seed')},{gap:.3g},{shape:.3g},{shape_out:.3g},{mass:.3g}",
              flush=True)
