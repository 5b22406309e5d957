"""Mechanical systems driven by a control input u (Santos, Ekal & Ventura, §3.1 and §7).

The state is s = (q, q̇) in generalised coordinates (one chart, ``angle``); the control enters the
forced Euler–Lagrange equations (Santos et al. eq. (3)–(4)) as the generalised force F = B u with a
constant input matrix B (``input_matrix``):

    M(q) q̈ = B u − b(q, q̇),   b = C(q, q̇) + ∇V(q)   (Coriolis/centrifugal terms and gravity).

Each system gives M(q), V(q) and b(q, q̇) in closed form. ``angles`` marks which coordinates are
angles (embedded on S¹ by the models); the others are translations.

A system that a swing-up controller can be built for (``encons.tools.control``) declares how on its class:
``controller``, a :class:`ControllerSettings` (gains, LQR weights, switching level, success tolerance,
horizon, scored starts and the energy-pumping law), and ``input_unit``, the unit of u in the printed table.
"""

from __future__ import annotations

import abc
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar, cast

import torch
from torch import Tensor

from encons.infra.bounds import Count, NonNegative, Positive
from encons.infra.errors import ConfigError
from encons.systems.mechanical import Mechanical

INPUTS = ("constant", "steps", "multisine")
PUMPING = ("pivot", "cart")  # the energy-pumping laws of encons.tools.control.SwingUp


