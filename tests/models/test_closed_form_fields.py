"""The closed-form derivatives of the models' networks (``MLPTape``) equal autodiff's.

Float64, small random networks of every activation, with and without the angle embedding: the
tape's gradient, forward tangents and curvature against ``torch.func``; each model's closed-form
field terms against the autodiff versions of the same learned pieces (which the true-physics
tests in tests/models/test_true_physics.py check against the systems' own fields).
"""

from __future__ import annotations

import pytest
import torch
from torch.func import hessian, jacfwd, jacrev, jvp, vmap

from encons.infra.batching import batched_grad
from encons.models.constrained import CHNN, CLNN
from encons.models.hnn import HNN, HNNStructure
from encons.models.lnn import LNN, LNNStructure, euler_lagrange_terms, lagrangian_derivatives
from encons.models.networks import ACTIVATIONS, MLPTape, layer_curvature, mlp, narrow_in, narrow_out
from encons.systems.base import split_state
from encons.systems.gyroscope import Gyroscope
from encons.systems.pendulum import NPendulum

SYSTEMS = {"pendulum2": lambda: NPendulum(2), "gyroscope": Gyroscope}


def gap(a, b):
    return ((a - b).abs().max() / b.abs().max()).item()


@pytest.mark.parametrize("activation", sorted(ACTIVATIONS))
def test_tape_derivatives_are_autodiff_ones(activation):
    torch.manual_seed(0)
    net = mlp(5, 1, 16, 3, activation).double()
    x = torch.randn(7, 5, dtype=torch.float64)
    directions = torch.randn(7, 3, 5, dtype=torch.float64)
    f = lambda xi: net(xi).squeeze(-1)  # noqa: E731
    tape = MLPTape(net, x)
    assert gap(tape.out, net(x)) < 1e-14  # the first layer runs column-major (narrow_in): equal to rounding
    assert gap(tape.pullback(torch.ones_like(tape.out)), batched_grad(f, x)) < 1e-13
    out_dot, tangents = tape.push(directions)
    assert gap(out_dot, vmap(lambda d: jvp(net, (x,), (d,))[1], 1, 1)(directions)) < 1e-13
    exact = torch.einsum("bik,bkl,bjl->bij", directions, vmap(hessian(f))(x), directions)
    if activation != "relu":  # piecewise linear: zero curvature on both sides
        assert gap(tape.curvature(tangents), exact) < 1e-12
    else:
        assert tape.curvature(tangents).abs().max() == 0 and exact.abs().max() == 0


def test_layer_curvature_is_its_plain_expression_to_every_order():
    """``layer_curvature`` (its own backward, for speed) against Σ_k (T_k[:I] ⊙ w_k) T_kᵀ: values, first
    and second derivatives (gradcheck/gradgradcheck), forward mode, and jacrev/jacfwd under vmap."""
    torch.manual_seed(0)
    tangents = [torch.randn(5, 4, 7, dtype=torch.float64, requires_grad=True) for _ in range(2)]
    weights = [torch.randn(5, 7, dtype=torch.float64, requires_grad=True) for _ in range(2)]
    f = lambda t1, t2, w1, w2: layer_curvature(3, [t1, t2], [w1, w2])  # noqa: E731
    plain = (  # noqa: E731
        lambda t1, t2, w1, w2: sum(
            torch.einsum("...ic,...c,...jc->...ij", t[..., :3, :], w, t) for t, w in ((t1, w1), (t2, w2))
        )
    )
    args = (*tangents, *weights)
    assert f(*args).shape == (5, 3, 4) and gap(f(*args), plain(*args)) < 1e-14
    assert torch.autograd.gradcheck(f, args, check_forward_ad=True)
    assert torch.autograd.gradgradcheck(f, args)
    detached = [a.detach() for a in args]
    for jacobian in (jacrev, jacfwd):
        got = vmap(jacobian(f, argnums=(0, 1, 2, 3)))(*detached)
        want = vmap(jacobian(plain, argnums=(0, 1, 2, 3)))(*detached)
        assert all(torch.allclose(g, w, atol=1e-14) for g, w in zip(got, want))


def test_narrow_products_are_the_plain_ones_to_every_order():
    """``narrow_in``/``narrow_out`` (column-major operands, for speed) against x Wᵀ + b and g W, with
    batch dimensions: values, first and second derivatives; a wide input takes the plain path."""
    torch.manual_seed(0)
    x = torch.randn(2, 20, 5, dtype=torch.float64, requires_grad=True)
    g = torch.randn(2, 20, 16, dtype=torch.float64, requires_grad=True)
    weight_t = torch.randn(5, 16, dtype=torch.float64, requires_grad=True)
    bias = torch.randn(16, dtype=torch.float64, requires_grad=True)
    assert gap(narrow_in(x, weight_t, bias), x @ weight_t + bias) < 1e-14
    assert gap(narrow_out(g, weight_t), g @ weight_t.T) < 1e-14
    assert gap(narrow_out(g, weight_t, bias[:5]), g @ weight_t.T + bias[:5]) < 1e-14
    for f, args in (
        (narrow_in, (x, weight_t, bias)),
        (narrow_in, (x, weight_t)),
        (narrow_out, (g, weight_t)),
        (narrow_out, (g, weight_t, bias[:5])),
    ):
        assert torch.autograd.gradcheck(f, args) and torch.autograd.gradgradcheck(f, args)
    wide_t = torch.randn(16, 3, dtype=torch.float64)
    assert torch.equal(narrow_in(g, wide_t), g @ wide_t)


