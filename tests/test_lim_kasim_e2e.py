"""Lim & Kasim's tasks: every new model × new system, with and without regularisers, trains end to end."""

from __future__ import annotations

import math

import pytest

SYSTEMS = ["mass_spring", "pendulum", "double_pendulum", "damped_pendulum"]
TINY = ["data.test_steps=12", "data.substeps=2", "model.hidden=8"]


@pytest.mark.parametrize("system", SYSTEMS)
@pytest.mark.parametrize("model, extra", [
    ("node", []),
    ("nsf", ["objective=derivative"]),
    ("inn_node", ["regulariser=hamiltonian", "model.blocks=2", "model.block_hidden=8"]),
])
def test_new_models_train_on_new_systems(train_run, model, extra, system):
    results = train_run([f"model={model}", f"system={system}", *TINY, *extra])
    assert math.isfinite(results["test/traj_rel_err"])
    assert math.isfinite(results["test/energy_rmse_median"])


@pytest.mark.parametrize("overrides", [
    ["model=node", "system=mass_spring", "regulariser=hamiltonian", "objective=derivative"],
    ["model=node", "system=damped_pendulum", "regulariser=dissipative", "objective=derivative"],
    ["model=hnn", "system=pendulum", "regulariser=hamiltonian"],
])
def test_regularised_runs_log_their_penalty(train_run, overrides):
    results = train_run([*overrides, *TINY])
    assert results["train/regulariser"] >= 0
    assert math.isfinite(results["test/energy_rmse_p97_5"])
