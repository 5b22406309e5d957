"""N-link planar pendulum (Zhong et al. §4.1; Finzi et al. 2020 "ChainPendulum").

Angle chart: absolute angle of each link from the downward vertical and its rate.
Cartesian chart: the N bobs in 2D (D = 2N) with constraints |x_1|² = l_1² (tether to the
pivot) and |x_i − x_{i−1}|² = l_i². Gravity points along −y.
With ``frame_size`` set the chain is also observed by square grey-scale frames (Gym's pendulum
picture, ``encons.systems.render``): ``system=pixel_pendulum`` (Lim & Kasim 2023, §6.1).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Annotated

import torch
from torch import Tensor

from encons.infra.bounds import Count, NonNegative, Positive, Range
from encons.infra.errors import ConfigError
from encons.systems.base import CartesianLayout, PointSystem, point_mass_matrix, split_state
from encons.systems.constrained import DistanceConstraints
from encons.systems.render import render_rods

RENDER_BLOCK = 4096  # frames drawn per batched expression (bounds the renderer's memory)
PerLink = Positive | Sequence[Positive]  # one value for every link, or one per link
Pixels = Annotated[int, Range(ge=4, says=">= 4 pixels")]


def _per_link(value: float | Sequence[float], n: int, what: str) -> Tensor:
    vals = [float(value)] * n if isinstance(value, (int, float)) else [float(v) for v in value]
    if len(vals) != n:
        raise ConfigError(
            f"system.{what}={value!r} does not fit {n} link(s); allowed: one positive number or {n} of them"
        )
    return torch.tensor(vals, dtype=torch.float64)


class NPendulum(PointSystem):
    """Chain of ``n_links`` point masses on massless rods, hanging from a fixed pivot."""

    def __init__(
        self,
        n_links: Count = 2,
        masses: PerLink = 1.0,
        lengths: PerLink = 1.0,
        g: NonNegative = 9.81,
        init_scale: Positive = 1.0,
        frame_size: Pixels | None = None,
        rate_scale: NonNegative | None = None,
    ):
        self.frame_shape = None if frame_size is None else (frame_size, frame_size)
        self.name = f"pendulum{n_links}" if frame_size is None else f"pixel_pendulum{'' if n_links == 1 else n_links}"
        self.n = n_links
        self.m = _per_link(masses, n_links, "masses")
        self.l = _per_link(lengths, n_links, "lengths")
        self.g = float(g)
        self.init_scale = float(init_scale)
        self.rate_scale = self.init_scale if rate_scale is None else float(rate_scale)
        self.mu = self.m.flip(0).cumsum(0).flip(0)  # μ_k = Σ_{j≥k} m_j
        idx = torch.arange(n_links)
        self.coeff = self.mu[torch.maximum(idx[:, None], idx[None, :])] * self.l[:, None] * self.l[None, :]
        self.layout = CartesianLayout(n_links, 2, tuple((i,) for i in range(n_links)))
        self.constraints = DistanceConstraints(
            n_links, 2, [(0, -1)] + [(k, k - 1) for k in range(1, n_links)], self.l.tolist()
        )  # tether, then rods

    def _consts(self, like: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        return (self.m.to(like), self.l.to(like), self.mu.to(like))

    def mass_matrix(self, q: Tensor) -> Tensor:
        """M(q)_ij = μ_max(i,j) l_i l_j cos(q_i − q_j)."""
        return self.coeff.to(q) * torch.cos(q[..., :, None] - q[..., None, :])

    def potential(self, q: Tensor) -> Tensor:
        _, length, mu = self._consts(q)
        return -self.g * (mu * length * torch.cos(q)).sum(-1)

    def point_masses(self) -> Tensor:
        """The true (n_points, n_points) Cartesian mass matrix over points."""
        return point_mass_matrix(self.layout, list(self.m.reshape(-1, 1)))

    def cartesian_potential(self, x: Tensor) -> Tensor:
        return self.g * (self.m.to(x) * x[..., 1::2]).sum(-1)

    def cartesian_potential_gradient(self, x: Tensor) -> Tensor:
        grad_v = torch.zeros_like(x)
        grad_v[..., 1::2] = self.g * self.m.to(x)
        return grad_v

    def acceleration(self, q: Tensor, qd: Tensor) -> Tensor:
        _, length, mu = self._consts(q)
        coeff = self.coeff.to(q)
        diff = q[..., :, None] - q[..., None, :]
        coriolis = (coeff * torch.sin(diff) * qd[..., None, :] ** 2).sum(-1)
        gravity = self.g * mu * length * torch.sin(q)
        return torch.linalg.solve(coeff * torch.cos(diff), -(coriolis + gravity))

    def sample_initial(self, n: int, generator: torch.Generator) -> Tensor:
        scale = torch.tensor([self.init_scale] * self.n + [self.rate_scale] * self.n, dtype=torch.float64)
        return scale * torch.randn(n, 2 * self.n, generator=generator, dtype=torch.float64)

    def render(self, s: Tensor, chart: str) -> Tensor:
        """Frames (..., H, W) float32 in [0, 1]: every rod drawn from its bob positions (pivot in the
        centre, y up), in blocks of ``RENDER_BLOCK`` frames."""
        if self.frame_shape is None:
            return super().render(s, chart)
        bobs = self.to_chart(s, chart, "cartesian")[..., : 2 * self.n].unflatten(-1, (self.n, 2)).float()
        flat = bobs.reshape(-1, self.n, 2)
        frames = [render_rods(block, self.l, self.frame_shape[0]) for block in flat.split(RENDER_BLOCK)]
        return torch.cat(frames).reshape(*bobs.shape[:-2], *self.frame_shape)

    def map_chart(self, s: Tensor, src: str, dst: str) -> Tensor:
        q, qd = split_state(s)
        length = self.l.to(s)
        if src == "angle":
            seg = torch.stack([torch.sin(q), -torch.cos(q)], -1) * length[:, None]
            vel = torch.stack([torch.cos(q), torch.sin(q)], -1) * (length * qd)[..., None]
            return torch.cat([seg.cumsum(-2).flatten(-2), vel.cumsum(-2).flatten(-2)], -1)
        pts, vel = q.unflatten(-1, (self.n, 2)), qd.unflatten(-1, (self.n, 2))
        seg = torch.cat([pts[..., :1, :], pts[..., 1:, :] - pts[..., :-1, :]], -2)
        dseg = torch.cat([vel[..., :1, :], vel[..., 1:, :] - vel[..., :-1, :]], -2)
        angle = torch.atan2(seg[..., 0], -seg[..., 1])
        rate = (seg[..., 0] * dseg[..., 1] - seg[..., 1] * dseg[..., 0]) / (seg**2).sum(-1)
        return torch.cat([angle, rate], -1)
