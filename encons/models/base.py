"""The Model seam: a learned continuous vector field ż = f(t, z, u), or a model that steps itself.

Data come as ``s = (q, q̇)`` in the model's chart; ``to_internal`` maps them to the internal
state a continuous field acts on (e.g. ``(q, p)`` for Hamiltonian models, p = M(q) q̇) and
``from_internal`` maps back. (An observation model's ``encode``/``decode`` are another map:
observations such as frames to states and back, ``encons.models.observation``.) Exogenous inputs ``u`` (controls,
per-trajectory parameters; shape (..., m)) travel beside the state in one argument, never inside it.
``encons.numerics.integrators.rollout`` is the one way to roll any model out: continuous fields through torchdiffeq,
discrete models (``DiscreteModel``) by their own ``rollout``.

What a model supports is declared by class attributes, checked once when a run is built
(``encons.config.check.check_capabilities``): ``discrete``, ``supports_controls``, ``needs_constraints``,
``history`` and ``objectives``; ``family`` names the structure it learns (a benchmark profile's ``per_family``)
and ``headline`` the ``diagnostics`` a benchmark summary shows. What a controller can be built from is
declared by ``energy_structure`` (the learned M(q), V(q) and input matrix, ``encons.tools.control``).
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Callable, ClassVar, Iterator, NamedTuple

import torch
from torch import Tensor, nn

from encons.infra.bounds import Declared
from encons.infra.errors import ConfigError
from encons.systems.base import System


class EnergyStructure(NamedTuple):
    """What an energy-based controller needs of a model (``encons.tools.control``): the learned M(q) (..., n, n),
    V(q) (...) and the input matrix, a constant B (n, m) or a callable g(q) (..., n, m) (``encons.models.inputs``)."""

    mass: Callable[[Tensor], Tensor]
    potential: Callable[[Tensor], Tensor]
    input_matrix: Tensor | Callable[[Tensor], Tensor] | None  # None: the system has no inputs


class DynamicsModel(nn.Module, Declared):
    """Base of every model; subclasses of it alone are continuous vector fields.

    Subclasses set ``default_chart`` (``None``: the system's base chart) and the capability
    attributes below, and implement ``forward(t, z, u=None)`` (``forward(t, z)`` suffices for a
    model without inputs: it is called with ``u`` only when there are inputs). ``to_internal``/
    ``from_internal`` default to the identity.
    """

    config_key = "model"
    default_chart: ClassVar[str | None] = None
    needs_constraints: ClassVar[bool] = False  # uses the system's holonomic constraints Φ(x) = 0
    supports_controls: ClassVar[bool] = False  # accepts exogenous inputs u
    discrete: ClassVar[bool] = False  # False: a vector field rolled out by the integrator group
    history: ClassVar[int] = 1  # data states a rollout starts from
    objectives: ClassVar[tuple[str, ...]] = ("rollout", "derivative", "onestep")  # supported; the first is the default
    family: ClassVar[str | None] = None  # the structure it learns; a benchmark profile's per_family keys name it
    headline: ClassVar[tuple[str, ...]] = ()  # of its diagnostics(): shown in a benchmark summary's headline table

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        if {"encode", "decode"} & vars(cls).keys():  # the names of this map before; the rollout would skip them
            raise ConfigError(
                f"model class {cls.__module__}.{cls.__qualname__} defines encode/decode; allowed: "
                f"to_internal(s)/from_internal(z), a model's map to its internal state"
            )

    def __init__(self, system: System | None = None, chart: str | None = None):
        if system is None or not hasattr(
            system, "check_chart"
        ):  # a subclass's super().__init__() without the system encons passed it
            cls = type(self)
            raise ConfigError(
                f"model._target_={cls.__module__}.{cls.__qualname__}: its __init__ calls "
                f"super().__init__() with system={system!r}; allowed: super().__init__(system, chart), "
                f"passing on the system encons gives the constructor as system="
            )
        super().__init__()
        self.chart = chart or self.default_chart or system.base_chart
        system.check_chart(self.chart)
        self.n = system.coord_dim(self.chart)
        self.n_controls = system.n_controls

    def to_internal(self, s: Tensor) -> Tensor:
        """Data-chart state (..., 2n) -> internal state."""
        return s

    def from_internal(self, z: Tensor) -> Tensor:
        """Internal state -> data-chart state (..., 2n)."""
        return z

    def forward(self, t: Tensor, z: Tensor, u: Tensor | None = None) -> Tensor:  # noqa: D401 - torchdiffeq
        """dz/dt at internal states ``z`` of any batch shape, under inputs ``u`` (..., m) or None."""
        raise NotImplementedError

    @contextmanager
    def rollout_scope(self) -> Iterator[None]:
        """One rollout with fixed parameters (``encons.numerics.integrators.rollout`` enters it): a model may
        compute what depends on its parameters alone once here instead of per field evaluation
        (CHNN/CLNN: the inverse mass matrix). Default: nothing."""
        yield

    def energy_structure(self) -> EnergyStructure | None:
        """The learned M(q), V(q) and input matrix an energy-based controller is built from
        (``encons.tools.control``), or None: a model without them (the default) gets no controller."""
        return None

    def diagnostics(self) -> dict[str, float]:
        """Counters of the model's own solvers over the rollouts since ``reset_diagnostics`` (e.g. SyMo's
        Newton root-finds that did not converge), added to the test metrics. Default: none."""
        return {}

    def reset_diagnostics(self) -> None:
        """Start the counters of ``diagnostics`` afresh (the module does so before testing)."""

    def sync_diagnostics(self, copy: DynamicsModel) -> None:
        """Take the counters of ``copy``, a copy of this model that rolled out in its place (the
        evaluation's float64 copy), as this model's."""

    def true_counterpart(self, system: System) -> DynamicsModel | None:
        """The system's true dynamics in this model's form, stepped as this model steps: what it would be had it
        learned them exactly (the floor of metrics that roll out by the training integrator or the model's own
        step, ``encons.evaluators.santos``), or None where the form has none. A continuous model's is the true
        field in its chart (``TrueField``), for the same integrator to step."""
        return TrueField(system, self.chart)

    def constrained_field(self, s: Tensor, u: Tensor | None = None) -> tuple[Tensor, Callable[..., Tensor]]:
        """Points, per-point inputs and the per-sample field that soft dynamics constraints act on.

        Returns ``(z, field)`` with ``field(z_i, u_i)`` (``u_i`` None without inputs). Default: the
        internal field at ``to_internal(s)``; for a model whose ``to_internal`` is a learned invertible map
        this is the latent field, as in Lim & Kasim eq. (7).
        """
        t = torch.zeros((), dtype=s.dtype, device=s.device)
        return self.to_internal(s), lambda z, ui=None: self(t, z) if ui is None else self(t, z, ui)


class TrueField(DynamicsModel):
    """The system's true vector field in ``chart`` as a model: what the oracle row rolls out
    (``encons.numerics.evaluation``)."""

    def __init__(self, system: System, chart: str):
        super().__init__(system, chart)
        self.system = system

    def forward(self, t: Tensor, s: Tensor, u: Tensor | None = None) -> Tensor:
        return self.system.field(s, self.chart, u)


class DiscreteModel(DynamicsModel):
    """A model that advances itself by discrete steps from its last ``history`` states.

    It has no vector field, so ``objective=derivative`` and the Jacobian regularisers do not apply;
    the integrator group does not apply either. Subclasses implement ``rollout`` and, when
    ``"residual"`` is among their ``objectives``, ``residual``.
    """

    discrete = True
    history = 2
    objectives: ClassVar[tuple[str, ...]] = ("rollout", "onestep")

    def forward(self, t: Tensor, z: Tensor, u: Tensor | None = None) -> Tensor:
        raise TypeError(f"{type(self).__name__} is a discrete model: it has no vector field")

    def rollout(self, start: Tensor, t: Tensor, u: Tensor | None = None) -> Tensor:
        """States (..., T, 2n) on times ``t`` (T,) from the first ``history`` states ``start``
        (..., history, 2n), which are returned unchanged; ``u`` (..., T, m) per step or None."""
        raise NotImplementedError

    def residual(self, states: Tensor, t: Tensor, u: Tensor | None = None) -> Tensor:
        """Residual vectors (..., K) of the model's own equations on windows ``states`` (..., T, 2n)."""
        raise NotImplementedError

    def true_counterpart(self, system: System) -> DynamicsModel | None:
        """None unless the discrete model defines its own (the system's field is not stepped by its step)."""
        return None


def angle_mask(system: System, angular: bool) -> bool | tuple[bool, ...]:
    """Which coordinates the networks embed on S¹ when ``angular``: the system's ``angles`` (a bool when they
    are all alike: the same layout), all when it declares none."""
    if not angular or system.angles is None:
        return angular
    mask = tuple(bool(a) for a in system.angles)
    return mask[0] if len(set(mask)) == 1 else mask
