"""Every model × benchmark system trains end to end on a tiny config."""

from __future__ import annotations

import math

import pytest


SYSTEMS = ["pendulum1", "pendulum2", "pendulum4", "gyroscope"]
MODELS = ["node", "hnn", "hnn_angle", "hnn_structure", "hnn_structure_angle", "lnn", "lnn_angle", "lnn_structure",
          "lnn_structure_angle", "chnn", "clnn"]


@pytest.mark.parametrize("system", SYSTEMS)
@pytest.mark.parametrize("model", MODELS)
def test_trains_end_to_end(train_run, model, system):
    results = train_run([f"model={model}", f"system={system}"])
    assert math.isfinite(results["test/traj_rel_err"])
    assert math.isfinite(results["val/traj_rel_err"])
