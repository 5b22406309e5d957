"""Physical parts built of the networks: angle embeddings (Zhong et al.'s "-angle" inputs), the Cholesky mass
matrix M(q), the potential V(q) and the Cartesian point masses (Finzi et al.)."""

from __future__ import annotations

import copy
from collections.abc import Sequence

import torch
from torch import Tensor, nn

from encons.models.networks import mlp, run
from encons.systems.base import CartesianLayout, System

Angular = bool | tuple[bool, ...]


def embed_angles(q: Tensor, angular: Angular) -> Tensor:
    """(cos q, sin q) for angle-aware models (Zhong et al. §3, "-angle" variants), else q.

    ``angular`` may mark each coordinate (a tuple of bools): then the translations come first,
    unchanged, followed by (cos, sin) of the marked angles (Santos et al. §5.3, "embeddings").
    """
    if isinstance(angular, bool):
        return torch.cat([torch.cos(q), torch.sin(q)], -1) if angular else q
    angles = q[..., [i for i, a in enumerate(angular) if a]]
    return torch.cat([q[..., [i for i, a in enumerate(angular) if not a]], torch.cos(angles), torch.sin(angles)], -1)


class AngleEmbedding:
    """``embed_angles(q, angular)`` (``x``), with cos and sin of the angles computed once for its forward
    (``jvp``) and reverse (``vjp``) derivatives. A per-coordinate ``angular`` (e.g. the cart-pole's
    (False, True)) keeps the translations first, unchanged, as ``embed_angles`` does."""

    linear: list[int]
    angles: list[int] | slice

    def __init__(self, q: Tensor, angular: Angular):
        self.angular = angular
        if angular is False:
            self.x = q
            return
        if angular is True:
            self.linear, self.angles = [], slice(None)  # a slice: no gathered copy of q
        else:
            self.linear = [i for i, a in enumerate(angular) if not a]
            self.angles = [i for i, a in enumerate(angular) if a]
            self.order = torch.tensor(self.linear + self.angles, device=q.device).argsort()  # [lin, ang] -> q order
        angles = q[..., self.angles]
        self.cos, self.sin = torch.cos(angles), torch.sin(angles)
        self.x = (
            torch.cat([q[..., self.linear], self.cos, self.sin], -1)
            if self.linear
            else torch.cat([self.cos, self.sin], -1)
        )

    def jvp(self, tangent: Tensor) -> Tensor:
        """∂embed_angles(q)/∂q · t for tangents t (..., n)."""
        if self.angular is False:
            return tangent
        angles = tangent[..., self.angles]
        parts = [-self.sin * angles, self.cos * angles]
        return torch.cat([tangent[..., self.linear], *parts] if self.linear else parts, -1)

    def vjp(self, cotangent: Tensor) -> Tensor:
        """gᵀ ∂embed_angles(q)/∂q for cotangents g on the embedding."""
        if self.angular is False:
            return cotangent
        if isinstance(self.angular, bool):
            cos, sin = cotangent.chunk(2, -1)
            return self.cos * sin - self.sin * cos
        k = len(self.linear)
        cos, sin = cotangent[..., k:].chunk(2, -1)
        return torch.cat([cotangent[..., :k], self.cos * sin - self.sin * cos], -1)[..., self.order]


def embedded_width(n: int, angular: Angular) -> int:
    """Width of ``embed_angles`` of n coordinates."""
    return n + (n * angular if isinstance(angular, bool) else sum(angular))


class CholeskyMass(nn.Module):
    """M(q) = L(q) L(q)ᵀ with L lower triangular, softplus diagonal + ``eps`` (Zhong et al. §3).

    With ``extra`` > 0 the same network has ``extra`` more outputs (``factor``): a trunk shared
    with another head, e.g. V(q) in the structured models (one forward for both).
    """

    diag: Tensor  # buffers (register_buffer)
    scatter: Tensor

    def __init__(self, n: int, angular: Angular, hidden: int, depth: int, activation: str, eps: float, extra: int = 0):
        super().__init__()
        self.n, self.angular, self.eps = n, angular, eps
        rows, cols = torch.tril_indices(n, n)
        self.entries = len(rows)
        self.register_buffer("diag", rows == cols, persistent=False)
        self.register_buffer("scatter", nn.functional.one_hot(rows * n + cols, n * n).float(), persistent=False)
        self.net = mlp(embedded_width(n, angular), self.entries + extra, hidden, depth, activation)

    def factor(self, q: Tensor) -> tuple[Tensor, Tensor]:
        """L(q) (..., n, n) and the ``extra`` outputs (..., extra) of one network forward."""
        return self.head(run(self.net, embed_angles(q, self.angular)))

    def head(self, out: Tensor) -> tuple[Tensor, Tensor]:
        """L and the ``extra`` outputs from the network's outputs ``out`` (..., entries + extra)."""
        entries = out[..., : self.entries]
        entries = torch.where(self.diag, nn.functional.softplus(entries) + self.eps, entries)
        return self.lower(entries), out[..., self.entries :]

    def head_slopes(self, out: Tensor) -> Tensor:
        """∂(entry of L)/∂(its output) (..., entries): softplus' σ' (sigmoid) on the diagonal, 1 below."""
        entries = out[..., : self.entries]
        return torch.where(self.diag, torch.sigmoid(entries), torch.ones_like(entries))

    def lower(self, entries: Tensor) -> Tensor:
        """The lower-triangular (..., n, n) matrix with ``entries`` (..., entries) row by row."""
        return (entries @ self.scatter.to(entries)).unflatten(-1, (self.n, self.n))

    def lower_adjoint(self, matrix: Tensor) -> Tensor:
        """Adjoint of ``lower``: the cotangent of the entries for a cotangent ``matrix`` (..., n, n)."""
        return matrix.flatten(-2) @ self.scatter.to(matrix).T

    def cholesky(self, q: Tensor) -> Tensor:
        """L(q), shape (..., n, n)."""
        return self.factor(q)[0]

    def forward(self, q: Tensor) -> Tensor:
        """M(q), shape (..., n, n)."""
        factor = self.cholesky(q)
        return factor @ factor.transpose(-1, -2)

    def solve(self, q: Tensor, p: Tensor) -> Tensor:
        """M(q)⁻¹ p through the Cholesky factor."""
        return torch.cholesky_solve(p.unsqueeze(-1), self.cholesky(q)).squeeze(-1)


