"""Constraints declared as structure (``DistanceConstraints``): Φ as written by hand, closed-form
DΦ, D_xΦ̇ equal to autodiff, and CHNN/CLNN fields (closed-form masses and inverse) equal to the general path (autodiff
Jacobians, assembled and inverted mass matrix)."""

from __future__ import annotations

import contextlib

import pytest
import torch

from encons.models.constrained import CHNN, CLNN
from encons.systems.base import point_mass_matrix
from encons.systems.constrained import DistanceConstraints, constraint_jacobians
from encons.systems.gyroscope import Gyroscope
from encons.systems.pendulum import NPendulum
from encons.training import stacked

SYSTEMS = {
    "pendulum1": lambda: NPendulum(1),
    "pendulum2": lambda: NPendulum(2, masses=[1.0, 1.5], lengths=[1.0, 0.8]),
    "pendulum4": lambda: NPendulum(4, lengths=[1.0, 0.7, 1.2, 0.9]),
    "gyroscope": Gyroscope,
}


def hand_written_phi(system, x):
    """Φ as the systems wrote it before the structure existed."""
    if isinstance(system, Gyroscope):
        pts = x.unflatten(-1, (4, 3))
        com, axes = pts[..., 0, :], pts[..., 1:, :]
        unit = ((axes - com[..., None, :]) ** 2).sum(-1) - 1
        i, j = torch.triu_indices(3, 3, 1)
        right = ((axes[..., i, :] - axes[..., j, :]) ** 2).sum(-1) - 2
        return torch.cat([unit, right, com - system.ell * (axes[..., 2, :] - com)], -1)
    pts = x.unflatten(-1, (system.n, 2))
    rel = torch.cat([pts[..., :1, :], pts[..., 1:, :] - pts[..., :-1, :]], -2)
    return (rel**2).sum(-1) - system.l.to(x) ** 2


def off_manifold_states(system, n=16):
    gen = torch.Generator().manual_seed(3)
    s = system.to_chart(system.sample_initial(n, gen), "angle", "cartesian")
    return s + 0.1 * torch.randn(s.shape, generator=gen, dtype=s.dtype)


@pytest.mark.parametrize("system_name", SYSTEMS)
def test_closed_form_jacobians_equal_autodiff(system_name):
    system = SYSTEMS[system_name]()
    assert isinstance(system.constraints, DistanceConstraints)
    x, v = off_manifold_states(system).chunk(2, -1)
    assert torch.allclose(system.constraints(x), hand_written_phi(system, x), rtol=0, atol=1e-12)
    jac, d_rate = system.constraints.jacobians(x, v)
    jac_ad, d_rate_ad = constraint_jacobians(lambda y: hand_written_phi(system, y), x, v)
    assert (jac - jac_ad).abs().max() < 1e-10
    assert (d_rate - d_rate_ad).abs().max() < 1e-10


@pytest.mark.parametrize("system_name", SYSTEMS)
@pytest.mark.parametrize("cls", [CHNN, CLNN], ids=lambda c: c.__name__)
def test_fast_field_equals_general_path(cls, system_name):
    system = SYSTEMS[system_name]()
    torch.manual_seed(0)
    fast = cls(system, hidden=16, depth=2).double()
    with torch.no_grad():
        for p in fast.masses.parameters():
            p.normal_(0.0, 0.5)  # learned (random) masses
    general = cls(system, hidden=16, depth=2).double()
    general.load_state_dict(fast.state_dict())
    general.constraints = lambda y: hand_written_phi(system, y)  # an arbitrary Φ: the autodiff path
    masses = [p.exp() for p in general.masses.log_params]
    general.point_masses = lambda: point_mass_matrix(system.layout, masses)  # assembled, then inverted
    general.point_masses_inverse = lambda: torch.linalg.inv(general.point_masses())
    assert (fast.point_masses() - general.point_masses()).abs().max() < 1e-12
    assert (fast.point_masses_inverse() - general.point_masses_inverse()).abs().max() < 1e-10
    s = off_manifold_states(system)
    z = fast.to_internal(s)
    t = torch.tensor(0.0, dtype=torch.float64)
    assert (z - general.to_internal(s)).abs().max() < 1e-12
    assert (fast(t, z) - general(t, z)).abs().max() < 1e-10 * max(1.0, general(t, z).abs().max().item())
    assert (fast.from_internal(z) - s).abs().max() < 1e-10


@pytest.mark.parametrize("system_name", ["pendulum2", "gyroscope"])  # without and with constant linear rows
@pytest.mark.parametrize("cls", [CHNN, CLNN], ids=lambda c: c.__name__)
def test_member_stacked_masses_give_each_members_own_field(cls, system_name):
    """Three members with their own random masses and potentials, as one model with the ensemble dimension
    (``PointMasses.ensemble``: member-stacked M⁻¹, M_P⁻¹ and P₂, ``encons.infra.batching.product``), outside and
    inside ``rollout_scope``: member k's rows of the field, ``to_internal`` and ``from_internal`` equal member k's
    own."""
    system = SYSTEMS[system_name]()
    members = []
    for seed in range(3):
        torch.manual_seed(seed)
        model = cls(system, hidden=16, depth=2).double()
        with torch.no_grad():
            for p in model.masses.parameters():
                p.normal_(0.0, 0.5)
        members.append(model)
    one = stacked.dimension_model(members)
    assert one is not None and one.masses.params().shape == (3, system.layout.n_points)
    s = torch.stack([off_manifold_states(system, 5)] * 3)  # (K, N, 2D): the member axis first
    t = torch.tensor(0.0, dtype=torch.float64)
    want_z = torch.stack([m.to_internal(s[k]) for k, m in enumerate(members)])
    want_field = torch.stack([m(t, want_z[k]) for k, m in enumerate(members)])
    assert (one.to_internal(s) - want_z).abs().max() < 1e-12
    for scope in (contextlib.nullcontext(), one.rollout_scope()):
        with scope:
            assert (one(t, want_z) - want_field).abs().max() < 1e-10 * want_field.abs().max()
            assert (one.from_internal(want_z) - s).abs().max() < 1e-10
    fresh = [cls(system, hidden=16, depth=2).double() for _ in range(3)]
    stacked.copy_members(one, fresh)  # the members' slices written back: each is its member again
    assert (torch.stack([m(t, want_z[k]) for k, m in enumerate(fresh)]) - want_field).abs().max() < 1e-10 * (
        want_field.abs().max()
    )
