"""The Model seam: a learned continuous vector field ż = f(t, z) on an internal state z.

Data come as ``s = (q, q̇)`` in the model's chart; ``encode`` maps them to the internal
state the field acts on (e.g. ``(q, p)`` for Hamiltonian models) and ``decode`` maps back.
The rollout (``encons.integrators.rollout``) is the only place that integrates a model.
"""

from __future__ import annotations

from typing import Callable, ClassVar

import torch
from torch import Tensor, nn

from encons.systems.base import System


class DynamicsModel(nn.Module):
    """Base of every continuous-time model.

    Subclasses set ``default_chart`` (``None``: the system's base chart), may set
    ``needs_constraints`` (True for models that use the system's known Φ), and implement
    ``forward(t, z)``. ``encode``/``decode`` default to the identity.
    """

    default_chart: ClassVar[str | None] = None
    needs_constraints: ClassVar[bool] = False

    def __init__(self, system: System, chart: str | None = None):
        super().__init__()
        self.chart = chart or self.default_chart or system.base_chart
        system.check_chart(self.chart)
        self.n = system.coord_dim(self.chart)

    def encode(self, s: Tensor) -> Tensor:
        """Data-chart state (..., 2n) -> internal state."""
        return s

    def decode(self, z: Tensor) -> Tensor:
        """Internal state -> data-chart state (..., 2n)."""
        return z

    def forward(self, t: Tensor, z: Tensor) -> Tensor:  # noqa: D401 - torchdiffeq signature
        """dz/dt at internal states ``z`` of any batch shape."""
        raise NotImplementedError

    def constrained_field(self, s: Tensor) -> tuple[Tensor, Callable[[Tensor], Tensor]]:
        """Points and per-sample field that soft dynamics constraints (``encons.regularisers``) act on.

        Default: the internal field at ``encode(s)``; for a model whose ``encode`` is a learned
        invertible map this is the latent field, as in Lim & Kasim eq. (7).
        """
        t = torch.zeros((), dtype=s.dtype, device=s.device)
        return self.encode(s), lambda z: self(t, z)
