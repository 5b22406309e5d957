"""SyMo / E2E-SyMo (Santos et al. §5–6) against the true discrete mechanics, in float64.

The models' learned M(q) and V(q) are swapped for the system's own: the DEL residual (eq. (15)) must
vanish on the true variational integrator's trajectories and shrink as h³ on exact trajectories,
Newton must converge on them, and the implicit gradient (Theorem 1, eq. (16)) must equal the
gradient through unrolled Newton iterations and finite differences.
"""

from __future__ import annotations

import math

import pytest
import torch
from torch import nn
from torchdiffeq import odeint

from encons.models.symo import E2ESyMo, SyMo
from encons.systems.controlled import CartPole, ControlledPendulum
from encons.systems.pendulum import NPendulum

SYSTEMS = {
    "pendulum_control": ControlledPendulum,
    "cartpole": CartPole,
    "pendulum3": lambda: NPendulum(3, masses=[1.0, 0.7, 0.5], lengths=[1.0, 0.8, 0.6]),
}


class TrueCholesky(nn.Module):
    """The system's M(q) behind ``CholeskyMass``'s interface (its Cholesky factor)."""

    def __init__(self, system):
        super().__init__()
        self.system = system

    def forward(self, q):
        return self.system.mass_matrix(q)

    def cholesky(self, q):
        return torch.linalg.cholesky(self.system.mass_matrix(q))

    def solve(self, q, p):
        return torch.cholesky_solve(p.unsqueeze(-1), self.cholesky(q)).squeeze(-1)


class TruePotential(nn.Module):
    def __init__(self, system):
        super().__init__()
        self.system = system

    def forward(self, q):
        return self.system.potential(q)


def true_symo(system, **newton):
    model = SyMo(system, hidden=8, depth=1, **newton).double()
    model.mass, model.potential = TrueCholesky(system), TruePotential(system)
    return model


def exact(system, s0, t, u=None):
    """Trajectories (N, T, 2n) by RK4 with 50 substeps per step (float64), constant inputs u (N, m)."""
    field = (
        (lambda _, s: system.vector_field(s, "angle", u))
        if u is not None
        else (lambda _, s: system.vector_field(s, "angle"))
    )
    return odeint(field, s0, t, method="rk4", options={"step_size": float(t[1] - t[0]) / 50}).movedim(0, 1)


def draw(system, n, seed=0):
    gen = torch.Generator().manual_seed(seed)
    s0 = system.sample_initial(n, gen) if system.n_controls else 0.5 * system.sample_initial(n, gen)
    u = system.sample_controls(n, gen) if system.n_controls else None
    return s0, u


def per_step(u, steps):
    return None if u is None else u[:, None].expand(-1, steps, -1)


@pytest.mark.parametrize("name", SYSTEMS)
def test_del_residual_vanishes_on_the_true_variational_integrator(name):
    system = SYSTEMS[name]()
    model = true_symo(system, eval_tol=1e-12, eval_iters=20).eval()
    s0, u = draw(system, 8)
    h, steps = 0.05, 40
    t = torch.arange(steps, dtype=torch.float64) * h
    start = exact(system, s0, t[:2], u)
    traj = model.rollout(start, t, per_step(u, steps))
    assert max(model.newton_iterations) < 20  # converged every step, not stopped by the cap
    assert model.residual(traj, t, per_step(u, steps)).abs().max() < 1e-10


@pytest.mark.parametrize("name", SYSTEMS)
def test_true_variational_integrator_is_second_order(name):
    """Global configuration error at t = 1 falls fourfold when h halves."""
    system = SYSTEMS[name]()
    model = true_symo(system, eval_tol=1e-12, eval_iters=20).eval()
    s0, u = draw(system, 8, seed=3)
    n, errors = system.coord_dim("angle"), []
    for steps in (26, 51):
        t = torch.linspace(0, 1, steps, dtype=torch.float64)
        truth = exact(system, s0, t, u)
        traj = model.rollout(truth[:, :2], t, per_step(u, steps))
        errors.append((traj[:, -1, :n] - truth[:, -1, :n]).norm(dim=-1).max())
    assert 3.2 < errors[0] / errors[1] < 4.8


