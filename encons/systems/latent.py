"""The coordinates a dynamics model learns in when an observation model (``encons.models.observation``)
maps the data to them: 2n numbers with no known physics, the model's "generalised coordinates".

Their one chart is called ``angle``, the name every model of generalised coordinates (HNN, LNN, ...)
works in; nothing makes them angles. There is no true field, energy or sampler: the truth lives in
the observed system, whose frames or states the metrics compare.
"""

from __future__ import annotations

import torch
from torch import Tensor

from encons.errors import ChartError, ConfigError
from encons.systems.base import System


class LatentSystem(System):
    """2n latent coordinates of ``observed`` (the system whose observations are encoded)."""

    charts = ("angle",)
    common_chart = "angle"
    known_physics = False

    def __init__(self, size: int, observed: System):
        if size % 2:
            raise ConfigError(f"observation.latent={size}; allowed: an even integer >= 2 (latent states are (q, q̇)-like pairs)")
        self.n = size // 2
        self.name = f"{observed.name} latent"
        self.n_controls = observed.n_controls

    def coord_dim(self, chart: str) -> int:
        self.check_chart(chart)
        return self.n

    def _none(self, what: str):
        raise ChartError(f"system '{self.name}' has no known {what}: it is learned")

    def vector_field(self, s: Tensor, chart: str, u: Tensor | None = None) -> Tensor:
        self._none("vector field")

    def energy(self, s: Tensor, chart: str) -> Tensor:
        self._none("energy")

    def sample_initial(self, n: int, generator: torch.Generator) -> Tensor:
        self._none("initial-condition distribution")
