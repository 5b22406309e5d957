"""The hidden size × depth grid of Xiao et al. Tables 3–4 (sweeps/glnn_size.yaml), on a tiny config."""

from __future__ import annotations

import json

import pytest

from encons.tools.report import write_sweep_report


@pytest.mark.slow
def test_glnn_size_grid_runs_every_width_and_depth(tmp_path, cli, monkeypatch):
    monkeypatch.setenv("ENCONS_ROOT", str(tmp_path))
    proc = cli(
        "-m",
        "sweeps=glnn_size",
        "debug=fast",
        "figures=false",
        "trainer.max_epochs=1",
        "model.hidden=8,16",
        "model.depth=2,3",
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    folder = next((tmp_path / "multirun" / "glnn_size-damped_oscillator").iterdir())
    results = {p.name: json.loads((p / "test_metrics.json").read_text()) for p in folder.iterdir() if p.is_dir()}
    assert sorted(results) == ["h16-d2", "h16-d3", "h8-d2", "h8-d3"]
    assert all("state_mse" in r and "baseline_linear_ode/state_mse" in r for r in results.values())
    # the report of the multirun: one row per job and Tables 3–4's hidden × depth layout
    (folder / "h16-d3" / "test_metrics.json").unlink()  # a job that did not finish
    write_sweep_report(folder)
    md = (folder / "sweep.md").read_text()
    mse = {name: f"{r['state_mse_final']:.3g}" for name, r in results.items()}
    assert "| 8 | 2 | " in md and "| 16 | 3 | not finished |" in md
    table = md.split("state_mse_final: model.hidden (rows) × model.depth (columns)")[1]
    assert "| model.hidden \\ model.depth | 2 | 3 |" in table
    assert f"| 8 | {mse['h8-d2']} | {mse['h8-d3']} |" in table and f"| 16 | {mse['h16-d2']} | — |" in table
    assert (folder / "sweep.csv").read_text().count("\n") == 5
