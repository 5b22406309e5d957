"""LNN trains at defaults (issue 11 item 3): a 20-epoch tiny run stays finite and learns."""

from __future__ import annotations

import math

import pytest


@pytest.mark.slow
@pytest.mark.parametrize("system", ["pendulum2", "gyroscope"])
def test_lnn_twenty_epochs_finite_and_val_error_falls(train_run, system):
    first = train_run(["model=lnn", f"system={system}", "trainer.max_epochs=1"], name="one")
    last = train_run(["model=lnn", f"system={system}", "trainer.max_epochs=20"], name="twenty")
    assert all(math.isfinite(v) for v in last.values()), last
    assert last["best/val/traj_rel_err"] < 0.9 * first["best/val/traj_rel_err"]
