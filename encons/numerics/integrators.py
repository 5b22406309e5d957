"""Rollouts: the one way every model is advanced.

Continuous vector fields are integrated by torchdiffeq with the ``integrator`` group's method;
discrete models (``DiscreteModel``) advance by their own step. Inputs ``u`` are given per data
step, shape (..., T, m), and held constant over each step (zero-order hold).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable, cast

import torch
from torch import Tensor
from torch.func import jvp
from torchdiffeq import odeint

from encons.infra import bounds
from encons.infra.bounds import Count, Positive
from encons.infra.compat import ode_methods
from encons.infra.errors import ConfigError

if TYPE_CHECKING:
    from encons.models.base import DiscreteModel, DynamicsModel

METHODS, FIXED_STEP = ode_methods()


@dataclass(frozen=True)
class Integrator:
    """A torchdiffeq method; fixed-step methods step once per ``substeps``-th of the data dt, adaptive ones
    at ``rtol``/``atol`` with at most ``max_steps`` steps per data dt (then torchdiffeq raises)."""

    method: str = "rk4"
    substeps: Count = 1
    rtol: Positive = 1e-7
    atol: Positive = 1e-9
    max_steps: Count = 1000

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ConfigError(f"integrator.method={self.method!r} is unknown; allowed: {', '.join(METHODS)}")
        bounds.check(vars(self), bounds.hints(Integrator), "integrator", types=False)

    def options(self, t: Tensor) -> dict:
        if self.method in FIXED_STEP:
            return {"method": self.method, "options": {"step_size": float(t[1] - t[0]) / self.substeps}}
        return {
            "method": self.method,
            "rtol": self.rtol,
            "atol": self.atol,
            "options": {"max_num_steps": self.max_steps},
        }  # torchdiffeq counts per output interval


def odeint_held(
    field: Callable[[Tensor, Tensor, Tensor], Tensor], z0: Tensor, t: Tensor, u: Tensor, **options
) -> Tensor:
    """``odeint`` of ``field(t, z, u_k)`` with inputs ``u`` (..., T, m) held constant on each
    [t_k, t_{k+1}]: one solve per data step, so no solver stage sees the next step's input (a
    field cannot tell the end of one step from the start of the next by ``t`` alone).
    Returns (T, ..., d) like ``odeint``."""
    states = [z0]
    for k in range(len(t) - 1):
        uk = u[..., k, :]
        states.append(odeint(lambda time, z: field(time, z, uk), states[-1], t[k : k + 2], **options)[-1])
    return torch.stack(states)


def rollout(
    model: DynamicsModel, start: Tensor, t: Tensor, integrator: Integrator | None = None, u: Tensor | None = None
) -> Tensor:
    """Roll ``model`` out over times ``t`` (T,) under inputs ``u`` (..., T, m) or None.

    ``start`` is the data-chart state (..., 2n) for a continuous model, the first ``history``
    states (..., history, 2n) for a discrete one. Returns data-chart states (..., T, 2n); for a
    continuous model index 0 along time is ``start`` itself (``from_internal(to_internal(start))`` in exact
    arithmetic; not computed, so a learned decoder costs T − 1 evaluations).
    """
    weight = next(model.parameters(), None)
    if weight is not None and weight.is_floating_point() and weight.dtype != start.dtype:
        raise ConfigError(
            f"start dtype={str(start.dtype).removeprefix('torch.')} differs from the model's "
            f"{str(weight.dtype).removeprefix('torch.')}; allowed: start.to({weight.dtype}) or a model "
            f"of the start's dtype (model.to(start.dtype))"
        )
    t = t.to(start)
    if model.discrete:
        return cast("DiscreteModel", model).rollout(start, t, u)  # a discrete model is a DiscreteModel
    if integrator is None:
        raise ConfigError(
            f"{type(model).__name__} is a continuous model: its rollout needs an integrator; "
            f"allowed: an Integrator (the integrator group)"
        )
    options = integrator.options(t)
    with model.rollout_scope():
        if u is None:  # models without inputs may define forward(t, z) only
            z = odeint(model, model.to_internal(start), t, **options)
        else:
            z = odeint_held(model, model.to_internal(start), t, u.to(start), **options)
        return torch.cat([start.unsqueeze(-2), model.from_internal(z[1:].movedim(0, -2))], -2)  # batch-major rows


def state_derivative(model: DynamicsModel, s: Tensor, u: Tensor | None = None) -> Tensor:
    """ds/dt in the data chart: the model's field pushed through ``from_internal`` (chain rule by jvp)."""
    z = model.to_internal(s)
    t = torch.zeros(())
    return jvp(model.from_internal, (z,), (model(t, z) if u is None else model(t, z, u),))[1]
