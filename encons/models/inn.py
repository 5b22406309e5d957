"""Neural ODE in the latent coordinates of an invertible network (Lim & Kasim 2023, §3.2).

z = g(s) (eq. (5)), g a stack of Glow-style blocks (Kingma & Dhariwal 2018; the layout of
FrEIA's ``AllInOneBlock`` the authors used): an affine coupling with soft-clamped log-scales,
a global affine scaling and a fixed random rotation. The latent field ż = f(z) is an MLP.
Rollouts integrate z and map back with g⁻¹ (``from_internal``), which is integrating the pushed-back field
ṡ = (∂g⁻¹/∂z) f(g(s)) of eq. (6) (``encons.numerics.integrators.state_derivative`` evaluates it);
regularisers act on f at g(s), eq. (7).
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import cast

import torch
from torch import Tensor, nn

from encons.infra.batching import member_view, product
from encons.infra.bounds import Count, Positive
from encons.infra.errors import ConfigError
from encons.models.base import DynamicsModel
from encons.models.networks import mlp
from encons.systems.base import System


def random_rotation(dim: int) -> Tensor:
    """A random matrix of SO(dim), drawn from torch's global generator."""
    q, r = torch.linalg.qr(torch.randn(dim, dim))
    q = q * torch.sign(torch.diagonal(r))
    if torch.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


class CouplingBlock(nn.Module):
    """y = R (e^a ⊙ (x₁, x₂ ⊙ e^{c·tanh(s(x₁)/c)} + t(x₁)) + b), invertible in closed form.

    The coupling network's last layer starts at zero, so a fresh block is the rotation R.
    """

    rotation: Tensor  # a buffer (register_buffer)

    def __init__(self, dim: int, hidden: int, depth: int, activation: str, clamp: float):
        super().__init__()
        if dim < 2:
            raise ConfigError(f"model=inn_node on a state of {dim} entry; allowed: systems with >= 2 state entries")
        self.split, self.clamp = dim - dim // 2, float(clamp)
        self.coupling = mlp(self.split, 2 * (dim // 2), hidden, depth, activation)
        last = cast(nn.Linear, self.coupling[-1])  # an mlp ends in a Linear layer
        nn.init.zeros_(last.weight)
        nn.init.zeros_(last.bias)
        self.log_scale = nn.Parameter(torch.zeros(dim))
        self.offset = nn.Parameter(torch.zeros(dim))
        self.register_buffer("rotation", random_rotation(dim))

    @classmethod
    def ensemble(cls, members: Sequence[CouplingBlock]) -> CouplingBlock:
        """K members' blocks as one whose own scales, offsets and rotations carry the member axis first ((K, dim),
        (K, dim, dim)), acting per member on rows (K, ..., dim) whose leading axis is the member axis (a seed
        ensemble's ensemble dimension, ``encons.training.stacked``, which stacks the coupling networks' layers
        itself)."""
        out = copy.deepcopy(members[0])
        out.log_scale = nn.Parameter(torch.stack([m.log_scale.detach() for m in members]))
        out.offset = nn.Parameter(torch.stack([m.offset.detach() for m in members]))
        out.rotation = torch.stack([m.rotation for m in members])
        return out

    def _per_member(self, v: Tensor, x: Tensor) -> Tensor:
        """A vector of the block, (dim,) or member-stacked (K, dim), broadcastable against rows ``x``."""
        return v if v.dim() == 1 else member_view(v, x.dim())

    def _affine(self, x1: Tensor) -> tuple[Tensor, Tensor]:
        s, t = self.coupling(x1).chunk(2, -1)
        return self.clamp * torch.tanh(s / self.clamp), t

    def forward(self, x: Tensor) -> Tensor:
        x1, x2 = x[..., : self.split], x[..., self.split :]
        s, t = self._affine(x1)
        u = torch.cat([x1, x2 * torch.exp(s) + t], -1)
        return product(
            u * torch.exp(self._per_member(self.log_scale, u)) + self._per_member(self.offset, u),
            self.rotation.transpose(-1, -2),
        )

    def inverse(self, y: Tensor) -> Tensor:
        # R⁻¹, not Rᵀ: R drawn in float32 is orthogonal to ~1e-7 only, which a float64 model would inherit.
        rotated = product(y, torch.linalg.inv(self.rotation).transpose(-1, -2))
        u = (rotated - self._per_member(self.offset, y)) * torch.exp(-self._per_member(self.log_scale, y))
        u1, u2 = u[..., : self.split], u[..., self.split :]
        s, t = self._affine(u1)
        return torch.cat([u1, (u2 - t) * torch.exp(-s)], -1)


class InvertibleNet(nn.Module):
    """g = block_K ∘ … ∘ block_1 and its exact inverse, on the last axis of any batch shape."""

    def __init__(
        self,
        dim: int,
        blocks: int = 8,
        hidden: int = 100,
        depth: int = 1,
        activation: str = "softplus",
        clamp: float = 2.0,
    ):
        super().__init__()
        self.blocks = nn.ModuleList(CouplingBlock(dim, hidden, depth, activation, clamp) for _ in range(blocks))

    def forward(self, x: Tensor) -> Tensor:
        for block in self.blocks:
            x = block(x)
        return x

    def inverse(self, z: Tensor) -> Tensor:
        for block in reversed(self.blocks):
            z = cast(CouplingBlock, block).inverse(z)  # the ModuleList holds CouplingBlocks only
        return z


class INNNODE(DynamicsModel):
    """Latent MLP field on z = g(s); works in any chart (default: the system's base chart).

    Sizes default to the paper's: MLP of 2 hidden layers × 200, INN of 8 blocks whose
    coupling networks have one hidden layer of 100 (two linear layers).
    """

    family = "unstructured"

    def __init__(
        self,
        system: System,
        chart: str | None = None,
        hidden: Count = 200,
        depth: Count = 2,
        activation: str = "softplus",
        blocks: Count = 8,
        block_hidden: Count = 100,
        block_depth: Count = 1,
        clamp: Positive = 2.0,
    ):
        super().__init__(system, chart)
        self.inn = InvertibleNet(2 * self.n, blocks, block_hidden, block_depth, activation, clamp)
        self.net = mlp(2 * self.n, 2 * self.n, hidden, depth, activation)

    def to_internal(self, s: Tensor) -> Tensor:
        return self.inn(s)

    def from_internal(self, z: Tensor) -> Tensor:
        return self.inn.inverse(z)

    def forward(self, t: Tensor, z: Tensor) -> Tensor:  # type: ignore[override]  # no inputs: u omitted (DynamicsModel)
        return self.net(z)
