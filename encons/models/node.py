"""Neural ODE baseline (Chen et al. 2018): ṡ = f_θ(s, u), an MLP on the data chart."""

from __future__ import annotations

import torch
from torch import Tensor

from encons.infra.bounds import Count
from encons.models.base import DynamicsModel
from encons.models.networks import mlp
from encons.systems.base import System


class NODE(DynamicsModel):
    """Unstructured vector field; works in any chart (default: the system's base chart).

    With a controlled system the inputs u (..., m) are concatenated to the state at the MLP's input
    (the NODE baseline of Santos et al. §4)."""

    supports_controls = True
    family = "unstructured"

    def __init__(
        self,
        system: System,
        chart: str | None = None,
        hidden: Count = 256,
        depth: Count = 3,
        activation: str = "softplus",
    ):
        super().__init__(system, chart)
        self.net = mlp(2 * self.n + self.n_controls, 2 * self.n, hidden, depth, activation)

    def forward(self, t: Tensor, z: Tensor, u: Tensor | None = None) -> Tensor:
        return self.net(z if u is None else torch.cat([z, u.to(z)], -1))
