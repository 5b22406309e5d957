"""The hidden size × depth grid of Xiao et al. Tables 3–4 (sweeps/glnn_size.yaml), on a tiny config."""

from __future__ import annotations

import json

import pytest

from tests.helpers import run_cli


@pytest.mark.slow
def test_glnn_size_grid_runs_every_width_and_depth(tmp_path):
    proc = run_cli("-m", "sweeps=glnn_size", "debug=fast", "trainer.max_epochs=1",
                   "model.hidden=8,16", "model.depth=2,3",
                   cwd=tmp_path, env={"ENCONS_ROOT": str(tmp_path)})
    assert proc.returncode == 0, proc.stderr[-3000:]
    folder = next((tmp_path / "multirun" / "glnn_size-damped_oscillator").iterdir())
    results = {p.name: json.loads((p / "test_metrics.json").read_text()) for p in folder.iterdir() if p.is_dir()}
    assert sorted(results) == ["h16-d2", "h16-d3", "h8-d2", "h8-d3"]
    assert all("state_mse" in r and "baseline_linear_ode/state_mse" in r for r in results.values())
