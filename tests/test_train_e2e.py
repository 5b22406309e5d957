"""End to end on tiny configs, read from the catalogue (conf/model, conf/system):

- every model on every system of ``KINDS`` it can serve (an angle chain, a rigid body, dissipation,
  controls), the rest skipped with their reason (the plain oscillator and friction systems, which
  add no model code path, train with one model each below, and node/regularisers on the mass-spring
  and glnn/second_order on friction in test_lim_kasim_e2e and test_glnn);
- every simulated system with the first catalogue model that can serve it, its figures drawn (the
  model × system runs leave them out: drawing costs most of a tiny run).

The full model × system product (~300 runs) costs more CI time than it catches beyond these two.
"""

from __future__ import annotations

import math

import pytest
from encons import api
from encons.errors import ConfigError
from tests.helpers import simulated_systems

KINDS = ["pendulum2", "gyroscope", "damped_pendulum", "pendulum_control"]


def builds(model: str, system: str, tmp_path) -> str | None:
    """None when ``model`` can serve ``system``, else the one-line reason."""
    from hydra.utils import execution_whitelist

    from encons.build import build_model, build_system
    from encons.trust import trusted_targets

    cfg = api.compose("debug=fast", f"model={model}", f"system={system}", output_dir=tmp_path)
    try:
        with execution_whitelist(trusted_targets()):
            build_model(cfg, build_system(cfg))
    except ConfigError as err:
        return str(err)
    return None


def trains(train_run, model: str, system: str, figures: bool = False) -> None:
    overrides = [f"model={model}", f"system={system}"]
    if api.compose(f"system={system}", output_dir=".").get("evaluators", {}).get("santos"):
        overrides += ["evaluators.santos.steps=20", "evaluators.santos.n_trajectories=4"]  # §7's 500 × 16: minutes
    results = train_run(overrides, figures=figures)  # a DivergenceError fails the test
    assert math.isfinite(results["test/traj_rel_err"])
    assert math.isfinite(results["best/val/traj_rel_err"])


def test_kinds_are_in_the_catalogue():
    assert set(KINDS) <= set(simulated_systems())


@pytest.mark.slow
@pytest.mark.parametrize("system", KINDS)
@pytest.mark.parametrize("model", api.catalogue("model"))
def test_every_model_trains(train_run, tmp_path, model, system):
    reason = builds(model, system, tmp_path)
    if reason:
        pytest.skip(f"declared incompatibility: {reason}")
    trains(train_run, model, system)


@pytest.mark.slow
@pytest.mark.parametrize("system", simulated_systems())
def test_every_system_trains(train_run, tmp_path, system):
    model = next((m for m in api.catalogue("model") if builds(m, system, tmp_path) is None), None)
    assert model is not None, f"no catalogue model serves {system}"
    trains(train_run, model, system, figures=True)  # each system's evaluators draw their figures once here
    assert list((tmp_path / "run" / "figures").glob("*.png"))