@pytest.mark.parametrize("name", SYSTEMS)
def test_del_residual_of_exact_trajectories_shrinks_as_h_cubed(name):
    system = SYSTEMS[name]()
    model = true_symo(system)
    s0, u = draw(system, 8, seed=1)
    errors = []
    for h in (0.02, 0.01):
        t = torch.arange(3, dtype=torch.float64) * h
        errors.append(model.residual(exact(system, s0, t, u), t, per_step(u, 3)).norm(dim=-1).max())
    assert 6.5 < errors[0] / errors[1] < 9.5  # local error O(h³) of the midpoint rule


def unrolled_newton(model, c, q, guess, h, iters):
    """Newton differentiated through its iterations (the reference for the implicit gradient)."""
    x = guess
    for _ in range(iters):
        d1, jac = model.d1_and_jacobian(q, x, h)
        x = x - torch.linalg.solve(jac, (c + d1).unsqueeze(-1)).squeeze(-1)
    return x


def test_implicit_gradient_matches_unrolled_newton_and_finite_differences():
    """Three degrees of freedom, float64: ∂L/∂θ of a root by eq. (16) vs. the two references."""
    torch.manual_seed(0)
    system = SYSTEMS["pendulum3"]()
    model = E2ESyMo(system, hidden=16, depth=2, train_tol=1e-13, train_iters=30).double().train()
    s0, _ = draw(system, 6, seed=2)
    t = torch.arange(4, dtype=torch.float64) * 0.05
    start = exact(system, s0, t[:2])
    weights = torch.randn(6, 2, 3, dtype=torch.float64)
    params = list(model.parameters())

    def loss_implicit():
        return (model.rollout(start, t)[:, 2:, :3] * weights).sum()

    implicit = torch.autograd.grad(loss_implicit(), params, materialize_grads=True)
    assert max(model.newton_iterations) < 30

    def loss_unrolled():
        h, q_prev, q = t[1] - t[0], start[:, 0, :3], start[:, 1, :3]
        roots = []
        for _ in range(2):
            c = model.slot_derivatives(q_prev, q, h)[1]
            q_prev, q = q, unrolled_newton(model, c, q, 2 * q - q_prev, h, 12)
            roots.append(q)
        return (torch.stack(roots, 1) * weights).sum()

    unrolled = torch.autograd.grad(loss_unrolled(), params, materialize_grads=True)
    flat = lambda grads: torch.cat([g.reshape(-1) for g in grads])  # noqa: E731
    assert torch.allclose(flat(implicit), flat(unrolled), rtol=1e-5, atol=1e-5 * flat(unrolled).abs().max())

    direction = [torch.randn_like(p) for p in params]
    eps = 1e-6
    with torch.no_grad():
        values = []
        for sign in (1, -1):
            for p, d in zip(params, direction):
                p.add_(sign * eps * d)
            values.append(loss_implicit())
            for p, d in zip(params, direction):
                p.sub_(sign * eps * d)
    finite = (values[0] - values[1]) / (2 * eps)
    analytic = sum((g * d).sum() for g, d in zip(implicit, direction))
    assert abs(finite - analytic) <= 1e-5 * abs(analytic)


def test_symo_trains_on_the_residual_and_e2e_on_the_rollout():
    assert SyMo.objectives[0] == "residual" and E2ESyMo.objectives[0] == "rollout"
    assert SyMo.discrete and SyMo.history == 2 and SyMo.supports_controls


