"""Neural ODE baseline (Chen et al. 2018): ṡ = f_θ(s), an MLP on the data chart."""

from __future__ import annotations

from torch import Tensor

from encons.models.base import DynamicsModel
from encons.models.networks import mlp
from encons.systems.base import System


class NODE(DynamicsModel):
    """Unstructured vector field; works in any chart (default: the system's base chart)."""

    def __init__(self, system: System, chart: str | None = None, hidden: int = 256, depth: int = 3,
                 activation: str = "softplus"):
        super().__init__(system, chart)
        self.net = mlp(2 * self.n, 2 * self.n, hidden, depth, activation)

    def forward(self, t: Tensor, z: Tensor) -> Tensor:
        return self.net(z)
