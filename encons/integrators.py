"""Rollouts: the one way every model is integrated, through torchdiffeq."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor
from torch.func import jvp
from torchdiffeq import odeint
from torchdiffeq._impl.odeint import SOLVERS
from torchdiffeq._impl.solvers import FixedGridODESolver

from encons.errors import ConfigError
from encons.models.base import DynamicsModel

METHODS = tuple(sorted(SOLVERS))
FIXED_STEP = tuple(sorted(m for m, solver in SOLVERS.items() if issubclass(solver, FixedGridODESolver)))


@dataclass(frozen=True)
class Integrator:
    """A torchdiffeq method; fixed-step methods step once per ``substeps``-th of the data dt."""

    method: str = "rk4"
    substeps: int = 1
    rtol: float = 1e-7
    atol: float = 1e-9

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ConfigError(f"integrator.method={self.method!r} is unknown; allowed: {', '.join(METHODS)}")
        if self.substeps < 1:
            raise ConfigError(f"integrator.substeps={self.substeps} must be >= 1")

    def options(self, t: Tensor) -> dict:
        if self.method in FIXED_STEP:
            return {"method": self.method, "options": {"step_size": float(t[1] - t[0]) / self.substeps}}
        return {"method": self.method, "rtol": self.rtol, "atol": self.atol}


def rollout(model: DynamicsModel, s0: Tensor, t: Tensor, integrator: Integrator) -> Tensor:
    """Integrate ``model`` from data-chart states ``s0`` (..., 2n) over times ``t`` (T,).

    Returns data-chart states (..., T, 2n); index 0 along time is ``decode(encode(s0))``.
    """
    z = odeint(model, model.encode(s0), t.to(s0), **integrator.options(t))
    return model.decode(z).movedim(0, -2)


def state_derivative(model: DynamicsModel, s: Tensor) -> Tensor:
    """ds/dt in the data chart: the model's field pushed through ``decode`` (chain rule by jvp)."""
    z = model.encode(s)
    return jvp(model.decode, (z,), (model(torch.zeros(()), z),))[1]
