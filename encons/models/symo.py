"""Symplectic Momentum networks (Santos, Ekal & Ventura, §5–6): SyMo and E2E-SyMo.

A learned Lagrangian L = ½ q̇ᵀ M(q) q̇ − V(q) (eq. (1)), M = L Lᵀ through a Cholesky factor (§5.2),
is discretised by the midpoint rule (eqs. (12)–(13)):

    L_d(a, b) = h [½ vᵀ M(m) v − V(m)],   v = (b − a)/h,   m = (a + b)/2,

(eq. (13) prints no ½; it follows eq. (1)). The forced discrete Euler–Lagrange (DEL) equations
(eqs. (7), (15)) at step k are

    g_k(q_{k+1}) = D₂L_d(q_{k−1}, q_k) + D₁L_d(q_k, q_{k+1}) + (h/2) B (u_{k−1} + u_k) = 0,

the midpoint forces of eq. (14) with u held constant over each data step (the rollout seam's
zero-order hold, so u_{k+1/2} = u_k) and B the system's input matrix. A rollout solves g_k = 0 for
q_{k+1} by batched Newton (one linear solve per iteration for the whole batch), from the guess
2q_k − q_{k−1} (§6), until each sample's RMS residual is ≤ ``tol`` or ``iters`` iterations, each step
halved until it lowers the sample's residual (backtracking); a root-find that ends above ``tol`` is
counted and reported (``newton_unconverged`` among the test metrics), never returned silently;
velocities come from the discrete Legendre transform p_{k+1} = D₂L_d(q_k, q_{k+1}) + (h/2) B u_k,
q̇ = M(q)⁻¹ p. The gradient of a root is implicit (Theorem 1, eq. (16)): Newton's iterations are
not differentiated.
"""

from __future__ import annotations

import copy
from typing import Annotated, Callable, ClassVar, cast

import torch
from torch import Tensor
from torch.func import grad, vjp, vmap

from encons.infra.bounds import Count, Positive, Range
from encons.infra.errors import ConfigError
from encons.models.base import DiscreteModel, DynamicsModel, EnergyStructure, angle_mask
from encons.models.parts import CholeskyMass, KnownMass, KnownPotential, Potential
from encons.systems.base import System


class ImplicitRoot(torch.autograd.Function):
    """Identity on a root q* of g(q*, x; θ) = 0 whose backward is the implicit-function gradient.

    Inputs: ``residual`` = g(q*, x; θ) evaluated with its autograd graph (≈ 0), ``jacobian`` ∂g/∂q*
    (..., n, n) at the root, and the root. Backward solves Jᵀ λ = ∂L/∂q* and sends −λ into g's graph,
    giving ∂L/∂θ = −λᵀ ∂g/∂θ (Santos et al. Theorem 1, eq. (16)) and the same for the inputs x.
    """

    @staticmethod
    def forward(ctx, residual: Tensor, jacobian: Tensor, root: Tensor) -> Tensor:
        ctx.save_for_backward(jacobian)
        return root.clone()

    @staticmethod
    def backward(ctx, grad_root: Tensor):
        (jacobian,) = ctx.saved_tensors
        lam = torch.linalg.solve(jacobian.transpose(-1, -2), grad_root.unsqueeze(-1)).squeeze(-1)
        return -lam, None, None


