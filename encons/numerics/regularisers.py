"""Soft dynamics constraints of Lim & Kasim (TMLR 2023) as weighted loss penalties.

A regulariser is called as ``regulariser(model, s, u)`` on data-chart states ``s`` (B, 2n)
(and their inputs ``u`` (B, m), or None) and
returns ``weight`` times its constraint averaged over the batch. It acts on the field a model
exposes through ``DynamicsModel.constrained_field`` (by default the internal field at
``to_internal(s)``), whose Jacobians come from ``torch.func`` (jacfwd or jacrev under vmap) and stay
differentiable with respect to the model's parameters.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Callable

import torch
from torch import Tensor
from torch.func import jacfwd, jacrev, vmap

from encons.infra.bounds import Declared, NonNegative
from encons.infra.errors import ConfigError
from encons.models.base import DynamicsModel

JACOBIANS: dict[str, Callable[..., Callable[..., Tensor]]] = {"forward": jacfwd, "reverse": jacrev}


def field_jacobian(field: Callable[..., Tensor], z: Tensor, mode: str = "reverse", u: Tensor | None = None) -> Tensor:
    """∂f/∂z of a per-sample field ``f(z_i)`` (``f(z_i, u_i)`` with inputs ``u`` (B, m)) at points
    ``z`` (B, d); shape (B, d, d).

    ``mode="forward"`` (jacfwd) is wrong in torch 2.13 for fields calling ``torch.linalg.solve``
    (vmap of jacfwd of solve); ``"reverse"`` (jacrev) has no such limit.
    """
    if u is None:
        return vmap(JACOBIANS[mode](field))(z)
    return vmap(JACOBIANS[mode](field))(z, u)  # differentiates the first argument only


def hamiltonian_violation(jac: Tensor) -> Tensor:
    """C_H = ‖Jᵀ A − Aᵀ J‖²_F of Jacobians A (..., 2n, 2n), J = [[0, I], [−I, 0]] (eq. (4)).

    Zero exactly when J⁻¹A is symmetric, i.e. when the field is J∇H locally (Theorem 3.1).
    """
    n = jac.shape[-1] // 2
    jt_a = torch.cat([-jac[..., n:, :], jac[..., :n, :]], -2)
    return ((jt_a - jt_a.transpose(-1, -2)) ** 2).sum((-1, -2))


def dissipative_violation(jac: Tensor, bound: Tensor) -> Tensor:
    """C_D = Σ_i max(0, Re λ_i(A) − a_i)² of Jacobians A (..., d, d) (eq. (8)).

    ``bound`` holds one a for every eigenvalue or one a_i per eigenvalue, the latter matched
    to the eigenvalues sorted by decreasing real part.
    """
    real = torch.linalg.eigvals(jac).real.sort(-1, descending=True).values
    return (torch.relu(real - bound) ** 2).sum(-1)


class JacobianPenalty(Declared):
    """``weight`` × batch mean of a constraint on the Jacobian of the model's constrained field."""

    config_key = "regulariser"

    def __init__(self, weight: NonNegative = 1.0, jacobian: str = "reverse"):
        if jacobian not in JACOBIANS:
            raise ConfigError(f"regulariser.jacobian={jacobian!r} is unknown; allowed: {', '.join(JACOBIANS)}")
        self.weight, self.jacobian = float(weight), jacobian

    def violation(self, jac: Tensor) -> Tensor:
        """The constraint per Jacobian (B, d, d) -> (B,)."""
        raise NotImplementedError

    def __call__(self, model: DynamicsModel, s: Tensor, u: Tensor | None = None) -> Tensor:
        z, field = model.constrained_field(s, u)
        jac = field_jacobian(
            field, z.reshape(-1, z.shape[-1]), self.jacobian, None if u is None else u.reshape(-1, u.shape[-1])
        )
        return self.weight * self.violation(jac).mean()


class Hamiltonian(JacobianPenalty):
    """C_H of Lim & Kasim eq. (4) (eq. (7) when the field lives in learned latent coordinates)."""

    label = "C_H"

    def violation(self, jac: Tensor) -> Tensor:
        if jac.shape[-1] % 2:
            raise ConfigError(f"regulariser=hamiltonian needs an even field dimension, got {jac.shape[-1]}")
        return hamiltonian_violation(jac)


class Dissipative(JacobianPenalty):
    """C_D of Lim & Kasim eq. (8); ``bound`` is one a for all eigenvalues or a list of a_i."""

    label = "C_D"

    def __init__(self, weight: NonNegative = 1.0, bound: float | Sequence[float] = 0.0, jacobian: str = "reverse"):
        super().__init__(weight, jacobian)
        self.bound = torch.as_tensor(bound if isinstance(bound, (int, float)) else list(bound), dtype=torch.float64)

    def violation(self, jac: Tensor) -> Tensor:
        if self.bound.numel() not in (1, jac.shape[-1]):
            raise ConfigError(
                f"regulariser.bound has {self.bound.numel()} entries; give one number or "
                f"{jac.shape[-1]} (one per eigenvalue of the {jac.shape[-1]}-dim field)"
            )
        return dissipative_violation(jac, self.bound.to(jac).reshape(-1))


def from_paper_weight(weight: float, constraint: str, state_dim: int) -> float:
    """encons' ``regulariser.weight`` equivalent to Lim & Kasim's ``weight`` on a ``state_dim``-dim field.

    Their loss is the entry mean of the squared derivative error plus ``weight`` × the entry mean
    of the constraint ((2n)² Jacobian entries for C_H, 2n eigenvalues for C_D); encons sums both
    (``objective=derivative`` sums the 2n squared errors). Multiplying their loss by 2n gives
    encons' form, so the weight is ``weight / 2n`` for ``hamiltonian`` and ``weight`` for
    ``dissipative``. E.g. Task 1 (mass-spring, 2n = 2): 1e5 → 5e4.
    """
    scale = {"hamiltonian": 1.0 / state_dim, "dissipative": 1.0}
    if constraint not in scale:
        raise ConfigError(f"regulariser={constraint!r} has no paper weight; allowed: {', '.join(scale)}")
    return weight * scale[constraint]
