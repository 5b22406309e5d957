"""LNN, its angle form and GLNN at their default settings solve ∇²_q̇L q̈ = r without bias: fed the true
Lagrangian at physical scale (and GLNN the true force) they give the true q̈ (``guarded_solve``)."""

from __future__ import annotations

from functools import partial

import pytest
import torch
from hydra.utils import execution_whitelist

from encons.config.check import validate
from encons.config.trust import trusted_targets
from encons.entry import api
from encons.models.glnn import GLNN
from encons.models.lnn import LNN, guarded_solve, lagrangian_derivatives
from encons.models.networks import cranmer_init_, mlp
from encons.systems.base import split_state
from encons.training.build import build_model, build_system

SYSTEMS = ["pendulum1", "pendulum2", "pendulum4", "gyroscope", "damped_oscillator", "compound_pendulum"]


def true_lagrangian(system):
    def lagrangian(s):
        q, qd = split_state(s)
        return 0.5 * (qd.unsqueeze(-2) @ system.mass_matrix(q) @ qd.unsqueeze(-1))[..., 0, 0] - system.potential(q)

    return lagrangian


def physical_states(system, n=256):
    """States as the data sample them (the gyroscope's kept |sin θ| ≥ 0.1, as its data are)."""
    s = system.sample_initial(4 * n, torch.Generator().manual_seed(3))
    if system.name == "gyroscope":
        s = s[torch.sin(s[:, 1]).abs() >= 0.1]
    return s[:n]


@pytest.mark.parametrize("name", SYSTEMS)
@pytest.mark.parametrize("model_name", ["lnn", "lnn_angle", "glnn"])
def test_true_lagrangian_gives_the_true_acceleration_at_default_settings(model_name, name):
    cfg = api.compose(f"model={model_name}", f"system={name}", output_dir=".")
    with execution_whitelist(trusted_targets()):
        checked = validate(cfg)
        system = build_system(checked)
        model = build_model(checked, system).double()
    model.lagrangian_derivatives = partial(lagrangian_derivatives, true_lagrangian(system))
    force = getattr(system, "force", lambda s: torch.zeros_like(split_state(s)[0]))
    s = physical_states(system)
    q, _ = split_state(s)
    expected = split_state(system.vector_field(s, "angle"))[1]
    if isinstance(model, GLNN):
        model.force = force
    else:  # LNN learns no force: the true q̈ of L alone
        expected = expected - torch.linalg.solve(system.mass_matrix(q), force(s).unsqueeze(-1)).squeeze(-1)
    got = split_state(model(torch.zeros(()), s))[1]
    rel = ((got - expected).norm(dim=-1) / expected.norm(dim=-1)).max().item()
    assert rel <= 1e-6, rel


def test_the_guard_acts_where_the_hessian_is_near_singular_and_bounds_the_solution():
    h = torch.tensor(
        [[[2.0, 0.0], [0.0, 1e-7]], [[2.0, 0.0], [0.0, 1.0]], [[1.0, 0.0], [0.0, 0.0]]],
        dtype=torch.float64,
        requires_grad=True,
    )
    r = torch.ones(3, 2, dtype=torch.float64)
    x = guarded_solve(h, r, 1e-4)
    lam = 1e-4 * h.detach().flatten(-2).norm(dim=-1)
    assert torch.equal(x[1], torch.tensor([0.5, 1.0], dtype=torch.float64))  # well conditioned: exact
    assert (x[0].norm() <= r[0].norm() / (2 * lam[0])) and x[0, 0].item() == pytest.approx(
        0.5
    )  # damped on the small σ only
    assert x[2].tolist() == pytest.approx([1.0, 0.0]) and x[2, 1] == 0  # singular: finite, not NaN
    x.sum().backward()
    assert h.grad.isfinite().all()
    assert guarded_solve(1e6 * h.detach()[:2], 1e6 * r[:2], 1e-4).allclose(x[:2].detach())  # scale-free


def test_the_guard_is_finite_where_the_hessian_vanishes_or_underflows():
    """Far outside the data a softplus L saturates and ∇²_q̇L underflows to 0: q̈ stays finite (0 at H = 0:
    the least-squares solution of minimum norm)."""
    h = torch.stack([torch.zeros(2, 2), 1e-30 * torch.eye(2)])
    r = torch.tensor([[4.0, 1.0], [70.0, 2.0]])
    x = guarded_solve(h.requires_grad_(), r, 1e-3)
    assert x.isfinite().all() and x[0].eq(0).all()
    x.sum().backward()
    assert h.grad.isfinite().all()


