"""benchmarks/speed.py compares like with like: its straightforward implementations compute the
models' own fields (float64, random states and masses). benchmarks/time_to_accuracy.py stops a run at
its target and says when a target was not reached (at a smoke size)."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

from encons.models.constrained import CHNN, CLNN
from encons.models.lnn import LNN, LNNStructure
from encons.systems.gyroscope import Gyroscope
from encons.systems.pendulum import NPendulum


def _script(name: str):
    spec = importlib.util.spec_from_file_location(name, Path(__file__).parents[2] / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


speed, tta = _script("speed"), _script("time_to_accuracy")

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
    z = model.to_internal(system.to_chart(s0, system.base_chart, model.chart))
    t = torch.zeros((), dtype=torch.float64)
    fast, naive = model(t, z), speed.naive_of(model, system)(t, z)
    assert (fast - naive).abs().max() < 1e-8 * fast.abs().max()


def test_time_to_accuracy_stops_at_the_target(tmp_path):
    row = tta.time_to_accuracy("node", "pendulum1", 1e9, 3, tmp_path, ("debug=fast",))
    assert row["reached"] and row["epochs"] == 1 and row["time_to_target_s"] > 0
    assert math.isfinite(row["val_traj_rel_err"]) and row["val_traj_rel_err"] > 0 and row["test_traj_rel_err"] > 0


def test_the_clock_stops_at_the_first_validation_at_or_below_its_target():
    """The rule the table reports: the first validation at or below the target stops training there (its epoch
    and value are the row's); a target never met runs the budget and has no time."""

    def validate(clock, values):
        trainer = SimpleNamespace(should_stop=False, current_epoch=0, callback_metrics={})
        clock.on_fit_start(trainer, None)
        for epoch, value in enumerate(values):
            if trainer.should_stop:
                break
            trainer.current_epoch, trainer.callback_metrics = epoch, {"val/traj_rel_err": torch.tensor(value)}
            clock.on_validation_end(trainer, None)
        return trainer.should_stop

    values = [0.9, 0.6, 0.5, 0.2]
    met = tta.Clock(0.5)
    assert validate(met, values) and met.epochs == 3 and met.value == 0.5 and met.reached_s >= 0
    missed = tta.Clock(0.1)
    assert not validate(missed, values) and missed.reached_s is None and missed.epochs == 4
    assert missed.value == pytest.approx(0.2)


def test_time_to_accuracy_reports_a_target_not_reached(tmp_path):
    out = tmp_path / "tta.csv"
    rows = tta.main(
        [
            "--runs",
            "node/pendulum2",
            "--max-epochs",
            "2",
            "--out",
            str(out),
            "debug=fast",
            "data.n_train=4",
            "data.n_val=2",
            "data.n_test=2",
        ]
    )
    assert [(r["reached"], r["time_to_target_s"], r["epochs"]) for r in rows] == [(False, None, 2)]
    assert "not in 2 epochs" in out.with_suffix(".md").read_text()
