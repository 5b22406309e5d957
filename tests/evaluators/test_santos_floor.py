"""Santos §7's one-step MSE rolls out by each model's own step, so each model has its own floor: the system's true
dynamics stepped that way (``DynamicsModel.true_counterpart``), reported as ``mse_test_floor`` beside ``mse_test``.
The floors follow the steps' orders of accuracy on the cart-pole (the values at the paper's h = 0.05 on this
project's data: ``benchmarks/reports/santos-2000-seeds/floor.json``)."""

from __future__ import annotations

import math

import pytest

from encons.entry.api import build
from encons.evaluators.santos import SantosMetrics
from encons.models.base import TrueField
from encons.training.build import compose


def floors(tmp_path, dt: float) -> dict[str, float]:
    """The one-step test MSE floors of SyMo's midpoint DEL step and of the true field by RK4 and by the explicit
    midpoint rule, on the same cart-pole test trajectories of step ``dt``."""
    out = {}
    for name, overrides in {
        "del": ["model=e2e_symo"],
        "rk4": ["model=lnode", "integrator=rk4"],
        "midpoint": ["model=lnode", "integrator=midpoint"],
    }.items():
        cfg = compose(
            ["debug=fast", "system=cartpole", "logger=none", f"data.dt={dt}", *overrides],
            tmp_path / name / "run",
            tmp_path / "cache",
        )
        data, module = build(cfg)
        data.prepare_data()
        data.setup("test")
        floor = module.model.true_counterpart(module.system)
        assert floor is not None
        if name != "del":
            assert isinstance(floor, TrueField)
        out[name] = SantosMetrics.one_step_mse(module, data.arrays["test"], floor.double())
    return out


@pytest.mark.slow
def test_each_steps_floor_follows_its_order_of_accuracy(tmp_path):
    h = (0.05, 0.025, 0.0125)
    f = {dt: floors(tmp_path / str(dt), dt) for dt in h}
    # at the paper's step: RK4 far below the variational midpoint DEL, far below the explicit midpoint rule
    # (measured 2.7e-12, 1.01e-08, 4.25e-07 on the paper-size test set)
    assert f[0.05]["rk4"] < 1e-9 < f[0.05]["del"] < 1e-7 < f[0.05]["midpoint"]

    def slope(step: str, coarse: float, fine: float) -> float:  # p in MSE ∝ hᵖ
        return math.log2(f[coarse][step] / f[fine][step])

    # the DEL step is the central difference q_{k+1} − 2q_k + q_{k−1} = h² q̈ + O(h⁴): MSE ∝ h⁸ (measured 8.05, 7.8)
    assert 7.5 < slope("del", 0.05, 0.025) < 8.5 and 7.5 < slope("del", 0.025, 0.0125) < 8.5
    # one step of the explicit midpoint rule errs by O(h³) in q, of RK4 by O(h⁵): MSE ∝ h⁶ and h¹⁰ as h → 0
    # (measured 7.86 then 6.68, and 12.1 then 10.7: the coarser pair is not yet asymptotic)
    assert 6 < slope("midpoint", 0.025, 0.0125) < 7
    assert 10 < slope("rk4", 0.025, 0.0125) < 11.5