def test_hidden_tangents_are_the_tangents_push_returns():
    torch.manual_seed(0)
    net = mlp(5, 1, 16, 3).double()
    tape = MLPTape(net, torch.randn(7, 5, dtype=torch.float64))
    directions = torch.randn(7, 2, 5, dtype=torch.float64)
    hidden = tape.hidden_tangents(directions @ net[0].weight.T)
    assert all(gap(h, t) < 1e-14 for h, t in zip(hidden, tape.push(directions)[1], strict=True))


def states(system, n=24):
    s = system.sample_initial(4 * n, torch.Generator().manual_seed(3))
    return s[torch.sin(s[:, 1]).abs() > 0.3][:n] if isinstance(system, Gyroscope) else s[:n]


@pytest.mark.parametrize("angular", [False, True])
@pytest.mark.parametrize("system_name", SYSTEMS)
def test_hnn_and_lnn_closed_forms_are_autodiff_ones(system_name, angular):
    system, s = SYSTEMS[system_name](), states(SYSTEMS[system_name]())
    torch.manual_seed(1)
    hnn = HNN(system, hidden=16, depth=3, angular=angular).double()
    z = hnn.to_internal(s)
    assert gap(hnn.hamiltonian_gradient(z), batched_grad(hnn.hamiltonian, z)) < 1e-12
    lnn = LNN(system, hidden=16, depth=3, angular=angular).double()
    with torch.no_grad():  # off the separable start L = g(q̇) − h(q), whose mixed term (∇_q ∇_q̇ᵀ L) q̇ is exactly 0
        for weight in lnn.parameters():
            weight.add_(0.1 * torch.randn_like(weight))
    # LNN's convex start drives its deeper units to pre-activations ~10-20 (L ~ 2e3 on the gyroscope's states):
    # the two orders of rounding differ by up to 3e-10 there (measured), 5e-9 for ∇²_q̇L
    for fast, slow in zip(lnn.lagrangian_derivatives(s), lagrangian_derivatives(lnn.lagrangian, s)):
        assert gap(fast, slow) < 1e-8


@pytest.mark.parametrize("shared_trunk", [True, False])
@pytest.mark.parametrize("angular", [False, True])
@pytest.mark.parametrize("system_name", SYSTEMS)
def test_structured_closed_forms_are_autodiff_ones(system_name, angular, shared_trunk):
    system, s = SYSTEMS[system_name](), states(SYSTEMS[system_name]())
    torch.manual_seed(2)
    hnn = HNNStructure(system, hidden=16, depth=3, angular=angular, shared_trunk=shared_trunk).double()
    z = hnn.to_internal(s)
    assert gap(hnn.hamiltonian_gradient(z), batched_grad(hnn.hamiltonian, z)) < 1e-12
    lnn = LNNStructure(system, hidden=16, depth=3, angular=angular, shared_trunk=shared_trunk).double()
    q, qd = split_state(s)
    for fast, slow in zip(lnn.euler_lagrange_terms(q, qd), euler_lagrange_terms(lnn.factor_potential, q, qd)):
        assert gap(fast, slow) < 1e-12


@pytest.mark.parametrize("cls", [CHNN, CLNN], ids=lambda c: c.__name__)
@pytest.mark.parametrize("system_name", SYSTEMS)
def test_cartesian_potential_gradient_is_autodiff_one(cls, system_name):
    system = SYSTEMS[system_name]()
    torch.manual_seed(3)
    model = cls(system, hidden=16, depth=3).double()
    x = split_state(system.to_chart(states(system), "angle", "cartesian"))[0]
    assert gap(model.potential_gradient(x), batched_grad(model.potential, x)) < 1e-12


def test_closed_forms_differentiate_like_autodiff():
    """A training step differentiates the closed forms: parameter gradients of an LNN field (third
    derivatives of the network) equal those of the autodiff field."""
    system = NPendulum(2)
    torch.manual_seed(4)
    lnn = LNN(system, hidden=16, depth=2).double()
    s = states(system)
    params = list(lnn.parameters())
    fast = torch.autograd.grad(lnn(torch.zeros(()), s).square().sum(), params[:-1])  # not the output bias
    lnn.lagrangian_derivatives = lambda si: lagrangian_derivatives(lnn.lagrangian, si)
    slow = torch.autograd.grad(lnn(torch.zeros(()), s).square().sum(), params[:-1])
    for a, b in zip(fast, slow):
        assert gap(a, b) < 1e-10
