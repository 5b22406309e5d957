"""Rollouts through torchdiffeq on ż = −z: every fixed-step method honours ``integrator.substeps``,
Euler matches its closed form."""

from __future__ import annotations

import pytest
import torch

from encons.models.base import DynamicsModel
from encons.numerics.integrators import FIXED_STEP, Integrator, rollout
from encons.systems.pendulum import NPendulum


class Decay(DynamicsModel):
    def forward(self, t, z, u=None):
        return -z


@pytest.fixture(scope="module")
def decay():
    return Decay(NPendulum(n_links=1))


def error(model, integrator: Integrator) -> float:
    t = torch.linspace(0, 1, 5, dtype=torch.float64)
    s0 = torch.tensor([[1.0, -0.5]], dtype=torch.float64)
    return float((rollout(model, s0, t, integrator) - s0[:, None] * torch.exp(-t)[:, None]).abs().max())


def test_fixed_step_methods_are_torchdiffeqs_fixed_grid_solvers():
    assert {"euler", "rk4", "fixed_adams", "implicit_adams"} <= set(FIXED_STEP) and "dopri5" not in FIXED_STEP


@pytest.mark.parametrize("method", FIXED_STEP)
def test_substeps_multiply_the_steps_of_every_fixed_step_method(method):
    counts = []
    for k in (1, 4):
        model = Decay(NPendulum(n_links=1))
        model.calls = 0
        model.register_forward_hook(lambda *_: setattr(model, "calls", model.calls + 1))
        error(model, Integrator(method, substeps=k))
        counts.append(model.calls)
    assert counts[1] > 2 * counts[0], counts  # 4× the steps (multistep methods: plus start-up evaluations)


def test_euler_substeps_match_the_closed_form(decay):
    k, dt = 3, 0.25  # k Euler steps of dt/k per data step: (1 − dt/k)^k per step, exactly
    t = torch.arange(5, dtype=torch.float64) * dt
    out = rollout(decay, torch.ones(1, 2, dtype=torch.float64), t, Integrator("euler", substeps=k))
    assert torch.allclose(out[0, :, 0], (1 - dt / k) ** (k * torch.arange(5.0, dtype=torch.float64)), rtol=1e-12)
