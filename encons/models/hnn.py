"""Hamiltonian models in generalised coordinates (Zhong et al. §3): HNN, HNN-structure, "-angle".

Each learns H(q, p) and integrates q̇ = ∂H/∂p, ṗ = −∂H/∂q (Zhong et al. eq. (6)). Data hold
(q, q̇) only, so a learned M(q) = L Lᵀ maps q̇ → p = M(q) q̇ at the start of a rollout and
p → q̇ = M(q)⁻¹ p on the way out. ``angular=True`` (the "-angle" variants, ``model=*_angle``) embeds
each angle as (cos q, sin q).
"""

from __future__ import annotations

import torch
from torch import Tensor

from encons.infra.batching import batched_grad
from encons.infra.bounds import Count
from encons.models.base import DynamicsModel
from encons.models.networks import MLPTape, mlp
from encons.models.parts import AngleEmbedding, CholeskyMass, embed_angles
from encons.models.structured import MassPotentialModel
from encons.systems.base import System, split_state


class HamiltonianModel(DynamicsModel):
    """ż = J ∇H(z) on z = (q, p); subclasses set ``self.mass`` and define ``hamiltonian``."""

    default_chart = "angle"
    family = "canonical"
    mass: CholeskyMass  # set by every subclass

    def hamiltonian(self, z: Tensor) -> Tensor:
        """H(q, p) of internal states (..., 2n)."""
        raise NotImplementedError

    def to_internal(self, s: Tensor) -> Tensor:
        q, qd = split_state(s)
        return torch.cat([q, (self.mass(q) @ qd.unsqueeze(-1)).squeeze(-1)], -1)

    def from_internal(self, z: Tensor) -> Tensor:
        q, p = split_state(z)
        return torch.cat([q, self.mass.solve(q, p)], -1)

    def hamiltonian_gradient(self, z: Tensor) -> Tensor:
        """∇H (..., 2n) by autodiff of ``hamiltonian`` (any H); the models below write it in closed form."""
        return batched_grad(self.hamiltonian, z)

    def forward(self, t: Tensor, z: Tensor, u: Tensor | None = None) -> Tensor:
        dq, dp = split_state(self.hamiltonian_gradient(z))
        return torch.cat([dp, -dq], -1)


class HNN(HamiltonianModel):
    """Unstructured H(q, p) network (Greydanus et al. 2019; Zhong et al. eq. (6))."""

    def __init__(
        self,
        system: System,
        chart: str | None = None,
        hidden: Count = 256,
        depth: Count = 3,
        activation: str = "softplus",
        mass_eps: float = 1e-3,
        angular: bool = False,
    ):
        super().__init__(system, chart)
        n, self.angular = self.n, angular
        self.hamiltonian_net = mlp(3 * n if self.angular else 2 * n, 1, hidden, depth, activation, out_bias=False)
        self.mass = CholeskyMass(n, self.angular, hidden, depth, activation, mass_eps)

    def hamiltonian(self, z: Tensor) -> Tensor:
        q, p = split_state(z)
        return self.hamiltonian_net(torch.cat([embed_angles(q, self.angular), p], -1)).squeeze(-1)

    def hamiltonian_gradient(self, z: Tensor) -> Tensor:
        """∇H through the network in closed form (``MLPTape``: one forward, one explicit backward)."""
        q, p = split_state(z)
        embedding = AngleEmbedding(q, self.angular)
        tape = MLPTape(self.hamiltonian_net, torch.cat([embedding.x, p], -1))
        g = tape.pullback()
        return torch.cat([embedding.vjp(g[..., : -self.n]), g[..., -self.n :]], -1)


class HNNStructure(HamiltonianModel, MassPotentialModel):
    """H = ½ pᵀ M(q)⁻¹ p + V(q) with learned M and V (SymODEN, Zhong et al. 2020a; eqs. (8)–(9)).

    ½ pᵀ M⁻¹ p = ½ |L⁻¹ p|² by one triangular solve with the Cholesky factor L of M.
    ∇H in closed form: ∇_p H = M⁻¹ p = L⁻ᵀ w (w = L⁻¹ p), and ∇_q H pulls the cotangent of (L, V),
    ∂H/∂L = −M⁻¹p wᵀ and ∂H/∂V = 1, back through the head and the network(s) (``MLPTape``).
    """

    family = "mass_matrix"  # learns M(q) and V(q) like LNNStructure, not an unstructured H
    supports_controls = True  # ṗ = −∂H/∂q + g(q) u (Symplectic ODE-Net, ``encons.models.inputs``)

    def forward(self, t: Tensor, z: Tensor, u: Tensor | None = None) -> Tensor:
        field = super().forward(t, z)
        if u is None:
            return field
        q = z[..., : self.n]
        assert self.input_matrix is not None  # inputs reach only a model built for a system with controls
        return field + torch.cat([torch.zeros_like(q), self.input_matrix.force(q, u)], -1)

    def hamiltonian(self, z: Tensor) -> Tensor:
        q, p = split_state(z)
        factor, potential = self.factor_potential(q)
        return _kinetic(factor, p) + potential

    def hamiltonian_gradient(self, z: Tensor) -> Tensor:
        q, p = split_state(z)
        embedding = AngleEmbedding(q, self.angular)
        x = embedding.x
        tape = MLPTape(self.mass.net, x)
        factor = self.mass.head(tape.out)[0]
        w = torch.linalg.solve_triangular(factor, p.unsqueeze(-1), upper=False)
        g_p = torch.linalg.solve_triangular(factor.transpose(-1, -2), w, upper=True)  # M⁻¹ p
        g_out = self.mass.head_slopes(tape.out) * self.mass.lower_adjoint(
            -g_p @ w.transpose(-1, -2)
        )  # ∂H/∂L = −M⁻¹p wᵀ
        g_p = g_p.squeeze(-1)
        if self.shared_trunk:
            g_x = tape.pullback(torch.cat([g_out, torch.ones_like(g_out[..., :1])], -1))  # ∂H/∂V = 1
        else:
            potential = MLPTape(self.potential_net.net, x)
            g_x = tape.pullback(g_out) + potential.pullback()
        return torch.cat([embedding.vjp(g_x), g_p], -1)


def _kinetic(factor: Tensor, p: Tensor) -> Tensor:
    """½ pᵀ (L Lᵀ)⁻¹ p = ½ |L⁻¹ p|² (one triangular solve)."""
    w = torch.linalg.solve_triangular(factor, p.unsqueeze(-1), upper=False).squeeze(-1)
    return 0.5 * w.square().sum(-1)
