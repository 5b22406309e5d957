"""Every script left in benchmarks/ (speed benches and the evaluation's floor: grids are encons.tools.benchmark
profiles) runs at a smoke size, so none can rot: each runs as ``__main__`` without an exception and prints its table.
Timings are not
asserted."""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).parents[2] / "benchmarks"
SMOKE = {
    "jacobian_speed.py": ["--dims", "2", "--batch", "8", "--hidden", "8", "--repeats", "1"],
    "symo_speed.py": ["--steps", "1", "--batch", "4"],
    # the stacked path forced: the path a run would take is timed, and at smoke size either may win
    "ensemble_speed.py": [
        "--cells",
        "lim_kasim",
        "--members",
        "1",
        "2",
        "--steps",
        "1",
        "--repeats",
        "1",
        "--path",
        "stacked",
        "--ceiling",
    ],
    "evaluation_floor.py": ["pendulum1", "2"],
    "pixel_speed.py": ["--steps", "1", "--videos", "2", "--frames", "10"],
    "time_to_accuracy.py": ["--runs", "node/pendulum2", "--max-epochs", "1", "debug=fast"],
    "control_b.py": None,
    "control_b_curve.py": None,
    "profile_costs.py": None,
    "structure_figures.py": None,  # report makers (not smoke-run)
    "speed.py": [
        "--systems",
        "pendulum2",
        "--models",
        "chnn",
        "--steps",
        "1",
        "--repeats",
        "1",
        "--naive-steps",
        "0",
        "--compile",
        "--batch",
        "4",
        "--chunk",
        "3",
        "--hidden",
        "8",
        "--depth",
        "1",
    ],
}
PRINTS = {
    "evaluation_floor.py": "geom_rel_err",
    "jacobian_speed.py": "vmap(jacrev)",
    "symo_speed.py": "E2ESyMo",
    "ensemble_speed.py": ("lim_kasim | 2 | stacked", "ceiling: lim_kasim | 2 | "),
    "pixel_speed.py": "rollout frames/s",
    "speed.py": "chnn",
    "time_to_accuracy.py": "node/pendulum2",
}


def test_every_benchmark_script_has_a_smoke_run():
    assert sorted(p.name for p in BENCHMARKS.glob("*.py")) == sorted(SMOKE)


@pytest.mark.slow
@pytest.mark.parametrize("script", sorted(s for s, args in SMOKE.items() if args is not None))
def test_benchmark_script_runs_at_smoke_size(script, tmp_path, monkeypatch, capsys):
    """Each script as ``python benchmarks/<script>`` runs it (``__main__``), in this process: a new interpreter
    would spend ~6 s of each smoke run importing Lightning."""
    extra = ["--out", str(tmp_path / "out.csv")] if script in ("speed.py", "time_to_accuracy.py") else []
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("WANDB_MODE", "disabled")
    monkeypatch.setattr(sys, "argv", [str(BENCHMARKS / script), "--threads", "1", *extra, *SMOKE[script]])
    runpy.run_path(str(BENCHMARKS / script), run_name="__main__")
    out = capsys.readouterr().out
    expected = PRINTS[script]
    assert all(line in out for line in ((expected,) if isinstance(expected, str) else expected)), out
