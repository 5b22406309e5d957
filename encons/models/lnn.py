"""Lagrangian models in generalised coordinates (Zhong et al. §3): LNN, LNN-structure, "-angle".

The state is s = (q, q̇) and the field ṡ = (q̇, q̈) with q̈ from the Euler–Lagrange equations
of a learned Lagrangian. ``angular=True`` (the "-angle" variants, ``model=*_angle``) embeds each
angle as (cos q, sin q).
"""

from __future__ import annotations

from typing import Annotated, Callable, cast

import torch
from torch import Tensor
from torch.func import grad, jvp, vjp, vmap

from encons.infra.batching import batched_grad, member_view
from encons.infra.bounds import Count, Range
from encons.infra.errors import PhysicsError
from encons.models.base import DynamicsModel
from encons.models.networks import MLPTape, cranmer_init_, mlp, narrow_in
from encons.models.parts import AngleEmbedding, embed_angles, embedded_width
from encons.models.structured import MassPotentialModel
from encons.systems.base import System, split_state


def lagrangian_derivatives(lagrangian: Callable[[Tensor], Tensor], s: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """∇_q L (..., n), H = ∇_q̇ ∇_q̇ᵀ L (..., n, n) and (∇_q ∇_q̇ᵀ L) q̇ (..., n) at states s = (q, q̇)
    (..., 2n) of a batch-aware scalar L(s), by autodiff (any L).

    ∇L comes from one batched grad; the Hessian rows from n + 1 vector products with it,
    vmapped over the vectors only (reverse over reverse, rather than forward over reverse): (q̇, 0) gives (∇_q ∇_q̇ᵀ L)
    q̇ and (0, e_i) the rows of H.
    """
    n = s.shape[-1] // 2
    qd = s[..., n:]
    units = torch.eye(2 * n, dtype=s.dtype, device=s.device)[n:].reshape(n, *[1] * (s.dim() - 1), 2 * n)
    vectors = torch.cat([torch.cat([qd, torch.zeros_like(qd)], -1)[None], units.expand(n, *s.shape)])
    dl, pullback = cast("tuple[Tensor, Callable]", vjp(lambda u: batched_grad(lagrangian, u), s))  # no has_aux
    (rows,) = vmap(pullback)(vectors)
    return dl[..., :n], rows[1:, ..., n:].movedim(0, -2), rows[0, ..., n:]


def guarded_solve(hessian: Tensor, rhs: Tensor, guard: float) -> Tensor:
    """q̈ from H q̈ = r (..., n, n), (..., n): the plain solve (Cranmer et al.'s inverse) wherever H is
    well conditioned against its own scale, damped least squares where it is near singular.

    With λ = ``guard``·‖H‖_F per sample: x = H⁻¹r (LU) wherever ‖x‖·λ ≤ ‖r‖ — which holds whenever
    σ_min(H) ≥ λ, so a physical M(q) is solved exactly (no bias: the true L gives the true q̈) — and
    elsewhere (near-singular or singular H, NaN) x = (ĤᵀĤ + guard²I)⁻¹Ĥᵀr̂ with Ĥ, r̂ = H, r / ‖H‖_F
    (= (HᵀH + λ²I)⁻¹Hᵀr, without under/overflow), of norm ≤ ‖r‖/(2λ); H = 0 gives 0, the least-squares
    solution of minimum norm. Scale-free: L → cL leaves q̈ unchanged. The switch is per sample and not
    smooth. ``guard=0``: the plain solve (singular H: inf/nan, which training reports as divergence).
    Limits: a true M with σ_min/‖M‖_F < ``guard`` (the gyroscope near gimbal lock, below the data's
    |sin θ| ≥ 0.1) is damped too; the bound scales with 1/‖H‖_F, so it does not stop a learned L whose
    curvature fades along its own trajectory (a softplus L at growing q̇) from running away: that is the
    initialisation's job (``LNN``).
    """
    if guard == 0:
        return torch.linalg.solve_ex(hessian, rhs.unsqueeze(-1))[0].squeeze(-1)
    scale = hessian.flatten(-2).norm(dim=-1)
    eye = torch.eye(hessian.shape[-1], dtype=rhs.dtype, device=rhs.device)
    with torch.no_grad():  # which samples take the plain solve: a mask, no branch on values (a seed ensemble vmaps it)
        x = torch.linalg.solve_ex(hessian, rhs.unsqueeze(-1))[0].squeeze(-1)
        plain = x.norm(dim=-1) * guard * scale <= rhs.norm(dim=-1)  # NaN compares False
    # solved again with I where damped: a damped sample's zero gradient then goes back through the solve as 0,
    # where an exactly singular H (a zero LU pivot) or an overflowed x would send NaN
    x = torch.linalg.solve_ex(torch.where(plain[..., None, None], hessian, eye), rhs.unsqueeze(-1))[0].squeeze(-1)
    unit = torch.where(scale > 0, scale, 1)[..., None, None]  # H/‖H‖: no under/overflow in HᵀH; H = 0 gives q̈ = 0
    h, r = hessian / unit, rhs.unsqueeze(-1) / unit
    ht = h.transpose(-1, -2)
    damped = torch.linalg.solve_ex(ht @ h + guard**2 * eye, ht @ r)[0].squeeze(-1)
    return torch.where(plain.unsqueeze(-1), x, damped)


def typical_speed(system: System, chart: str, draws: int = 1024) -> Tensor:
    """Root mean square of each velocity q̇_i over ``draws`` of the system's initial states (a fixed draw, apart
    from the run's random state); 1 where the initial-state distribution is unknown (latent systems, data files)."""
    try:
        s = system.sample_initial(draws, torch.Generator().manual_seed(0))
    except PhysicsError:
        return torch.ones(system.coord_dim(chart))
    return split_state(system.to_chart(s, system.base_chart, chart))[1].square().mean(0).sqrt().float()


#: Objectives of models whose field is (q̇, q̈) by construction: q̈ alone is a complete target
#: (``acceleration``, Xiao et al. §3), beside the rollout and full-derivative ones.
SECOND_ORDER_OBJECTIVES = ("rollout", "acceleration", "derivative", "onestep")
Guard = Annotated[float, Range(ge=0, lt=1, says="a float in [0, 1) (0: plain Hessian solve)")]


class LNN(DynamicsModel):
    """Unstructured L(q, q̇) network, eq. (3) (Cranmer et al. 2020).

    The network starts from Cranmer et al.'s initialisation scales, shaped as a mechanical Lagrangian:
    ``cranmer_init_(convex=True, potential_inputs=...)`` makes it L = g(q̇) − h(q) with g, h input-convex (weights
    after the first layer non-negative, q and q̇ in disjoint halves of every layer, h's output weights negated),
    and ``input_rms`` caps each velocity's share of a first-layer pre-activation at 2, its RMS over the system's
    initial states (``typical_speed``) times Cranmer's σ₁ = 2.2/√w: a no-op at the default width on every
    benchmark system, it scales the gyroscope's spin ψ̇ (RMS 10.6) at width 16. Only the start: the model class
    (any MLP) and the solve are unchanged. Measured at debug=fast (2 × 16) on fresh networks: Cranmer et al.'s
    signed start left ∇²_q̇ L indefinite on 12-100 % of the data states (q̈ up to 1e4; NaN in the first steps
    on pendulum2 and the gyroscope); a jointly convex start keeps it positive definite but is convex in q
    too, i.e. its potential −L(q, 0) is concave, so the fresh field pushes states away (linearised growth
    rate·dt median 0.21 on mass_spring / Lim & Kasim's pendulum, q̈ outward on 68-84 % of the states) until
    the softplus curvature fades at large |q̇| and the rollout overflows (lnn on mass_spring, glnn on
    pendulum); the separable start oscillates (rate·dt median 0.00). On the gyroscope half the width-16
    first-layer units sat at |z| > 4 on the data (softplus curvature < e⁻⁴). Fresh rollout loss non-finite or
    > 1e3 over 200 draws (jointly convex → this start): lnn / lnn_angle / glnn on the gyroscope 13 / 25 / 19
    → 0 / 0 / 0 (separable without the cap: 2 / 4 / 13); on mass_spring, pendulum, damped_pendulum (dt 0.22)
    lnn 23 / 30 / 38 → 4 / 4 / 9, glnn 25 / 37 / 41 → 5 / 4 / 8, lnn_angle 0 / 0 / 0 → 6 / 6 / 6 (its angle
    embedding bounds the jointly convex potential); pendulum1/2 0 either way. Limits: not a bound — a few
    draws still run away where dt is large; the cap knows no velocities for latent systems and data files;
    it does not keep training stable: lnn_angle on pendulum4 at the defaults (100 epochs) seed 0 destabilised
    from epoch ~15 and diverged at 70 (seeds 1, 2 trained; the jointly convex start's seed 0 trained).

    q̈ takes ``guarded_solve`` with ``guard`` = 1e-3: the plain inverse unless the solution exceeds
    ‖r‖/(1e-3·‖∇²_q̇ L‖_F) (tested: on sampled states of pendulum1/2/4, the gyroscope, the damped oscillator
    and the compound pendulum the true L gives the true q̈ to 1e-6), damped least squares where it is near
    singular; 1e-2 damped true gyroscope states (q̈ off by up to 97 %). (It replaced an absolute Tikhonov guard
    λ = 1, which shrank the true L's q̈ by σ²/(σ² + 1) along M's smallest direction: ×1.4e-4 on the gyroscope.)
    """

    default_chart = "angle"
    objectives = SECOND_ORDER_OBJECTIVES
    family = "lagrangian"

    def __init__(
        self,
        system: System,
        chart: str | None = None,
        hidden: Count = 256,
        depth: Count = 3,
        activation: str = "softplus",
        guard: Guard = 1e-3,
        angular: bool = False,
    ):
        super().__init__(system, chart)
        self.guard, self.angular = guard, angular
        width = embedded_width(self.n, self.angular)
        rms = torch.cat([torch.ones(width), typical_speed(system, self.chart)])
        self.lagrangian_net = cranmer_init_(
            mlp(width + self.n, 1, hidden, depth, activation, out_bias=False),
            convex=True,
            potential_inputs=width,
            input_rms=rms,
        )

    def lagrangian(self, s: Tensor) -> Tensor:
        """L(q, q̇) of states (..., 2n)."""
        q, qd = split_state(s)
        return self.lagrangian_net(torch.cat([embed_angles(q, self.angular), qd], -1)).squeeze(-1)

    def lagrangian_derivatives(self, s: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """``lagrangian_derivatives`` of the network in closed form (``MLPTape``): ∇L from one explicit
        backward; H and (∇_q ∇_q̇ᵀ L) q̇ as the curvature between the directions (0, e_i) and
        (0, e_j), (q̇, 0), i.e. n + 1 forward tangents instead of n + 1 Hessian-vector products."""
        q, qd = split_state(s)
        embedding = AngleEmbedding(q, self.angular)
        tape = MLPTape(self.lagrangian_net, torch.cat([embedding.x, qd], -1))
        g = tape.pullback()
        width = g.shape[-1]
        along = narrow_in(embedding.jvp(qd), tape.first[..., : width - self.n, :])  # W_1 (q̇ through the embedding, 0)
        units = tape.first[..., width - self.n :, :]  # W_1 (0, e_i): columns of W_1, no product (per member if stacked)
        units = units if units.dim() == 2 else member_view(units, along.dim() + 1)
        tangents = tape.hidden_tangents(
            torch.cat([units.expand(*along.shape[:-1], *units.shape[-2:]), along.unsqueeze(-2)], -2)
        )
        curvature = tape.curvature(tangents, rows=self.n)
        return embedding.vjp(g[..., : width - self.n]), curvature[..., : self.n], curvature[..., self.n]

    def forward(self, t: Tensor, s: Tensor, u: Tensor | None = None) -> Tensor:
        dl_dq, hessian, mixed = self.lagrangian_derivatives(s)
        return torch.cat([split_state(s)[1], guarded_solve(hessian, dl_dq - mixed, self.guard)], -1)


def euler_lagrange_terms(
    factor_potential: Callable[[Tensor], tuple[Tensor, Tensor]], q: Tensor, qd: Tensor
) -> tuple[Tensor, Tensor, Tensor]:
    """L_M(q), ∇_q(½ q̇ᵀ M q̇ − V) at fixed q̇ and Ṁ q̇ (each (..., n) but L_M (..., n, n)) for any
    ``factor_potential`` q ↦ (L_M, V), by autodiff: one batched grad of q ↦ ½ |L_Mᵀ q̇|² − V with
    L_M and L̇_M along q̇ from one jvp inside it; Ṁ q̇ = L̇_M L_Mᵀ q̇ + L_M L̇_Mᵀ q̇."""

    def lagrangian(qi: Tensor) -> tuple[Tensor, tuple[Tensor, Tensor]]:
        # without has_aux, torch.func.jvp returns (output, tangent): both (L, V) pairs here
        pairs = cast("tuple[tuple[Tensor, Tensor], tuple[Tensor, Tensor]]", jvp(factor_potential, (qi,), (qd,)))
        (factor, potential), (factor_dot, _) = pairs
        w = (factor.transpose(-1, -2) @ qd.unsqueeze(-1)).squeeze(-1)
        mass_dot_qd = factor_dot @ w.unsqueeze(-1) + factor @ (factor_dot.transpose(-1, -2) @ qd.unsqueeze(-1))
        return (0.5 * w.square().sum(-1) - potential).sum(), (factor, mass_dot_qd.squeeze(-1))

    dl_dq, (factor, mass_dot_qd) = grad(lagrangian, has_aux=True)(q)
    return factor, dl_dq, mass_dot_qd


class LNNStructure(MassPotentialModel):
    """L = ½ q̇ᵀ M(q) q̇ − V(q) with learned M = L_M L_Mᵀ and V, eq. (5) (DeLaN, Lutter et al. 2019).

    q̈ = M⁻¹ [−Ṁ q̇ + ½ ∇_q(q̇ᵀ M q̇) − ∇V], M⁻¹ by the Cholesky factor. The terms in closed form
    through the network(s) (``MLPTape``): one forward (L_M and V from the shared trunk), one
    forward tangent along q̇ for L̇_M (Ṁ = L̇_M L_Mᵀ + L_M L̇_Mᵀ) and one explicit backward of the
    cotangent of ½ |L_Mᵀ q̇|² − V on the outputs for ∇_q, the small head (outputs → L_M) by hand
    (``CholeskyMass.head_slopes``: torch.func on it cost ~10% of a step in decomposed ops);
    ``euler_lagrange_terms`` is the same by autodiff.
    """

    objectives = SECOND_ORDER_OBJECTIVES
    supports_controls = True  # M q̈ = g(q) u + …: the generalised force of ``encons.models.inputs``

    def euler_lagrange_terms(self, q: Tensor, qd: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """``euler_lagrange_terms`` of the model's network(s), in closed form."""
        embedding = AngleEmbedding(q, self.angular)
        x = embedding.x
        tape = MLPTape(self.mass.net, x)
        out_dot = tape.push(embedding.jvp(qd).unsqueeze(-2))[0].squeeze(-2)
        factor, slopes = self.mass.head(tape.out)[0], self.mass.head_slopes(tape.out)
        factor_dot = self.mass.lower(slopes * out_dot[..., : self.mass.entries])
        w = (factor.transpose(-1, -2) @ qd.unsqueeze(-1)).squeeze(-1)
        g_out = slopes * self.mass.lower_adjoint(qd.unsqueeze(-1) * w.unsqueeze(-2))  # ∂(½ |L_Mᵀ q̇|²)/∂L_M = q̇ wᵀ
        if self.shared_trunk:
            g_x = tape.pullback(torch.cat([g_out, -torch.ones_like(g_out[..., :1])], -1))  # ∂(−V)/∂V = −1
        else:
            potential = MLPTape(self.potential_net.net, x)
            g_x = tape.pullback(g_out) - potential.pullback()
        mass_dot_qd = factor_dot @ w.unsqueeze(-1) + factor @ (factor_dot.transpose(-1, -2) @ qd.unsqueeze(-1))
        return factor, embedding.vjp(g_x), mass_dot_qd.squeeze(-1)

    def forward(self, t: Tensor, s: Tensor, u: Tensor | None = None) -> Tensor:
        q, qd = split_state(s)
        factor, dl_dq, mass_dot_qd = self.euler_lagrange_terms(q, qd)
        if u is None:
            rhs = dl_dq - mass_dot_qd
        else:
            assert self.input_matrix is not None  # inputs reach only a model built for a system with controls
            rhs = dl_dq - mass_dot_qd + self.input_matrix.force(q, u)
        return torch.cat([qd, torch.cholesky_solve(rhs.unsqueeze(-1), factor).squeeze(-1)], -1)
