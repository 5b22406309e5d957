"""Non-conservative second-order models (Xiao, Zhang & Tang 2024): GLNN and its baseline.

The state is s = (q, q̇) and the field ṡ = (q̇, q̈). ``angular=True`` embeds each angle as
(cos q, sin q) at the networks' inputs. Both train on ``objective=acceleration`` (the paper's
first loss, squared error of q̈) or ``rollout`` (its second, on states).
"""

from __future__ import annotations

import torch
from torch import Tensor

from encons.infra.bounds import Count
from encons.models.base import DynamicsModel
from encons.models.lnn import LNN, SECOND_ORDER_OBJECTIVES, Guard, guarded_solve
from encons.models.networks import mlp
from encons.models.parts import embed_angles, embedded_width
from encons.systems.base import System, split_state


def _inputs(s: Tensor, angular: bool) -> Tensor:
    q, qd = split_state(s)
    return torch.cat([embed_angles(q, angular), qd], -1)


class GLNN(LNN):
    """Generalised Lagrangian neural network, Xiao et al. eq. (11): networks L(q, q̇) and F(q, q̇),

    q̈ = (∇_q̇∇_q̇ᵀ L)⁻¹ [∇_q L − (∇_q∇_q̇ᵀ L) q̇ + F],

    LNN's closed-form ``lagrangian_derivatives`` of the L network (``MLPTape``; tests check them against
    ``encons.models.lnn.lagrangian_derivatives``, torch.func of any L) with F added to the right-hand
    side, and LNN's ``guarded_solve`` (``guard`` 1e-3: the plain inverse of eq. (11) wherever ∇²_q̇L is
    not near singular; 0: always). L starts from
    LNN's initialisation (g(q̇) − h(q), g and h convex; see ``LNN``); F from PyTorch's default. Limits: L and F are not
    identifiable apart (any F can absorb a change of L), so only q̈ is learned, not the energy split.
    """

    def __init__(
        self,
        system: System,
        chart: str | None = None,
        hidden: Count = 200,
        depth: Count = 3,
        activation: str = "softplus",
        guard: Guard = 1e-3,
        angular: bool = False,
    ):
        super().__init__(system, chart, hidden, depth, activation, guard, angular)
        self.force_net = mlp(embedded_width(self.n, angular) + self.n, self.n, hidden, depth, activation)

    def force(self, s: Tensor) -> Tensor:
        """F(q, q̇) of states (..., 2n), shape (..., n)."""
        return self.force_net(_inputs(s, self.angular))

    def forward(self, t: Tensor, s: Tensor, u: Tensor | None = None) -> Tensor:
        dl_dq, hessian, mixed = self.lagrangian_derivatives(s)
        return torch.cat([split_state(s)[1], guarded_solve(hessian, dl_dq - mixed + self.force(s), self.guard)], -1)


class SecondOrder(DynamicsModel):
    """The paper's baseline 2 (Xiao et al. §4.1): q̈ = F(q, q̇) by one MLP, ṡ = (q̇, F(q, q̇))."""

    default_chart = "angle"
    objectives = SECOND_ORDER_OBJECTIVES
    family = "unstructured"

    def __init__(
        self,
        system: System,
        chart: str | None = None,
        hidden: Count = 200,
        depth: Count = 3,
        activation: str = "softplus",
        angular: bool = False,
    ):
        super().__init__(system, chart)
        self.angular = angular
        self.net = mlp(embedded_width(self.n, angular) + self.n, self.n, hidden, depth, activation)

    def forward(self, t: Tensor, s: Tensor) -> Tensor:  # type: ignore[override]  # no inputs: u omitted (DynamicsModel)
        return torch.cat([split_state(s)[1], self.net(_inputs(s, self.angular))], -1)
