"""NODE fed the true field rolls out the truth; HNN maps and defaults (the true-physics checks of
every structured model are in tests/models/test_true_physics.py)."""

from __future__ import annotations

import pytest
import torch

from encons.data.simulate import simulate
from encons.infra.errors import ConfigError
from encons.models.base import DynamicsModel
from encons.models.hnn import HNN
from encons.models.node import NODE
from encons.numerics.integrators import Integrator, rollout, state_derivative
from encons.systems.pendulum import NPendulum


class _Field(torch.nn.Module):
    def __init__(self, system):
        super().__init__()
        self.system = system

    def forward(self, z):
        return self.system.vector_field(z, "angle")


@pytest.fixture
def system_and_states():
    system = NPendulum(2, masses=[1.0, 1.5], lengths=[1.0, 0.8])
    return system, system.sample_initial(64, torch.Generator().manual_seed(3))


def test_hnn_with_learned_pieces_is_not_exact(system_and_states):
    """The check above can fail: an untrained HNN is far from the true field."""
    system, s = system_and_states
    model = HNN(system, hidden=8, depth=1).double()
    assert not torch.allclose(state_derivative(model, s), system.vector_field(s, "angle"), atol=1e-3)


def test_node_with_true_field_rolls_out_the_truth(system_and_states):
    system, s = system_and_states
    model = NODE(system, hidden=8, depth=1).double()
    model.net = _Field(system)
    t = torch.arange(11, dtype=torch.float64) * 0.03
    pred = rollout(model, s, t, Integrator("rk4", substeps=10))
    truth = rollout(model, s, t, Integrator("dopri5", rtol=1e-12, atol=1e-12))
    assert torch.allclose(state_derivative(model, s), system.vector_field(s, "angle"))
    assert (pred - simulate(system, s, t, substeps=10)).abs().max() < 1e-12  # the generator's own path
    assert (pred - truth).abs().max() < 1e-6


def test_hnn_momentum_map_round_trip(system_and_states):
    system, s = system_and_states
    model = HNN(system, hidden=8, depth=1, angular=True).double()
    assert torch.allclose(model.from_internal(model.to_internal(s)), s, atol=1e-10)


def test_a_rollout_starts_at_its_start_and_maps_back_only_the_later_states(system_and_states, monkeypatch):
    """Index 0 is the given state itself, not decode(encode(start)) recomputed: a learned decoder
    (HNN's M(q)⁻¹ p) runs on the T − 1 later states only."""
    system, s = system_and_states
    model = HNN(system, hidden=8, depth=1).double()
    decoded = []
    decode = model.from_internal
    monkeypatch.setattr(model, "from_internal", lambda z: decoded.append(z.shape[:-1]) or decode(z))
    t = torch.arange(6, dtype=torch.float64) * 0.03
    pred = rollout(model, s, t, Integrator("rk4"))
    assert torch.equal(pred[:, 0], s) and pred.shape == (64, 6, 4)
    assert decoded == [(64, 5)]  # batch-major (a seed ensemble's members fold into the batch axis)
    assert not torch.allclose(pred[:, 1], s, atol=1e-3)  # and it moves


def test_a_model_defining_the_old_encode_is_refused_with_the_new_names():
    with pytest.raises(ConfigError, match=r"defines encode/decode; allowed: to_internal\(s\)/from_internal\(z\)"):

        class Old(DynamicsModel):
            def encode(self, s):
                return s
