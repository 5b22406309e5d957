"""Shared base of the structured models: learned M(q) = L Lᵀ and V(q) (Zhong et al. eqs. (4), (8))."""

from __future__ import annotations

from torch import Tensor

from encons.models.base import DynamicsModel
from encons.models.networks import CholeskyMass, Potential
from encons.systems.base import System


class MassPotentialModel(DynamicsModel):
    """Learns ``mass`` (Cholesky M(q), ``forward``/``solve``) and ``potential`` V(q); "-angle" via ``angular``."""

    default_chart = "angle"

    def __init__(self, system: System, chart: str | None = None, hidden: int = 256, depth: int = 3,
                 activation: str = "softplus", mass_eps: float = 1e-3, angular: bool = False):
        super().__init__(system, chart)
        self.angular = angular
        self.mass = CholeskyMass(self.n, self.angular, hidden, depth, activation, mass_eps)
        self.potential_net = Potential(self.n, self.angular, hidden, depth, activation)

    def potential(self, q: Tensor) -> Tensor:
        """V(q)."""
        return self.potential_net(q)
