"""LNN trains at defaults: a 20-epoch run on tiny data, with the default network
(3 × 256, as every default run has; debug=fast shrinks it to 2 × 16), stays finite and learns."""

from __future__ import annotations

import math

import pytest

#: Measured: no start learns the debug-size gyroscope in 40 steps. Best val after 1 -> 20 epochs (lr 1e-3): this start
#: 0.3675 -> 0.3675 (also at lr 3e-3, and over 60 epochs), jointly convex 0.3875 -> 0.3875, the old damping λ = 1
#: 0.54 -> 0.357; predicting q̈ = 0 (constant velocity) scores 0.323 on these windows, so none has learned q̈ there yet.
GYROSCOPE = pytest.mark.xfail(
    strict=True,
    reason="no LNN start learns the debug-size gyroscope within 40 steps: best val "
    "stays at the first epoch's (0.3675), above the q̈ = 0 predictor's 0.323 (measured)",
)


@pytest.mark.slow
@pytest.mark.parametrize("system", ["pendulum2", pytest.param("gyroscope", marks=GYROSCOPE)])
def test_lnn_twenty_epochs_finite_and_val_error_falls(train_run, system):
    default_net = ["model.hidden=256", "model.depth=3"]
    first = train_run(["model=lnn", f"system={system}", "trainer.max_epochs=1", *default_net], name="one")
    last = train_run(["model=lnn", f"system={system}", "trainer.max_epochs=20", *default_net], name="twenty")
    assert all(math.isfinite(v) for v in last.values()), last
    # measured on pendulum2 (best val after 1 -> 20 epochs, lr 1e-3): 1.060 -> 0.693 (0.65x; q̈ = 0 scores 1.12);
    # from the jointly convex start (no q/q̇ separation) 1.324 -> 1.285 (0.97x): its concave potential pushed the
    # fresh rollouts away and it did not learn in 40 steps
    assert last["best/val/traj_rel_err"] < 0.75 * first["best/val/traj_rel_err"]
