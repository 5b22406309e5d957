"""Ground-truth trajectories: RK4 in float64, vectorised over all trajectories at once."""

from __future__ import annotations

import torch
from torch import Tensor
from torchdiffeq import odeint

from encons.errors import DataError
from encons.systems.base import System


def simulate(system: System, s0: Tensor, t: Tensor, substeps: int = 10) -> Tensor:
    """Trajectories (N, T, 2n) in the base chart from states ``s0`` (N, 2n) over times ``t``."""
    step = float(t[1] - t[0]) / substeps
    traj = odeint(lambda _, s: system.vector_field(s, system.base_chart), s0, t,
                  method="rk4", options={"step_size": step})
    return traj.movedim(0, 1)


def sample_trajectories(system: System, n: int, t: Tensor, generator: torch.Generator,
                        substeps: int = 10, max_tries: int = 5) -> tuple[Tensor, int]:
    """``n`` valid trajectories (see ``System.valid``) and how many were rejected and redrawn."""
    kept: list[Tensor] = []
    count, rejected = 0, 0
    for _ in range(max_tries):
        need = n - count
        traj = simulate(system, system.sample_initial(need + need // 4 + 1, generator), t, substeps)
        ok = system.valid(traj) & torch.isfinite(traj).flatten(1).all(1)
        rejected += int((~ok[: need + need // 4 + 1]).sum())
        kept.append(traj[ok][:need])
        count += kept[-1].shape[0]
        if count == n:
            return torch.cat(kept), rejected
    raise DataError(f"system '{system.name}': only {count} of {n} sampled trajectories were valid "
                    f"after {max_tries} draws; widen the initial-condition ranges")
