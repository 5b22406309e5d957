"""Training objectives, registered by name: each is a function ``(module, batch) -> loss``.

A model lists the names it supports in its ``objectives`` (the first is its default); the config's
``objective`` picks one, and the ``TrainingModule`` calls it. A new objective is one function here
under :func:`objective`. Batches are dicts (``encons.data.datamodule``): ``states`` and, where present,
inputs ``u`` and true derivatives ``rates``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Callable

from torch import Tensor

from encons.errors import ConfigError
from encons.integrators import state_derivative

if TYPE_CHECKING:
    from encons.module import TrainingModule

Batch = dict[str, Tensor]
Objective = Callable[["TrainingModule", Batch], Tensor]
OBJECTIVES: dict[str, Objective] = {}


def objective(name: str) -> Callable[[Objective], Objective]:
    """Register the decorated function as objective ``name``."""
    def register(fn: Objective) -> Objective:
        OBJECTIVES[name] = fn
        return fn

    return register


@objective("rollout")
def rollout(module: TrainingModule, batch: Batch) -> Tensor:
    """Zhong et al. §4.1: L1 over a window rolled out from its first state (first ``history`` states),
    summed over the window, plus the observation's own terms."""
    x, states = module.observe(batch)
    return module.rollout_loss(x, states, module.predict(batch, states))


@objective("residual")
def residual(module: TrainingModule, batch: Batch) -> Tensor:
    """The squared norm of a discrete model's own residual (e.g. SyMo's discrete Euler–Lagrange equations)."""
    _, states = module.observe(batch)
    return (module.model.residual(states, module.times(states.shape[1], states), batch.get("u")) ** 2).sum(-1).mean()


def _derivative_error(module: TrainingModule, batch: Batch, name: str) -> Tensor:
    if "rates" not in batch:
        raise ConfigError(f"objective={name} needs batches with rates; allowed: a data module built "
                          f"with objective='{name}' (data.objective: ${{objective}})")
    _, states = module.observe(batch)
    return state_derivative(module.model, states, batch.get("u")) - batch["rates"]


@objective("derivative")
def derivative(module: TrainingModule, batch: Batch) -> Tensor:
    """Lim & Kasim eq. (2): squared error of the field against the true state derivatives."""
    return (_derivative_error(module, batch, "derivative") ** 2).sum(-1).mean()


@objective("acceleration")
def acceleration(module: TrainingModule, batch: Batch) -> Tensor:
    """Xiao et al. §3: the derivative objective on the q̈ half only."""
    error = _derivative_error(module, batch, "acceleration")
    return (error[..., error.shape[-1] // 2:] ** 2).sum(-1).mean()
