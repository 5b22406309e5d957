"""Every foundation model × pendulum system trains end to end on a tiny config."""

from __future__ import annotations

import math

import pytest


@pytest.mark.parametrize("system", ["pendulum1", "pendulum2", "pendulum4"])
@pytest.mark.parametrize("model", ["node", "hnn", "hnn_angle"])
def test_trains_end_to_end(train_run, model, system):
    results = train_run([f"model={model}", f"system={system}"])
    assert math.isfinite(results["test/traj_rel_err"])
    assert math.isfinite(results["val/traj_rel_err"])