class Potential(nn.Module):
    """V(q): an MLP to a scalar, angles embedded on S¹ when ``angular`` (Zhong et al. §3)."""

    def __init__(self, n: int, angular: Angular, hidden: int, depth: int, activation: str):
        super().__init__()
        self.angular = angular
        self.net = mlp(embedded_width(n, angular), 1, hidden, depth, activation, out_bias=False)

    def forward(self, q: Tensor) -> Tensor:
        """V(q), shape ``q.shape[:-1]``."""
        return run(self.net, embed_angles(q, self.angular)).squeeze(-1)


class KnownMass(nn.Module):
    """A system's true M(q) (of its angle chart) behind ``CholeskyMass``'s methods: a model's learned mass matrix
    replaced by the truth (``DynamicsModel.true_counterpart``)."""

    def __init__(self, system: System):
        super().__init__()
        self.system = system

    def cholesky(self, q: Tensor) -> Tensor:
        return torch.linalg.cholesky(self.system.mass_matrix(q))

    def forward(self, q: Tensor) -> Tensor:
        return self.system.mass_matrix(q)

    def solve(self, q: Tensor, p: Tensor) -> Tensor:
        return torch.cholesky_solve(p.unsqueeze(-1), self.cholesky(q)).squeeze(-1)


class KnownPotential(nn.Module):
    """A system's true V(q) (of its angle chart) behind ``Potential``'s call (``DynamicsModel.true_counterpart``)."""

    def __init__(self, system: System):
        super().__init__()
        self.system = system

    def forward(self, q: Tensor) -> Tensor:
        return self.system.potential(q)


class PointMasses(nn.Module):
    """Constant Cartesian masses, exp-parametrised (Zhong et al. §4.1), one set per body of ``layout``.

    A point mass learns its mass; a rigid body its mass and one axis "inertia" per axis point
    (Finzi et al. 2020), kinetic energy ½ m |ẋ_c|² + ½ Σ_i I_i |ẋ_i − ẋ_c|². In body coordinates
    y = T x (y_c = x_c, y_i = x_i − x_c; a point mass is its own row) that is ½ Σ_k c_k |y_k|²
    with c the parameters, so the matrix over points is Mp = Tᵀ diag(c) T and its inverse
    T⁻¹ diag(1/c) T⁻ᵀ in closed form: no loop, no scatter, no matrix inversion per call (T and
    T⁻¹ are constants of the layout). Equals ``point_mass_matrix``.
    """

    frame: Tensor  # buffers (register_buffer)
    frame_inverse: Tensor

    def __init__(self, layout: CartesianLayout):
        super().__init__()
        self.layout = layout
        self.log_params = nn.ParameterList([nn.Parameter(torch.zeros(len(points))) for points in layout.bodies])
        frame = torch.zeros(layout.n_points, layout.n_points, dtype=torch.float64)
        row = 0
        for points in layout.bodies:  # once, at build; rows in the order of the parameters
            for k, point in enumerate(points):
                frame[row, point] = 1.0
                if k and len(points) > 1:
                    frame[row, points[0]] = -1.0
                row += 1
        self.register_buffer("frame", frame.float(), persistent=False)
        self.register_buffer("frame_inverse", torch.linalg.inv(frame).float(), persistent=False)

    @classmethod
    def ensemble(cls, members: Sequence[PointMasses]) -> PointMasses:
        """K members' masses as one whose parameters carry the member axis first, (K, points of the body): its
        matrices come out member-stacked, (K, n_points, n_points) (a seed ensemble's ensemble dimension,
        ``encons.training.stacked``; member k's slices are its own parameters)."""
        out = copy.deepcopy(members[0])
        out.log_params = nn.ParameterList(
            [nn.Parameter(torch.stack([m.log_params[i].detach() for m in members])) for i in range(len(out.log_params))]
        )
        return out

    def params(self) -> Tensor:
        """c: every body's positive parameters, concatenated (n_points,) (member-stacked: (K, n_points))."""
        return torch.cat(list(self.log_params), -1).exp()

    def forward(self) -> Tensor:
        """The (n_points, n_points) mass matrix over points, Tᵀ diag(c) T."""
        return (self.frame.T * self.params().unsqueeze(-2)) @ self.frame

    def inverse(self) -> Tensor:
        """Its inverse T⁻¹ diag(1/c) T⁻ᵀ."""
        return (self.frame_inverse * self.params().reciprocal().unsqueeze(-2)) @ self.frame_inverse.T