class SyMo(DiscreteModel):
    """SyMo (Santos et al. §5): M(q), V(q) in the midpoint DEL equations, trained on their residual (eq. (15)).

    Rolled out by Newton on the learned DEL (eq. (11)). ``angular`` embeds the system's angles as
    (cos q, sin q) (§5.3). Newton stops at RMS residual ``train_tol`` / ``train_iters`` in training
    mode, ``eval_tol`` / ``eval_iters`` otherwise (§7: 1e-5 / 10 and 1e-4 / 10); ``backtracks`` halvings
    of a step that would raise the residual (§7 gives plain Newton; the safeguard keeps an iterate from
    moving where the learned DEL's residual grows). Limits: B is constant
    (control-affine forcing, eq. (14)); a singular ∂g/∂q_{k+1} leaves that sample's iterate where it
    is, counted as not converged.
    """

    default_chart = "angle"
    supports_controls = True
    objectives: ClassVar[tuple[str, ...]] = ("residual", "rollout")
    family = "discrete_lagrangian"  # M(q) and V(q) inside a discrete Lagrangian (eqs. (12)–(13))
    headline = ("newton_unconverged",)  # Newton root-finds that did not converge (``diagnostics``)
    input_matrix: Tensor  # a buffer (register_buffer): the system's constant B

    def __init__(
        self,
        system: System,
        chart: str | None = None,
        hidden: Count = 128,
        depth: Count = 2,
        activation: str = "tanh",
        mass_eps: float = 1e-3,
        angular: bool = True,
        train_tol: Positive = 1e-5,
        train_iters: Count = 10,
        eval_tol: Positive = 1e-4,
        eval_iters: Count = 10,
        backtracks: Annotated[int, Range(ge=0)] = 8,
        input_matrix: str = "known",
    ):
        super().__init__(system, chart)
        if input_matrix != "known":
            raise ConfigError(
                f"model.input_matrix={input_matrix} for {type(self).__name__}; allowed: known (the "
                f"discrete forcing of eq. (14) here takes the system's constant B)"
            )
        angles = angle_mask(system, angular)
        self.mass = CholeskyMass(self.n, angles, hidden, depth, activation, mass_eps)
        self.potential = Potential(self.n, angles, hidden, depth, activation)
        self.register_buffer("input_matrix", system.input_matrix().float(), persistent=False)
        self.train_tol, self.train_iters, self.eval_tol, self.eval_iters = train_tol, train_iters, eval_tol, eval_iters
        self.backtracks = backtracks
        self.newton_iterations: list[int] = []  # iterations of each step of the last rollout
        self.reset_diagnostics()

    def energy_structure(self) -> EnergyStructure:
        """Its M(q), V(q) (those of its discrete Lagrangian) and input matrix: the energy-based controller's
        structure (``encons.tools.control``)."""
        return EnergyStructure(self.mass, self.potential, self.input_matrix)

    def true_counterpart(self, system: System) -> SyMo | None:
        """This model's midpoint DEL step with the system's true M(q) and V(q) in place of its networks (same
        Newton settings): the one-step error its discretisation leaves at best; None in a chart other than the
        angle chart (where the system's M and V are given) or for a system of unknown physics."""
        if self.chart != "angle" or not system.known_physics:
            return None
        twin = copy.deepcopy(self)
        # the same methods as the networks (the DEL step and the rollout call no others): typed as the networks
        twin.mass, twin.potential = KnownMass(system), KnownPotential(system)  # type: ignore[assignment]
        return twin

    # -- the discrete mechanics -------------------------------------------------------------------
    def discrete_lagrangian(self, a: Tensor, b: Tensor, h: Tensor) -> Tensor:
        """L_d(a, b) of eqs. (12)–(13) for configurations (..., n); shape (...)."""
        v, mid = (b - a) / h, 0.5 * (a + b)
        w = (self.mass.cholesky(mid).transpose(-1, -2) @ v.unsqueeze(-1)).squeeze(-1)  # vᵀ M v = |Lᵀ v|²
        return h * (0.5 * (w**2).sum(-1) - self.potential(mid))

    def slot_derivatives(self, a: Tensor, b: Tensor, h: Tensor) -> tuple[Tensor, Tensor]:
        """(D₁L_d(a, b), D₂L_d(a, b)), one batched gradient."""
        return grad(lambda x, y: self.discrete_lagrangian(x, y, h).sum(), argnums=(0, 1))(a, b)

    def forces(self, u: Tensor | None, h: Tensor) -> Tensor | None:
        """(h/2) B u_k per step, (..., T, n): each of f_d^± in eq. (14) under a zero-order hold."""
        if u is None:
            return None
        return 0.5 * h * u.to(self.input_matrix) @ self.input_matrix.T

    def residual(self, states: Tensor, t: Tensor, u: Tensor | None = None) -> Tensor:
        """DEL residuals g_k (eq. (15)) of windows ``states`` (..., T, 2n): shape (..., T − 2, n)."""
        h, q = t[1] - t[0], states[..., : self.n]
        d1, d2 = self.slot_derivatives(q[..., :-1, :], q[..., 1:, :], h)
        g = d2[..., :-1, :] + d1[..., 1:, :]
        f = self.forces(u, h)
        return g if f is None else g + f[..., :-2, :] + f[..., 1:-1, :]

    # -- Newton root-find --------------------------------------------------------------------------
    def d1(self, a: Tensor, b: Tensor, h: Tensor) -> Tensor:
        """D₁L_d(a, b), the first-slot gradient alone (the DEL unknown is b)."""
        return grad(lambda x: self.discrete_lagrangian(x, b, h).sum())(a)

    def d1_and_pullback(self, a: Tensor, b: Tensor, h: Tensor) -> tuple[Tensor, Callable]:
        """D₁L_d(a, b) and the vjp of b ↦ D₁L_d(a, b), from which ``jacobian`` builds ∂D₁L_d/∂b."""
        # without has_aux, torch.func.vjp returns (output, pullback)
        return cast("tuple[Tensor, Callable]", vjp(lambda y: self.d1(a, y, h), b))

    def jacobian(self, pullback: Callable, b: Tensor) -> Tensor:
        """∂D₁L_d/∂b (..., n, n) at the point of ``pullback``: rows by one vjp per coordinate, batched by
        vmap (reverse over reverse, rather than jvp over reverse)."""
        basis = torch.eye(self.n, dtype=b.dtype, device=b.device).reshape(self.n, *[1] * (b.dim() - 1), self.n)
        (rows,) = vmap(pullback)(basis.expand(self.n, *b.shape))
        return rows.movedim(0, -2)

    def d1_and_jacobian(self, a: Tensor, b: Tensor, h: Tensor) -> tuple[Tensor, Tensor]:
        """D₁L_d(a, b) and its Jacobian in b (..., n, n)."""
        value, pullback = self.d1_and_pullback(a, b, h)
        return value, self.jacobian(pullback, b)

    def newton(
        self, c: Tensor, q: Tensor, guess: Tensor, h: Tensor, tol: float, iters: int
    ) -> tuple[Tensor, Tensor, int, Tensor]:
        """Root of g(x) = c + D₁L_d(q, x) near ``guess``, by damped Newton without a graph.

        Each sample (leading index) converges on its own: it stops moving once its RMS residual over
        the n coordinates is ≤ ``tol``. A Newton step is safeguarded by backtracking: it is halved (up to
        ``backtracks`` times) until the sample's residual norm decreases; a sample whose residual no
        halved step decreases keeps its iterate and stops iterating: every later iteration would repeat
        that step exactly (the samples' computations are independent), so the result is the one ``iters``
        iterations give. When every sample takes its full step, that trial's vjp gives the next Jacobian
        (no second evaluation at the same point). Returns (root, ∂g/∂x at the root, Newton iterations taken, mask of the
        samples not converged after ``iters`` iterations).
        """
        c, q, x = c.detach(), q.detach(), guess.detach()

        def rms(value: Tensor) -> Tensor:
            return value.pow(2).mean(-1).sqrt().nan_to_num(nan=float("inf"))

        with torch.no_grad():
            d1, jac = self.d1_and_jacobian(q, x, h)
            g = c + d1
            norm, it = rms(g), 0
            stalled = torch.zeros_like(norm, dtype=torch.bool)
            while it < iters and (active := (norm > tol) & ~stalled).any():
                it += 1
                step = torch.linalg.solve_ex(jac, g.unsqueeze(-1))[0].squeeze(-1)
                step = torch.where(active.unsqueeze(-1), step, torch.zeros_like(step)).nan_to_num(0.0, 0.0, 0.0)
                scale, todo = torch.ones_like(norm), active.clone()
                for halvings in range(self.backtracks + 1):
                    trial = x - scale.unsqueeze(-1) * step
                    if halvings == 0:  # the full step: keep its vjp for the Jacobian should every sample take it
                        trial_d1, pullback = self.d1_and_pullback(q, trial, h)
                    else:
                        trial_d1 = self.d1(q, trial, h)
                    trial_norm = rms(c + trial_d1)
                    better = todo & (trial_norm < norm)
                    x = torch.where(better.unsqueeze(-1), trial, x)
                    norm = torch.where(better, trial_norm, norm)
                    todo = todo & ~better
                    if not todo.any():
                        break
                    scale = torch.where(todo, 0.5 * scale, scale)
                stalled |= todo  # same iterate, same step, same failed halvings in every later iteration
                if halvings == 0 and not todo.any():  # every sample is at the full step's trial (inactive: step 0)
                    d1, jac = trial_d1, self.jacobian(pullback, trial)
                else:
                    d1, jac = self.d1_and_jacobian(q, x, h)
                g = c + d1
        return x, jac, it, rms(g) > tol

    def step(self, c: Tensor, q_prev: Tensor, q: Tensor, h: Tensor) -> Tensor:
        """q_{k+1} solving c + D₁L_d(q_k, q_{k+1}) = 0, differentiable by the implicit gradient; every
        sample whose root-find did not converge is counted (``diagnostics``)."""
        tol, iters = (self.train_tol, self.train_iters) if self.training else (self.eval_tol, self.eval_iters)
        root, jac, it, unconverged = self.newton(c, q, 2 * q - q_prev, h, tol, iters)
        self.newton_iterations.append(it)
        self.newton_solves += unconverged.numel()
        self.newton_unconverged += int(unconverged.sum())
        if not torch.is_grad_enabled():
            return root
        residual = c + self.d1(q, root, h)
        return ImplicitRoot.apply(residual, jac, root)

    def diagnostics(self) -> dict[str, float]:
        """``newton_unconverged``: the fraction of root-finds (one per sample and step) since the last
        ``reset_diagnostics`` whose RMS DEL residual stayed above the tolerance after the iteration cap."""
        return {"newton_unconverged": self.newton_unconverged / max(1, self.newton_solves)}

    def reset_diagnostics(self) -> None:
        self.newton_solves, self.newton_unconverged = 0, 0

    def sync_diagnostics(self, copy: DynamicsModel) -> None:
        copy = cast(SyMo, copy)  # a copy of this model: a SyMo too
        self.newton_solves, self.newton_unconverged = copy.newton_solves, copy.newton_unconverged

    def momentum(self, a: Tensor, b: Tensor, d1: Tensor, h: Tensor) -> Tensor:
        """D₂L_d(a, b) from D₁L_d(a, b): the midpoint rule gives D₂ − D₁ = 2 M((a + b)/2) (b − a)/h."""
        return d1 + 2 * (self.mass((a + b) / 2) @ ((b - a) / h).unsqueeze(-1)).squeeze(-1)

    def rollout(self, start: Tensor, t: Tensor, u: Tensor | None = None) -> Tensor:
        """States (..., T, 2n) from the first two states (..., 2, 2n), which are returned unchanged."""
        h, n = t[1] - t[0], self.n
        f = self.forces(u, h)
        force = (lambda k: f[..., k, :]) if f is not None else (lambda k: 0.0)
        qs = [start[..., 0, :n], start[..., 1, :n]]
        p = self.slot_derivatives(qs[0], qs[1], h)[1] + force(0)
        momenta = []
        self.newton_iterations = []
        for k in range(1, len(t) - 1):
            c = p + force(k)
            qs.append(self.step(c, qs[-2], qs[-1], h))
            # p_{k+1} = D₂L_d(q_k, q_{k+1}) + (h/2) B u_k, with D₁L_d(q_k, q_{k+1}) = −c at the root
            p = self.momentum(qs[-2], qs[-1], -c, h) + force(k)
            momenta.append(p)
        if not momenta:
            return start[..., : len(t), :]
        q_new = torch.stack(qs[2:], -2)
        qd_new = self.mass.solve(q_new, torch.stack(momenta, -2))
        return torch.cat([start, torch.cat([q_new, qd_new], -1)], -2)


class E2ESyMo(SyMo):
    """E2E-SyMo (Santos et al. §6): SyMo trained through its Newton root-find layer (eq. (17)).

    The default objective is the rollout loss on the roots, whose gradient is implicit
    (Theorem 1, eq. (16)) — no backpropagation through the iterations.
    """

    objectives = ("rollout", "residual", "onestep")