@dataclass(frozen=True)
class ControllerSettings:
    """Gains, LQR weights, switching level, success tolerance and horizon of one system's swing-up controller
    (``encons.tools.control``), declared by the system class as ``controller``.

    ``tolerance`` holds the bound of each state entry (q then q̇) within which the state counts as upright.
    ``pumping`` names the energy-pumping law far from upright: ``pivot`` (one actuated angle: the torque
    u = u_max sat(k_E (E* − E)) sgn(q̇)) or ``cart`` (the cart-pole's: the cart's acceleration from the pole's
    energy, with ``cart_gains`` k_x, k_v keeping the cart near the origin).
    """

    gain_energy: float
    q_weights: tuple[float, ...]
    r_weight: float
    switch: float
    tolerance: tuple[float, ...]
    duration: float
    hold: float
    cart_gains: tuple[float, float] = (0.0, 0.0)  # k_x, k_v of the cart-pole's pumping
    start_range: tuple[float, ...] = ()  # half-widths of the uniform scored starts around upright at rest
    pumping: str = "pivot"

    def __post_init__(self) -> None:
        if self.pumping not in PUMPING:
            raise ConfigError(f"controller.pumping={self.pumping}; allowed: {', '.join(PUMPING)}")

    def starts(self, n: int, seed: int) -> Tensor:
        """``n`` scored starts (n, 2n_q), uniform in ±``start_range`` from ``seed`` (Santos et al. §7's
        initial states: the system's default ``init_range``, whatever the training data drew)."""
        unit = torch.rand(n, len(self.start_range), generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
        return (2 * unit - 1) * torch.tensor(self.start_range, dtype=torch.float64)


class ControlledMechanical(Mechanical):
    """Base of the controlled systems: M(q), V(q), b(q, q̇) and B in closed form, |u| ≤ u_max.

    Initial states are uniform in ``init_center ± init_range`` per state entry (default centre 0: the
    upright rest state, so the default half-widths span the whole circle; small half-widths give starts
    near a chosen state). ``inputs`` says how each trajectory's input is drawn, all held over each
    data step (zero-order hold):

    - ``constant``: one u ~ U(−u_max, u_max) per trajectory (Santos et al. §7);
    - ``steps``: a fresh u_k ~ U(−u_max, u_max) every data step (a random piecewise-constant input);
    - ``multisine``: u(t_k) = Σ_j a_j sin(2π j t_k / T + φ_j), j = 1..``tones``, T the trajectory's span,
      a_j ~ U(0, u_max/tones), φ_j ~ U(0, 2π) per trajectory (so |u| ≤ u_max): a band-limited excitation.
    """

    n_controls = 1
    angles: tuple[bool, ...]
    controller: ClassVar[ControllerSettings | None] = None  # None: no swing-up controller for this system
    input_unit: ClassVar[str] = "u"  # the unit of the input u (encons.tools.control's table)

    def __init__(
        self,
        init_range: Sequence[NonNegative],
        u_max: NonNegative,
        init_center: Sequence[float] | None = None,
        inputs: str = "constant",
        tones: Count = 5,
    ):
        width = 2 * len(self.angles)
        if len(init_range) != width:
            raise ConfigError(
                f"system.init_range={list(init_range)}; allowed: {width} non-negative half-widths (q then q̇)"
            )
        if init_center is not None and len(init_center) != width:
            raise ConfigError(
                f"system.init_center={list(init_center)}; allowed: null (the origin) or {width} numbers (q then q̇)"
            )
        if inputs not in INPUTS:
            raise ConfigError(f"system.inputs={inputs}; allowed: {', '.join(INPUTS)}")
        self.init_range = torch.tensor([float(r) for r in init_range], dtype=torch.float64)
        self.init_center = torch.tensor([float(c) for c in init_center or [0.0] * width], dtype=torch.float64)
        self.u_max, self.inputs, self.tones = float(u_max), inputs, int(tones)

    @property
    def n(self) -> int:  # type: ignore[override]  # Mechanical's n, here read from the declared angles
        return len(self.angles)

    def units(self, chart: str) -> tuple[str, ...]:
        return tuple("rad" if angle else "m" for angle in self.angles)

    @abc.abstractmethod
    def input_matrix(self) -> Tensor:
        """B (n, m): the generalised force of input u is B u."""

    def generalised_force(self, s: Tensor, u: Tensor | None) -> Tensor | None:
        """B u (Santos et al. eq. (4)); None for u = None (unforced)."""
        return None if u is None else u.to(s) @ self.input_matrix().to(s).T

    def sample_initial(self, n: int, generator: torch.Generator) -> Tensor:
        unit = torch.rand(n, self.init_range.numel(), generator=generator, dtype=torch.float64)
        return self.init_center + (2 * unit - 1) * self.init_range

    def sample_controls(self, n: int, generator: torch.Generator) -> Tensor:
        unit = torch.rand(n, self.n_controls, generator=generator, dtype=torch.float64)
        return (2 * unit - 1) * self.u_max

    def sample_inputs(self, n: int, t: Tensor, generator: torch.Generator) -> Tensor:
        """Inputs (n, T, m) drawn as ``inputs`` says (class docstring)."""
        if self.inputs == "constant":
            return cast(Tensor, super().sample_inputs(n, t, generator))  # from sample_controls above: a Tensor
        if self.inputs == "steps":
            unit = torch.rand(n, len(t), self.n_controls, generator=generator, dtype=torch.float64)
            return (2 * unit - 1) * self.u_max
        shape = (n, 1, self.n_controls, self.tones)
        amplitude = torch.rand(shape, generator=generator, dtype=torch.float64) * self.u_max / self.tones
        phase = torch.rand(shape, generator=generator, dtype=torch.float64) * 2 * math.pi
        freq = torch.arange(1, self.tones + 1, dtype=torch.float64) / float(t[-1] - t[0])
        angle = 2 * math.pi * freq * (t - t[0]).to(torch.float64)[:, None, None] + phase
        return (amplitude * torch.sin(angle)).sum(-1)


class ControlledPendulum(ControlledMechanical):
    """Gym's Pendulum (Brockman et al. 2016): a uniform rod of mass m, length l on a torque-driven pivot.

    θ is measured from the upright position; M = m l²/3, V = ½ m g l (1 + cos θ), B = 1, so that
    θ̈ = 3 g/(2 l) sin θ + 3 u/(m l²) as in Gym's dynamics.
    """

    angles = (True,)
    input_unit = "N m"  # the pivot's torque
    controller = ControllerSettings(
        gain_energy=2.0,
        q_weights=(10.0, 1.0),
        r_weight=1.0,
        switch=20.0,
        tolerance=(0.1, 0.5),
        duration=10.0,
        hold=2.0,
        start_range=(math.pi, 2 * math.pi),
    )

    def __init__(
        self,
        mass: Positive = 1.0,
        length: Positive = 1.0,
        g: Positive = 9.81,
        init_range: Sequence[NonNegative] = (math.pi, 2 * math.pi),
        u_max: NonNegative = 2.0,
        init_center: Sequence[float] | None = None,
        inputs: str = "constant",
        tones: Count = 5,
    ):
        super().__init__(init_range, u_max, init_center, inputs, tones)
        self.name = "pendulum_control"
        self.m, self.l, self.g = float(mass), float(length), float(g)

    def mass_matrix(self, q: Tensor) -> Tensor:
        return torch.full((*q.shape, 1), self.m * self.l**2 / 3, dtype=q.dtype, device=q.device)

    def potential(self, q: Tensor) -> Tensor:
        return 0.5 * self.m * self.g * self.l * (1 + torch.cos(q[..., 0]))

    def bias(self, q: Tensor, qd: Tensor) -> Tensor:
        return -0.5 * self.m * self.g * self.l * torch.sin(q)

    def input_matrix(self) -> Tensor:
        return torch.ones(1, 1, dtype=torch.float64)


class CartPole(ControlledMechanical):
    """Gym's CartPole (Barto, Sutton & Anderson 1983; Florian 2007) with a continuous force u on the cart.

    q = (x, θ): cart position and pole angle from upright; the pole is a uniform rod of mass m_p and
    half-length l. M = [[m_c + m_p, m_p l cos θ], [m_p l cos θ, (4/3) m_p l²]], V = m_p g l cos θ,
    B = (1, 0)ᵀ, C = (−m_p l sin θ θ̇², 0).
    """

    angles = (False, True)
    input_unit = "N"  # the force on the cart
    controller = ControllerSettings(
        gain_energy=300.0,
        q_weights=(1.0, 10.0, 1.0, 1.0),
        r_weight=1.0,
        switch=300.0,
        tolerance=(1.0, 0.1, math.inf, 0.5),
        duration=10.0,
        hold=2.0,
        cart_gains=(1.0, 2.0),
        start_range=(0.5, 3.14, 0.05, 3.0),
        pumping="cart",
    )

    def __init__(
        self,
        cart_mass: Positive = 1.0,
        pole_mass: Positive = 0.1,
        half_length: Positive = 0.5,
        g: Positive = 9.81,
        init_range: Sequence[NonNegative] = (0.5, 3.14, 0.05, 3.0),
        u_max: NonNegative = 2.0,
        init_center: Sequence[float] | None = None,
        inputs: str = "constant",
        tones: Count = 5,
    ):
        super().__init__(init_range, u_max, init_center, inputs, tones)
        self.name = "cartpole"
        self.mc, self.mp, self.l, self.g = float(cart_mass), float(pole_mass), float(half_length), float(g)

    def mass_matrix(self, q: Tensor) -> Tensor:
        off = self.mp * self.l * torch.cos(q[..., 1])
        top = torch.stack([torch.full_like(off, self.mc + self.mp), off], -1)
        bottom = torch.stack([off, torch.full_like(off, 4 / 3 * self.mp * self.l**2)], -1)
        return torch.stack([top, bottom], -2)

    def potential(self, q: Tensor) -> Tensor:
        return self.mp * self.g * self.l * torch.cos(q[..., 1])

    def bias(self, q: Tensor, qd: Tensor) -> Tensor:
        sin = torch.sin(q[..., 1])
        return torch.stack([-self.mp * self.l * sin * qd[..., 1] ** 2, -self.mp * self.g * self.l * sin], -1)

    def input_matrix(self) -> Tensor:
        return torch.tensor([[1.0], [0.0]], dtype=torch.float64)
