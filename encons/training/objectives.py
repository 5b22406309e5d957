"""Training objectives, registered by name: each is a function ``(module, batch) -> loss``.

A model lists the names it supports in its ``objectives`` (the first is its default); the config's
``objective`` picks one, and the ``TrainingModule`` calls it. A new objective is one function here
under :func:`objective`. Batches are dicts (``encons.data.datamodule``): ``states`` and, where present,
inputs ``u`` and true derivatives ``rates``. An objective means over the batch by ``module.reduce`` (per member
in a stacked ensemble, ``encons.training.stacked``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Callable, cast

from torch import Tensor

from encons.infra.errors import ConfigError
from encons.numerics import metrics
from encons.numerics.integrators import state_derivative

if TYPE_CHECKING:
    from encons.models.base import DiscreteModel
    from encons.numerics.learner import Learner

Batch = dict[str, Tensor]
Objective = Callable[["Learner", Batch], Tensor]
OBJECTIVES: dict[str, Objective] = {}


def objective(name: str) -> Callable[[Objective], Objective]:
    """Register the decorated function as objective ``name``."""

    def register(fn: Objective) -> Objective:
        OBJECTIVES[name] = fn
        return fn

    return register


@objective("rollout")
def rollout(module: Learner, batch: Batch) -> Tensor:
    """Zhong et al. §4.1: L1 over a window rolled out from its first state (first ``history`` states),
    summed over the window, plus the observation's own terms."""
    x, states = module.observe(batch)
    return module.rollout_loss(x, states, module.predict(batch, states))


@objective("residual")
def residual(module: Learner, batch: Batch) -> Tensor:
    """The squared norm of a discrete model's own residual (e.g. SyMo's discrete Euler–Lagrange equations)."""
    _, states = module.observe(batch)
    model = cast("DiscreteModel", module.model)  # a model listing "residual" defines it, as DiscreteModel declares
    return module.reduce((model.residual(states, module.times(states.shape[1], states), batch.get("u")) ** 2).sum(-1))


@objective("onestep")
def onestep(module: Learner, batch: Batch) -> Tensor:
    """Santos et al. §7: MSE over states and coordinates of every state of a window predicted from the
    true ``model.history`` states before it."""
    _, states = module.observe(batch)
    u, size = batch.get("u"), module.model.history + 1
    one = {"states": states.unfold(1, size, 1).movedim(-1, -2).flatten(0, 1)}
    if u is not None:
        one["u"] = u[:, : states.shape[1]].unfold(1, size, 1).movedim(-1, -2).flatten(0, 1)
    return module.reduce((module.predict(one)[:, -1] - one["states"][:, -1]).square())


def _rates(module: Learner, batch: Batch, name: str) -> tuple[Tensor, Tensor]:
    """The model's state derivatives at the batch's states and the true ones (``rates``)."""
    if "rates" not in batch:
        raise ConfigError(
            f"objective={name} needs batches with rates; allowed: a data module built "
            f"with objective='{name}' (data.objective: ${{objective}})"
        )
    _, states = module.observe(batch)
    return state_derivative(module.model, states, batch.get("u")), batch["rates"]


@objective("derivative")
def derivative(module: Learner, batch: Batch) -> Tensor:
    """Lim & Kasim eq. (2): squared error of the field against the true state derivatives."""
    pred, true = _rates(module, batch, "derivative")
    return module.reduce(((pred - true) ** 2).sum(-1))


@objective("acceleration")
def acceleration(module: Learner, batch: Batch) -> Tensor:
    """Xiao et al. §3: the derivative objective on the q̈ half only (``encons.numerics.metrics.acceleration_mse``, also
    the test metric ``accel_mse`` of ``encons.evaluators.Acceleration``)."""
    return metrics.acceleration_mse(*_rates(module, batch, "acceleration"), reduce=module.reduce)
