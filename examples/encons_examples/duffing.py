"""The undamped Duffing oscillator, a user's own system: q̈ = −α q − β q³.

One chart, ``angle`` (encons' name for generalised coordinates; here q is a displacement in m, so
``units`` says so: the default is rad); energy E = ½ q̇² + ½ α q² + ¼ β q⁴ per unit mass.
"""

from __future__ import annotations

import torch
from torch import Tensor

from encons.infra.errors import ConfigError
from encons.systems.base import System, split_state


class Duffing(System):
    """Stiffness ``alpha`` > 0 and cubic stiffness ``beta`` >= 0; initial states U(−amplitude, amplitude)²."""

    charts = ("angle",)               # the first chart is where trajectories are simulated
    common_chart = "angle"            # where metrics compare models

    def __init__(self, alpha: float = 1.0, beta: float = 0.5, amplitude: float = 1.5):
        if alpha <= 0 or beta < 0 or amplitude <= 0:
            raise ConfigError(f"system.alpha={alpha}, system.beta={beta}, system.amplitude={amplitude}; "
                              f"allowed: alpha > 0, beta >= 0, amplitude > 0")
        self.name = "duffing"
        self.alpha, self.beta, self.amplitude = float(alpha), float(beta), float(amplitude)

    def coord_dim(self, chart: str) -> int:
        self.check_chart(chart)
        return 1

    def units(self, chart: str) -> tuple[str, ...]:
        return ("m",)                                            # of q (q̇: m/s), for figure axes

    def vector_field(self, s: Tensor, chart: str) -> Tensor:
        self.check_chart(chart)
        q, qd = split_state(s)                                   # s = (q, q̇) on the last axis, any batch shape
        return torch.cat([qd, -self.alpha * q - self.beta * q**3], -1)

    def energy(self, s: Tensor, chart: str) -> Tensor:
        self.check_chart(chart)
        q, qd = split_state(s)
        return (0.5 * qd**2 + 0.5 * self.alpha * q**2 + 0.25 * self.beta * q**4).sum(-1)

    def sample_initial(self, n: int, generator: torch.Generator) -> Tensor:
        return self.amplitude * (2 * torch.rand(n, 2, generator=generator, dtype=torch.float64) - 1)
