"""Lim & Kasim's regularised runs train end to end and log their penalty (plain runs:
tests/training/test_train_e2e.py)."""

from __future__ import annotations

import math

import pytest

pytestmark = pytest.mark.slow  # end-to-end runs

TINY = ["data.test_steps=12", "data.substeps=2", "model.hidden=8"]


@pytest.mark.parametrize(
    "overrides",
    [
        ["model=node", "system=mass_spring", "regulariser=hamiltonian", "objective=derivative"],
        ["model=node", "system=damped_pendulum", "regulariser=dissipative", "objective=derivative"],
        ["model=hnn", "system=pendulum", "regulariser=hamiltonian"],
    ],
)
def test_regularised_runs_log_their_penalty(train_run, overrides):
    results = train_run([*overrides, *TINY])
    assert results["train/regulariser"] > 0  # an untrained field is not exactly Hamiltonian / dissipative
    assert math.isfinite(results["test/energy_rmse_p97_5"])
