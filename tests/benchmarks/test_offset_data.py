"""``benchmarks/reports/zhong-200/cause/offset_data.py``: Finzi et al.'s flattened unwrap gives the offsets k it
should on trajectories whose served angles are known (the script itself runs on the profile's data in seconds; its
committed item1-*.json are what it printed)."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import torch

from encons.systems.pendulum import NPendulum

SCRIPT = Path(__file__).parents[2] / "benchmarks" / "reports" / "zhong-200" / "cause" / "offset_data.py"


def _script():
    spec = importlib.util.spec_from_file_location("offset_data", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_flattened_unwrap_walks_across_trajectories():
    script = _script()
    still = [(3.0, 0.0), (-3.0, 0.0), (-3.0, 7.0), (3.0, 0.0)]  # resting angles (θ1, θ2); 7 beyond (−π, π]
    trajectories = torch.tensor([[[a, b, 0.0, 0.0]] * 8 for a, b in still], dtype=torch.float64)
    starts = np.zeros(4, dtype=np.int64)
    k, residual, _ = script.offsets("pendulum2", NPendulum(n_links=2), trajectories, np.arange(4), starts)
    # 3 → −3 is served as 2π − 3 (k 1), kept by the next; θ2 = 7 is served as 7 − 2π (k −1); then −3 → 3 back
    assert k.tolist() == [[0, 0], [1, 0], [1, -1], [0, 0]] and residual < 1e-12
    k, _, _ = script.offsets("pendulum2", NPendulum(n_links=2), trajectories, np.array([1, 0, 2, 3]), starts)
    assert k[:, 0].tolist() == [-1, 0, 0, -1]  # the generation order decides the walk: −3 first, 3 is served −2π


def test_the_gyroscope_is_served_on_scipys_branch():
    script = _script()
    q = torch.tensor([0.1, -0.5, 0.2], dtype=torch.float64)
    trajectories = torch.cat([q, torch.zeros(3, dtype=torch.float64)]).expand(1, 6, 6).clone()
    k, residual, flipped = script.offsets("gyroscope", None, trajectories, np.arange(1), np.zeros(1, dtype=np.int64))
    assert flipped.tolist() == [True] and residual < 1e-9
    served = script.served_angles("gyroscope", None, trajectories[:, :1])[0, 0]
    assert torch.allclose(served, script.on_branch("gyroscope", q) + 2 * math.pi * torch.from_numpy(k[0]))
