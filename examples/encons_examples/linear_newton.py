"""A user's own model: a linear Newtonian field q̈ = A q + B q̇ with learned n × n matrices A and B."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from encons.models.base import DynamicsModel


class LinearNewton(DynamicsModel):
    """ż = (q̇, A q + B q̇) on the data state z = (q, q̇) (..., 2n); A starts at −``stiffness`` · I, B at 0.

    A linear field cannot follow a nonlinear system for long: it is an example of the contract, not a
    good model. ``super().__init__(system, chart)`` sets ``self.chart`` (the model's chart, default the
    system's first) and ``self.n`` (the coordinate count in that chart)."""

    def __init__(self, system, chart: str | None = None, stiffness: float = 1.0):
        super().__init__(system, chart)
        self.a = nn.Parameter(-stiffness * torch.eye(self.n))
        self.b = nn.Parameter(torch.zeros(self.n, self.n))

    def forward(self, t: Tensor, z: Tensor, u: Tensor | None = None) -> Tensor:
        q, qd = z[..., : self.n], z[..., self.n :]
        return torch.cat([qd, q @ self.a.T + qd @ self.b.T], -1)
