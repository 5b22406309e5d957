"""Ideal mass-spring oscillator (Lim & Kasim 2023, Task 1): q̈ = −(k/m) q.

One chart, ``angle`` (the generalised coordinate q, the displacement from equilibrium, and q̇);
H = ½ m q̇² + ½ k q².
"""

from __future__ import annotations

import torch
from torch import Tensor

from encons.infra.bounds import Positive
from encons.systems.base import System, split_state


class MassSpring(System):
    """A mass ``m`` on a spring of stiffness ``k``; initial states ~ N(0, init_scale²)."""

    charts = ("angle",)
    common_chart = "angle"

    def __init__(self, mass: Positive = 1.0, stiffness: Positive = 1.0, init_scale: Positive = 1.0):
        self.name = "mass_spring"
        self.m, self.k, self.init_scale = float(mass), float(stiffness), float(init_scale)

    def coord_dim(self, chart: str) -> int:
        self.check_chart(chart)
        return 1

    def units(self, chart: str) -> tuple[str, ...]:
        return ("m",)

    def mass_matrix(self, q: Tensor) -> Tensor:
        return torch.full((*q.shape, 1), self.m, dtype=q.dtype, device=q.device)

    def potential(self, q: Tensor) -> Tensor:
        return 0.5 * self.k * (q**2).sum(-1)

    def vector_field(self, s: Tensor, chart: str) -> Tensor:  # type: ignore[override]  # no inputs: u omitted (System.field)
        self.check_chart(chart)
        q, qd = split_state(s)
        return torch.cat([qd, -(self.k / self.m) * q], -1)

    def energy(self, s: Tensor, chart: str) -> Tensor:
        self.check_chart(chart)
        q, qd = split_state(s)
        return 0.5 * self.m * (qd**2).sum(-1) + self.potential(q)

    def sample_initial(self, n: int, generator: torch.Generator) -> Tensor:
        return self.init_scale * torch.randn(n, 2, generator=generator, dtype=torch.float64)