@pytest.mark.parametrize("singular", [False, True])
def test_the_guard_is_a_mask_not_a_branch(monkeypatch, singular):
    """Three solves whatever the values (no Python branch on them, so a seed ensemble vmaps it): the one that picks
    the plain samples (no gradient), the plain system with I where damped (an exactly singular H would send NaN back
    even under a zero gradient), the damped one; under vmap over a member axis the same q̈ as member by member."""
    h = torch.tensor([[[2.0, 0.0], [0.0, 1e-7]], [[2.0, 0.0], [0.0, 1.0]]], dtype=torch.float64)
    if singular:
        h[0, 1, 1] = 0
    h.requires_grad_()
    calls = []
    solve_ex = torch.linalg.solve_ex
    monkeypatch.setattr(torch.linalg, "solve_ex", lambda a, b: calls.append(a.detach().clone()) or solve_ex(a, b))
    x = guarded_solve(h, torch.ones(2, 2, dtype=torch.float64), 1e-4)
    assert len(calls) == 3
    assert torch.equal(x[1], torch.tensor([0.5, 1.0], dtype=torch.float64)) and x[0, 0].item() == pytest.approx(0.5)
    x.sum().backward()
    assert h.grad.isfinite().all()
    members = torch.stack([h.detach(), h.detach().flip(0)])
    rhs = torch.ones(2, 2, 2, dtype=torch.float64)
    vmapped = torch.func.vmap(lambda a, b: guarded_solve(a, b, 1e-4))(members, rhs)
    assert torch.equal(vmapped, torch.stack([guarded_solve(m, b, 1e-4) for m, b in zip(members, rhs)]))


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("model_name", ["lnn", "lnn_angle", "glnn"])
@pytest.mark.parametrize("name", ["pendulum1", "pendulum2", "gyroscope", "mass_spring", "pendulum"])
def test_fresh_networks_take_their_first_steps_without_nan(tmp_path, model_name, name, seed):
    """debug=fast sizes: the loss of every training batch and its gradient stay finite at the start and over
    four AdamW steps. From Cranmer et al.'s signed start 11 of the 27 on pendulum1/2 and the gyroscope reached NaN;
    from a jointly convex start (no separation of q and q̇, no velocity scale) 3 of these 45: lnn on mass_spring
    and glnn on Lim & Kasim's pendulum (seed 0), lnn_angle on the gyroscope (seed 2)."""
    from encons.entry.api import build

    cfg = api.compose(
        "debug=fast",
        f"model={model_name}",
        f"system={name}",
        f"seed={seed}",
        output_dir=tmp_path,
        cache_dir=tmp_path / "cache",
    )
    with execution_whitelist(trusted_targets()):
        data, module = build(cfg)
    optimizer = module.optimizer(module.parameters())
    for batch in [*data.train_dataloader(), *data.train_dataloader()]:
        optimizer.zero_grad()
        loss = module.loss(batch)
        assert loss.isfinite(), loss
        loss.backward()
        assert all(p.grad.isfinite().all() for p in module.parameters() if p.grad is not None)
        optimizer.step()


@pytest.mark.parametrize("model_name", ["lnn", "lnn_angle", "glnn"])
def test_a_fresh_lagrangian_starts_as_kinetic_minus_potential(model_name):
    """A fresh L is g(q̇) − h(q) with g, h convex on sampled states: ∇²_q̇L positive definite (Cranmer et al.'s start:
    indefinite), no mixed term, ∇²_qL negative semi-definite in the plain chart (a jointly convex start: positive,
    a potential −L(q, 0) that pushes states away)."""
    cfg = api.compose(f"model={model_name}", "system=pendulum2", "model.hidden=16", "model.depth=2", output_dir=".")
    with execution_whitelist(trusted_targets()):
        checked = validate(cfg)
        system = build_system(checked)
        model = build_model(checked, system).double()
    s = physical_states(system)
    _, hessian, mixed = lagrangian_derivatives(model.lagrangian, s)
    assert torch.linalg.eigvalsh(hessian).min() > 0 and mixed.eq(0).all()
    if not model.angular:
        q, qd = split_state(s)
        curvature = torch.func.vmap(torch.func.hessian(lambda qi, qdi: model.lagrangian(torch.cat([qi, qdi]))))(q, qd)
        assert torch.linalg.eigvalsh(curvature).max() <= 1e-12


def test_the_start_keeps_large_velocities_out_of_softplus_tails():
    """Each velocity's share of a first-layer pre-activation, σ₁·RMS(q̇_i) with Cranmer et al.'s σ₁ = 2.2/√w, is
    capped at 2 (RMS over the system's initial states): on the gyroscope the spin ψ̇ (RMS 1.5·√50 ≈ 10.6) is scaled
    at width 16 (σ₁·10.6 ≈ 5.8) but not at the default 256 (1.46); a latent or data-file system counts as 1."""
    from encons.models.lnn import typical_speed
    from encons.systems.latent import LatentSystem

    cfg = api.compose("model=lnn", "system=gyroscope", output_dir=".")
    with execution_whitelist(trusted_targets()):
        gyroscope = build_system(validate(cfg))
    speed = typical_speed(gyroscope, "angle")
    # φ̇ ~ U(−4.5, 4.5): RMS 4.5/√3; θ̇ ~ U(−0.3, 0.3): 0.3/√3; ψ̇ = ±1.5·(7 + N(0, 1)): 1.5·√50
    assert speed.tolist() == pytest.approx([4.5 / 3**0.5, 0.3 / 3**0.5, 1.5 * 50**0.5], rel=0.03)
    latent = LatentSystem(4, gyroscope)
    assert torch.equal(typical_speed(latent, "angle"), torch.ones(latent.coord_dim("angle")))
    for hidden in (16, 256):
        torch.manual_seed(0)
        scaled = LNN(gyroscope, hidden=hidden, depth=2).lagrangian_net[0].weight
        torch.manual_seed(0)
        plain = cranmer_init_(mlp(6, 1, hidden, 2), convex=True, potential_inputs=3)[0].weight
        share = 2.2 / hidden**0.5 * torch.cat([torch.ones(3), speed])  # q as drawn (size 1), q̇ by its RMS
        assert torch.allclose(scaled, plain / (share / 2).clamp(min=1)) and (hidden == 16) == bool((share > 2).any())
