"""End to end on tiny configs, read from the catalogue (conf/model, conf/system):

- every model on every system of ``KINDS`` it can serve (a rigid body in Cartesian and angle charts, an
  angle chart with dissipation, controls), the rest skipped with their reason (the angle chains, the
  plain oscillator and friction systems, which add no model code path, train with one model each
  below; node/regularisers on the mass-spring and glnn/second_order on friction in
  test_lim_kasim_e2e and test_glnn);
- every simulated system with the first catalogue model that can serve it, the figures drawn on one
  system per evaluator set (drawing costs most of a tiny run).

The full model × system product (~300 runs) costs more CI time than it catches beyond these two.
"""

from __future__ import annotations

import functools
import math

import pytest

from encons.entry import api
from encons.infra.errors import ConfigError
from tests.helpers import SANTOS_TINY, simulated_systems

KINDS = ["gyroscope", "damped_pendulum", "pendulum_control"]


@functools.lru_cache(maxsize=None)
def _santos(system: str) -> bool:
    return bool(api.compose(f"system={system}", output_dir=".").get("evaluators", {}).get("santos"))


def composed(model: str, system: str, tmp_path, figures: bool = False):
    """The tiny run of ``model`` on ``system``, composed once for the build check and the training."""
    extra = SANTOS_TINY if _santos(system) else []
    return api.compose(
        "debug=fast",
        f"figures={str(figures).lower()}",
        f"model={model}",
        f"system={system}",
        *extra,
        output_dir=tmp_path / "run",
        cache_dir=tmp_path / "cache",
    )


def builds(cfg) -> str | None:
    """None when the run's model can serve its system, else the one-line reason."""
    from hydra.utils import execution_whitelist

    from encons.config.check import validate
    from encons.config.trust import trusted_targets
    from encons.training.build import build_model, build_system

    try:
        with execution_whitelist(trusted_targets()):
            checked = validate(cfg)
            build_model(checked, build_system(checked))
    except ConfigError as err:
        return str(err)
    return None


def trains(cfg) -> None:
    results = api.train(cfg).metrics  # a DivergenceError fails the test
    assert math.isfinite(results["test/traj_rel_err"])
    assert math.isfinite(results["best/val/traj_rel_err"])


def test_kinds_are_in_the_catalogue():
    assert set(KINDS) <= set(simulated_systems())


@pytest.mark.slow
@pytest.mark.parametrize("system", KINDS)
@pytest.mark.parametrize("model", api.catalogue("model"))
def test_every_model_trains(tmp_path, model, system):
    cfg = composed(model, system, tmp_path)
    reason = builds(cfg)
    if reason:
        pytest.skip(f"declared incompatibility: {reason}")
    trains(cfg)


#: One system per evaluator set draws its figures (states; states + Santos §7; pixels; states + accel_mse).
FIGURES = {"gyroscope", "pendulum_control", "pixel_pendulum", "compound_pendulum"}


@pytest.mark.slow
@pytest.mark.parametrize("system", simulated_systems())
def test_every_system_trains(tmp_path, system):
    cfg = next(
        (c for m in api.catalogue("model") if builds(c := composed(m, system, tmp_path, system in FIGURES)) is None),
        None,
    )
    assert cfg is not None, f"no catalogue model serves {system}"
    trains(cfg)
    assert bool(list((tmp_path / "run" / "figures").glob("*.png"))) == (system in FIGURES)
