"""How a model's inputs u enter its dynamics: the generalised force g(q) u (``model.input_matrix``).

Symplectic ODE-Net (SymODEN; Zhong, Dey & Chakraborty, "Symplectic ODE-Net: Learning Hamiltonian
Dynamics with Control", ICLR 2020) adds inputs to a Hamiltonian model in port-Hamiltonian form,
q̇ = ∂H/∂p, ṗ = −∂H/∂q + g(q) u, with the input matrix g(q) (n, m) a network of q; in Lagrangian form
the same force gives M(q) q̈ = g(q) u − Ṁ q̇ + ½ ∇_q(q̇ᵀ M q̇) − ∇V (Santos et al. eq. (4), B = g). Two
choices:

- ``known``: g = B, the system's constant input matrix (``System.input_matrix``: where the physics says
  which coordinate the input pushes, e.g. the force on the cart-pole's cart), nothing learned;
- ``learned``: g(q) an MLP of q (angles embedded on S¹ as the model's other networks), as SymODEN.
"""

from __future__ import annotations

from torch import Tensor, nn

from encons.infra.errors import ConfigError
from encons.models.networks import mlp, run
from encons.models.parts import embed_angles, embedded_width
from encons.systems.base import System

INPUT_MATRICES = ("known", "learned")


class InputMatrix(nn.Module):
    """g(q) (..., n, m): the system's constant B (``known``) or an MLP of q (``learned``)."""

    constant: Tensor  # a buffer (register_buffer), for ``known``

    def __init__(self, system: System, kind: str, n: int, angles, hidden: int, depth: int, activation: str):
        super().__init__()
        if kind not in INPUT_MATRICES:
            raise ConfigError(f"model.input_matrix={kind}; allowed: {', '.join(INPUT_MATRICES)}")
        self.kind, self.n, self.m, self.angles = kind, n, system.n_controls, angles
        if kind == "known":
            self.register_buffer("constant", system.input_matrix().float(), persistent=False)
        else:
            self.net = mlp(embedded_width(n, angles), n * self.m, hidden, depth, activation)

    def forward(self, q: Tensor) -> Tensor:
        """g(q) (..., n, m); the constant B broadcasts for ``known``."""
        if self.kind == "known":
            return self.constant.to(q)
        return run(self.net, embed_angles(q, self.angles)).unflatten(-1, (self.n, self.m))

    def force(self, q: Tensor, u: Tensor) -> Tensor:
        """g(q) u (..., n)."""
        return (self(q) @ u.to(q).unsqueeze(-1)).squeeze(-1)


def input_matrix(
    system: System, kind: str, n: int, angles, hidden: int, depth: int, activation: str
) -> InputMatrix | None:
    """The model's ``InputMatrix``, or None for a system without inputs (no unused parameters)."""
    return InputMatrix(system, kind, n, angles, hidden, depth, activation) if system.n_controls else None