def test_newton_step_matches_the_closed_form_del_root_of_the_pendulum():
    """One SyMo step with the pendulum's true M = m l²/3 and V = ½ m g l (1 + cos q) lands on the root of
    its scalar forced DEL equation (Santos et al. eqs. (13)–(15)), written out by hand and bracketed by
    scipy's brentq — an independent solve, not the model's own residual."""
    from scipy.optimize import brentq

    system = ControlledPendulum()
    model = true_symo(system, eval_tol=1e-13, eval_iters=30).eval()
    s0, u = draw(system, 6, seed=4)
    h = 0.1
    t = torch.arange(3, dtype=torch.float64) * h
    start = exact(system, s0, t[:2], u)
    pred = model.rollout(start, t, per_step(u, 3))
    inertia, mgl2 = system.m * system.l**2 / 3, 0.5 * system.m * system.g * system.l
    dv = lambda q: -mgl2 * math.sin(q)  # noqa: E731 - V'(q)
    for i in range(len(s0)):
        q0, q1, f = start[i, 0, 0].item(), start[i, 1, 0].item(), u[i, 0].item()
        del_eq = lambda q2: (  # noqa: E731
            inertia * (q1 - q0) / h
            - 0.5 * h * dv(0.5 * (q0 + q1))  # D₂L_d(q0, q1)
            - inertia * (q2 - q1) / h
            - 0.5 * h * dv(0.5 * (q1 + q2))  # D₁L_d(q1, q2)
            + 0.5 * h * (f + f)
        )  # (h/2) B (u0 + u1)
        root = brentq(del_eq, 2 * q1 - q0 - 1.0, 2 * q1 - q0 + 1.0, xtol=1e-15)
        assert abs(pred[i, 2, 0].item() - root) < 1e-10
    assert model.diagnostics() == {"newton_unconverged": 0.0}


def test_non_converged_newton_steps_are_counted_not_returned_silently():
    """With one iteration allowed and a tolerance below what one step reaches, every root-find ends
    unconverged and the model says so; with room to converge, none is counted."""
    system = CartPole()
    s0, u = draw(system, 5, seed=2)
    t = torch.arange(6, dtype=torch.float64) * 0.05
    start = exact(system, s0, t[:2], u)
    starved = true_symo(system, eval_tol=1e-15, eval_iters=1).eval()
    starved.rollout(start, t, per_step(u, 6))
    assert starved.diagnostics()["newton_unconverged"] == 1.0
    assert starved.newton_solves == 5 * 4  # one root-find per trajectory and step
    roomy = true_symo(system, eval_tol=1e-10, eval_iters=20).eval()
    roomy.rollout(start, t, per_step(u, 6))
    assert roomy.diagnostics()["newton_unconverged"] == 0.0


def test_newton_backtracking_never_raises_the_residual():
    """A learned DEL far from any root (an untrained network, a huge step) cannot throw the iterate away:
    the safeguarded step keeps each sample's residual at or below the plain guess's."""
    torch.manual_seed(0)
    system = CartPole()
    model = SyMo(system, hidden=16, depth=2, eval_iters=5).double().eval()
    s0, u = draw(system, 16, seed=5)
    h = torch.tensor(0.05, dtype=torch.float64)
    q_prev, q = s0[:, :2], s0[:, :2] + h * s0[:, 2:]
    c = model.slot_derivatives(q_prev, q, h)[1]
    guess = 2 * q - q_prev
    g0 = (c + model.d1_and_jacobian(q, guess, h)[0]).pow(2).mean(-1).sqrt()
    root, _, _, _ = model.newton(c, q, guess, h, 1e-12, 5)
    g1 = (c + model.d1_and_jacobian(q, root, h)[0]).pow(2).mean(-1).sqrt()
    assert torch.all(g1 <= g0 + 1e-15)
    assert root.isfinite().all()


