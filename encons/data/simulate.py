"""Ground-truth trajectories: RK4 in float64, vectorised over all trajectories at once."""

from __future__ import annotations

import torch
from torch import Tensor
from torchdiffeq import odeint

from encons.infra.errors import DataError
from encons.numerics.integrators import odeint_held
from encons.systems.base import System


def simulate(system: System, s0: Tensor, t: Tensor, substeps: int = 10, u: Tensor | None = None) -> Tensor:
    """Trajectories (N, T, 2n) in the base chart from states ``s0`` (N, 2n) over times ``t``,
    under inputs ``u`` (N, T, m) held over each data step, or None."""
    options = {"method": "rk4", "options": {"step_size": float(t[1] - t[0]) / substeps}}
    if u is None:
        traj = odeint(lambda _, s: system.vector_field(s, system.base_chart), s0, t, **options)
    else:
        traj = odeint_held(lambda _, s, uk: system.vector_field(s, system.base_chart, uk), s0, t, u, **options)
    return traj.movedim(0, 1)


def sample_trajectories(
    system: System, n: int, t: Tensor, generator: torch.Generator, substeps: int = 10, max_tries: int = 5
) -> tuple[Tensor, Tensor | None, int]:
    """``n`` valid trajectories (see ``System.valid``), their inputs (n, T, m) (None without
    inputs), and how many were rejected and redrawn."""
    kept: list[tuple[Tensor, Tensor | None]] = []
    count, rejected = 0, 0
    for _ in range(max_tries):
        need = n - count
        draw = need + need // 4 + 1
        s0 = system.sample_initial(draw, generator)
        u = system.sample_inputs(draw, t, generator)
        traj = simulate(system, s0, t, substeps, u)
        ok = system.valid(traj) & torch.isfinite(traj).flatten(1).all(1)
        rejected += int((~ok).sum())
        kept.append((traj[ok][:need], u[ok][:need] if u is not None else None))
        count += kept[-1][0].shape[0]
        if count == n:
            states = torch.cat([k[0] for k in kept])
            inputs = [k[1] for k in kept if k[1] is not None]  # all of them where u is not None
            return states, (torch.cat(inputs) if u is not None else None), rejected
    raise DataError(
        f"system '{system.name}': only {count} of {n} sampled trajectories were valid "
        f"after {max_tries} draws; allowed: wider initial-condition ranges (system.*)"
    )
