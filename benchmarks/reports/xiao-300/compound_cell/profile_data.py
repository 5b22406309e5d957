"""The compound pendulum's data as ``python -m encons.benchmark profile=xiao`` composes them (shared by
``check_field.py`` and ``exp_split.py`` beside it).

The profile (conf/profile/xiao.yaml) is composed and expanded as the benchmark runner does
(``encons.tools.benchmark.expand``); the compound pendulum's baseline run's train config is composed from its
overrides and built (``encons.build``), which simulates the data into the cache (``.cache/encons`` at the
repository's root, shared with any other run of the same data config) or finds them there. The trajectories are
read back from that cache file in float64, in the base chart (angle), as simulated: the same data every cell
of the compound pendulum in that profile trains and is tested on (10 training, 2 validation, 10 test
trajectories; 500 points of h = 0.02 for training, 1000 for the test).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[4]
CACHE = ROOT / ".cache" / "encons"
SYSTEM = "compound_pendulum"


def profile_overrides(system: str = SYSTEM) -> list[str]:
    """The train overrides ``python -m encons.benchmark profile=xiao`` gives the first run of ``system``."""
    from encons.tools.benchmark import expand
    from encons.training.build import compose

    planned = expand(compose(["profile=xiao"], config_name="benchmark"))
    return next(run for run in planned if run.system == system).overrides


def profile_data(system: str = SYSTEM) -> tuple[object, dict[str, torch.Tensor], float]:
    """(the system, its float64 trajectories by split ``train`` / ``val`` / ``test`` (N, T, 4), dt)."""
    import encons
    from encons.data import store

    with tempfile.TemporaryDirectory() as out:
        cfg = encons.compose(*profile_overrides(system), "logger=none", output_dir=out, cache_dir=CACHE)
        data, _ = encons.build(cfg)
    _, splits, _ = store.load(data.cache_file)
    return data.system, splits, data.dt
