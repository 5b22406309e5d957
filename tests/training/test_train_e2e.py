"""End to end on tiny configs, read from the catalogue (conf/model, conf/system):

- every model on every system of ``KINDS`` it can serve (a rigid body in Cartesian and angle charts, an
  angle chart with dissipation, controls), the rest skipped with their reason (the angle chains, the
  plain oscillator and friction systems, which add no model code path, train with one model each
  below; node/regularisers on the mass-spring and glnn/second_order on friction in
  tests/papers/test_lim_kasim_e2e.py and tests/models/test_glnn.py);
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


def declared_incompatibility(cfg) -> str | None:
    """The one-line reason the catalogue declares why the run's model cannot serve its system (the model class's
    capabilities against the built system, ``encons.config.check.check_capabilities``, and the observation's
    objectives), else None. The model is not built: a constructor that refuses a pair its class declares it
    serves raises in the training below and fails the test, not skips it."""
    from hydra.utils import execution_whitelist

    from encons.config import trust
    from encons.config.check import check_capabilities, check_observation, validate
    from encons.training.build import build_observation, build_system

    with execution_whitelist(trust.trusted_targets()):
        try:
            checked = validate(cfg)  # the classes' declarations (capabilities, objectives); no model is built
            system = build_system(checked)
            observation = build_observation(checked, system)
            check_observation(type(observation), checked.objective)
            check_capabilities(checked.cfg, checked.model, observation.latent_system(system), checked.request)
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
    reason = declared_incompatibility(cfg)
    if reason:
        pytest.skip(f"declared incompatibility: {reason}")
    trains(cfg)  # any ConfigError here (a model refusing what it declares it serves) fails


#: One system per evaluator set draws its figures (states; states + Santos §7; pixels; states + accel_mse).
FIGURES = {"gyroscope", "pendulum_control", "pixel_pendulum", "compound_pendulum"}


@pytest.mark.slow
@pytest.mark.parametrize("system", simulated_systems())
def test_every_system_trains(tmp_path, system):
    cfg = next(
        (
            c
            for m in api.catalogue("model")
            if declared_incompatibility(c := composed(m, system, tmp_path, system in FIGURES)) is None
        ),
        None,
    )
    assert cfg is not None, f"no catalogue model serves {system}"
    trains(cfg)
    assert bool(list((tmp_path / "run" / "figures").glob("*.png"))) == (system in FIGURES)


def test_a_model_refusing_a_pair_it_declares_it_serves_fails_not_skips(tmp_path, monkeypatch):
    """The skip above follows the declaration, not the refusal: a model whose constructor wrongly refuses every
    system is declared compatible with them, so its run raises the ConfigError (the test fails) instead of
    being skipped; a pair the catalogue declares unsupported is still named as such."""
    from encons.models.node import NODE

    def refuse(self, *args, **kwargs):
        raise ConfigError("model=node refuses every system; allowed: nothing")

    monkeypatch.setattr(NODE, "__init__", refuse)
    for system in KINDS:
        assert declared_incompatibility(composed("node", system, tmp_path)) is None
    with pytest.raises(ConfigError, match="refuses every system"):
        api.build(composed("node", "gyroscope", tmp_path))
    assert "lacks" in declared_incompatibility(composed("chnn", "pendulum_control", tmp_path))
    assert "control inputs" in declared_incompatibility(composed("hnn", "pendulum_control", tmp_path))
