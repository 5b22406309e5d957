"""Damped pendulum observed in redundant Cartesian states (Lim & Kasim 2023, Task 4).

θ̈ = −(g/l) sin θ − α θ̇ with m = l = g = 1, α = 0.05, observed as (x, y, ẋ, ẏ) with
x = l sin θ, y = −l cos θ. The chain of ``NPendulum`` with every angle's acceleration
damped by −α q̇; as ẋ = (∂x/∂q) q̇, the Cartesian acceleration is damped by −α ẋ on the
constraint manifold. The Cartesian chart comes first: it is the one observed, simulated and
served to models that work in any chart. With ``frame_size`` it is observed by frames as well
(``system=pixel_damped_pendulum``, Lim & Kasim §6.2).
"""

from __future__ import annotations

import torch
from torch import Tensor

from encons.infra.bounds import Count, NonNegative, Positive
from encons.systems.base import split_state
from encons.systems.pendulum import NPendulum, PerLink, Pixels


class DampedPendulum(NPendulum):
    """``NPendulum`` with damping rate ``damping`` (α) on every link; energy decays."""

    charts = ("cartesian", "angle")

    def __init__(
        self,
        n_links: Count = 1,
        masses: PerLink = 1.0,
        lengths: PerLink = 1.0,
        g: NonNegative = 1.0,
        damping: NonNegative = 0.05,
        init_scale: Positive = 1.0,
        frame_size: Pixels | None = None,
        rate_scale: NonNegative | None = None,
    ):
        super().__init__(n_links, masses, lengths, g, init_scale, frame_size, rate_scale)
        self.name = ("pixel_" if frame_size else "") + "damped_pendulum" + ("" if n_links == 1 else str(n_links))
        self.damping = float(damping)

    def vector_field(self, s: Tensor, chart: str) -> Tensor:  # type: ignore[override]  # no inputs: u omitted (System.field)
        _, qd = split_state(s)
        return super().vector_field(s, chart) - self.damping * torch.cat([torch.zeros_like(qd), qd], -1)

    def sample_initial(self, n: int, generator: torch.Generator) -> Tensor:
        """Angles ~ N(0, init_scale²) and rates ~ N(0, rate_scale²) (both init_scale by default, as in the
        paper), mapped to the Cartesian chart."""
        return self.to_chart(super().sample_initial(n, generator), "angle", "cartesian")
