"""Mechanical systems with non-conservative generalised forces (Xiao, Zhang & Tang 2024, §4).

The state is s = (q, q̇) in generalised coordinates (one chart, ``angle``). Each system is a
Lagrangian L = ½ q̇ᵀ M(q) q̇ − V(q) plus a velocity-dependent generalised force F(q, q̇), and
moves by the generalised Lagrange equation (Xiao et al. eq. (2), expanded in eq. (11)):

    M(q) q̈ = F(q, q̇) − b(q, q̇),   b = C(q, q̇) + ∇V(q)   (Coriolis/centrifugal terms and gravity).

The energy E = ½ q̇ᵀ M q̇ + V obeys dE/dt = F·q̇ ≤ 0 for the frictions here, so it decays
monotonically. Initial states are uniform in [−r, r] per entry (the paper's [−1, 1]^{2n}).
"""

from __future__ import annotations

import abc

import torch
from torch import Tensor

from encons.infra.bounds import NonNegative, Positive
from encons.systems.base import split_state
from encons.systems.mechanical import Mechanical


class DissipativeMechanical(Mechanical):
    """Base: M(q), V(q), b(q, q̇) and the non-conservative force F(q, q̇) in closed form."""

    def __init__(self, init_range: Positive):
        self.init_range = float(init_range)

    @abc.abstractmethod
    def force(self, s: Tensor) -> Tensor:
        """The non-conservative generalised force F(q, q̇) (..., n) of Xiao et al. eq. (2)."""

    def generalised_force(self, s: Tensor, u: Tensor | None = None) -> Tensor:
        return self.force(s)

    def sample_initial(self, n: int, generator: torch.Generator) -> Tensor:
        unit = torch.rand(n, 2 * self.n, generator=generator, dtype=torch.float64)
        return self.init_range * (2 * unit - 1)


class DampedOscillator(DissipativeMechanical):
    """Damped harmonic motion m q̈ + a q̇ + k² q = 0 (Xiao et al. §4.2; m = 1 there).

    L = ½ m q̇² − ½ k² q², F = −a q̇, E = ½ m q̇² + ½ k² q², dE/dt = −a q̇².
    """

    n = 1

    def __init__(self, mass: Positive = 1.0, k: Positive = 1.0, a: NonNegative = 0.02, init_range: Positive = 1.0):
        super().__init__(init_range)
        self.name = "damped_oscillator"
        self.m, self.k, self.a = float(mass), float(k), float(a)

    def units(self, chart: str) -> tuple[str, ...]:
        return ("m",)

    def mass_matrix(self, q: Tensor) -> Tensor:
        return torch.full((*q.shape, 1), self.m, dtype=q.dtype, device=q.device)

    def potential(self, q: Tensor) -> Tensor:
        return 0.5 * self.k**2 * q[..., 0] ** 2

    def bias(self, q: Tensor, qd: Tensor) -> Tensor:
        return self.k**2 * q

    def force(self, s: Tensor) -> Tensor:
        return -self.a * split_state(s)[1]


class CompoundPendulum(DissipativeMechanical):
    """Compound double pendulum with axle friction (Williams 2023; Xiao et al. §4.3, eq. (12)).

    Two identical rigid bodies of mass m and moment of inertia I about their axles, axles a
    distance d apart, angles θ₁, θ₂ from the downward vertical. Eq. (12) is the Lagrange equation of

        M = [[2md² + I, md² cos(θ₁ − θ₂)], [md² cos(θ₁ − θ₂), md² + I]],  V = −mgd (2 cos θ₁ + cos θ₂),

    with the axle frictions F = (−γ₁ θ̇₁ − γ₂ (θ̇₁ − θ̇₂), γ₂ (θ̇₁ − θ̇₂)), so dE/dt = −γ₁ θ̇₁² − γ₂ (θ̇₁ − θ̇₂)².
    (The paper's eqs. (13)–(14) for L and F contain misprints; these reproduce eq. (12) exactly.)
    """

    n = 2
    angles = (True, True)

    def __init__(
        self,
        mass: Positive = 1.0,
        d: Positive = 1.0,
        inertia: NonNegative = 1.0 / 12,
        g: NonNegative = 10.0,
        gamma1: NonNegative = 0.5,
        gamma2: NonNegative = 0.5,
        init_range: Positive = 1.0,
    ):
        super().__init__(init_range)
        self.name = "compound_pendulum"
        self.m, self.d, self.inertia, self.g = float(mass), float(d), float(inertia), float(g)
        self.gamma1, self.gamma2 = float(gamma1), float(gamma2)

    def mass_matrix(self, q: Tensor) -> Tensor:
        md2 = self.m * self.d**2
        off = md2 * torch.cos(q[..., 0] - q[..., 1])
        diag1 = torch.full_like(off, 2 * md2 + self.inertia)
        diag2 = torch.full_like(off, md2 + self.inertia)
        return torch.stack([torch.stack([diag1, off], -1), torch.stack([off, diag2], -1)], -2)

    def potential(self, q: Tensor) -> Tensor:
        return -self.m * self.g * self.d * (2 * torch.cos(q[..., 0]) + torch.cos(q[..., 1]))

    def bias(self, q: Tensor, qd: Tensor) -> Tensor:
        md2, mgd = self.m * self.d**2, self.m * self.g * self.d
        sin = torch.sin(q[..., 0] - q[..., 1])
        return torch.stack(
            [
                md2 * sin * qd[..., 1] ** 2 + 2 * mgd * torch.sin(q[..., 0]),
                -md2 * sin * qd[..., 0] ** 2 + mgd * torch.sin(q[..., 1]),
            ],
            -1,
        )

    def force(self, s: Tensor) -> Tensor:
        qd = split_state(s)[1]
        slip = self.gamma2 * (qd[..., 0] - qd[..., 1])
        return torch.stack([-self.gamma1 * qd[..., 0] - slip, slip], -1)
