"""benchmarks/speed.py compares like with like: its straightforward implementations compute the
models' own fields (float64, random states and masses)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
import torch

from encons.models.constrained import CHNN, CLNN
from encons.models.lnn import LNN, LNNStructure
from encons.systems.gyroscope import Gyroscope
from encons.systems.pendulum import NPendulum

SPEC = importlib.util.spec_from_file_location("speed", Path(__file__).parents[1] / "benchmarks" / "speed.py")
speed = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(speed)

SYSTEMS = {"pendulum2": lambda: NPendulum(2, masses=[1.0, 1.5]), "gyroscope": Gyroscope}


@pytest.mark.parametrize("system_name", SYSTEMS)
@pytest.mark.parametrize("cls", [CHNN, CLNN, LNN, LNNStructure], ids=lambda c: c.__name__)
def test_naive_field_is_the_model_field(cls, system_name):
    system = SYSTEMS[system_name]()
    torch.manual_seed(0)
    model = cls(system, hidden=16, depth=2).double()
    if isinstance(model, (CHNN, CLNN)):
        with torch.no_grad():
            for p in model.masses.parameters():
                p.normal_(0.0, 0.3)
    s0 = system.sample_initial(64, torch.Generator().manual_seed(1))
    s0 = s0[torch.sin(s0[:, 1]).abs() > 0.3][:8] if isinstance(system, Gyroscope) else s0[:8]
    z = model.encode(system.to_chart(s0, system.base_chart, model.chart))
    t = torch.zeros((), dtype=torch.float64)
    fast, naive = model(t, z), speed.naive_of(model, system)(t, z)
    assert (fast - naive).abs().max() < 1e-8 * fast.abs().max()
