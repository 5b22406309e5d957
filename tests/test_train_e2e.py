"""Every model of the catalogue (conf/model) trains end to end on every simulated system of the
catalogue (conf/system) it can serve, on a tiny config; the rest are skipped with their reason."""

from __future__ import annotations

import math

import pytest
from encons import api
from encons.errors import ConfigError
from tests.helpers import simulated_systems


@pytest.mark.slow
@pytest.mark.parametrize("system", simulated_systems())
@pytest.mark.parametrize("model", api.catalogue("model"))
def test_trains_end_to_end(train_run, tmp_path, model, system):
    from hydra.utils import execution_whitelist

    from encons.config import build_model, build_system

    cfg = api.compose("debug=fast", f"model={model}", f"system={system}", output_dir=tmp_path)
    try:
        with execution_whitelist(api.trusted_targets()):
            build_model(cfg, build_system(cfg))
    except ConfigError as err:
        pytest.skip(str(err))
    results = train_run([f"model={model}", f"system={system}"])  # a DivergenceError fails the test
    assert math.isfinite(results["test/traj_rel_err"])
    assert math.isfinite(results["best/val/traj_rel_err"])