def test_newton_failures_reach_the_test_metrics(train_run):
    """End to end: a starved Newton shows up in the run's test metrics and §7 integration metrics."""
    results = train_run(
        [
            "model=symo",
            "system=pendulum_control",
            "model.eval_iters=1",
            "model.eval_tol=1e-15",
            "evaluators.santos.steps=6",
            "evaluators.santos.n_trajectories=2",
            "trainer.max_epochs=1",
        ]
    )
    assert results["test/newton_unconverged"] == 1.0
    assert results["test/newton_unconverged_integration"] == 1.0


def newton_without_stall_exit(model, c, q, guess, h, tol, iters):
    """SyMo.newton as it was before samples whose every halved step failed stopped iterating and before the
    full step's vjp gave the next Jacobian: the reference both speed-ups must reproduce bit for bit."""
    from torch.func import grad

    c, q, x = c.detach(), q.detach(), guess.detach()

    def rms(value):
        return value.pow(2).mean(-1).sqrt().nan_to_num(nan=float("inf"))

    with torch.no_grad():
        d1, jac = model.d1_and_jacobian(q, x, h)
        g = c + d1
        norm, it = rms(g), 0
        while it < iters and (active := norm > tol).any():
            it += 1
            step = torch.linalg.solve_ex(jac, g.unsqueeze(-1))[0].squeeze(-1)
            step = torch.where(active.unsqueeze(-1), step, torch.zeros_like(step)).nan_to_num(0.0, 0.0, 0.0)
            scale, todo = torch.ones_like(norm), active.clone()
            for _ in range(model.backtracks + 1):
                trial = x - scale.unsqueeze(-1) * step
                trial_norm = rms(c + grad(lambda a: model.discrete_lagrangian(a, trial, h).sum())(q))
                better = todo & (trial_norm < norm)
                x = torch.where(better.unsqueeze(-1), trial, x)
                norm = torch.where(better, trial_norm, norm)
                todo = todo & ~better
                if not todo.any():
                    break
                scale = torch.where(todo, 0.5 * scale, scale)
            d1, jac = model.d1_and_jacobian(q, x, h)
            g = c + d1
    return x, jac, it, rms(g) > tol


@pytest.mark.parametrize("tol", [1e-5, 1e-12])
def test_newton_speedups_leave_roots_losses_and_gradients_unchanged(tol):
    """float32, as trained: E2E-SyMo's one-step loss, its gradients, the rollout and the non-converged
    count are bit-identical to the reference Newton — at the §7 training tolerance and at one float32
    cannot reach (every sample stalls), where the stall exit must also save iterations."""
    from encons.training.module import TrainingModule

    system = CartPole()
    s0, u = draw(system, 6, seed=3)
    t = torch.arange(9, dtype=torch.float64) * 0.05
    batch = {"states": exact(system, s0, t, u).float(), "u": per_step(u, 9).float()}
    outcomes = []
    for reference in (False, True):
        torch.manual_seed(0)
        model = E2ESyMo(system, hidden=32, depth=2, train_tol=tol, eval_tol=tol)
        if reference:
            model.newton = lambda *args: newton_without_stall_exit(model, *args)
        module = TrainingModule(model, system, 0.05, None, objective="onestep")
        loss = module.loss(batch)
        loss.backward()
        iterations = sum(model.newton_iterations)
        with torch.no_grad():
            model.eval()
            pred = model.rollout(batch["states"][:, :2], t.float(), batch["u"])
        outcomes.append(
            (
                loss.detach(),
                [p.grad for p in model.parameters() if p.grad is not None],
                pred,
                model.newton_unconverged,
                iterations,
            )
        )
    (loss, grads, pred, failed, its), (ref_loss, ref_grads, ref_pred, ref_failed, ref_its) = outcomes
    assert torch.equal(loss, ref_loss) and torch.equal(pred, ref_pred) and failed == ref_failed
    assert len(grads) == len(ref_grads) > 0 and all(torch.equal(a, b) for a, b in zip(grads, ref_grads))
    if tol < 1e-9:
        assert failed > 0 and its < ref_its
