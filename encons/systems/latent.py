"""The coordinates a dynamics model learns in when an observation model (``encons.models.observation``)
maps the data to them: 2n numbers with no known physics, the model's "generalised coordinates".

Their one chart is called ``angle``, the name every model of generalised coordinates (HNN, LNN, ...)
works in; nothing makes them angles. There is no true field, energy or sampler: the truth lives in
the observed system, whose frames or states the metrics compare.
"""

from __future__ import annotations

from encons.infra.errors import ConfigError
from encons.systems.base import DataOnlySystem, System


class LatentSystem(DataOnlySystem):
    """2n latent coordinates of ``observed`` (the system whose observations are encoded)."""

    charts = ("angle",)
    common_chart = "angle"

    def __init__(self, size: int, observed: System):
        if size % 2:
            raise ConfigError(
                f"observation.latent={size}; allowed: an even integer >= 2 (latent states are (q, q̇)-like pairs)"
            )
        self.n = size // 2
        self.name = f"{observed.name} latent"
        self.n_controls = observed.n_controls
