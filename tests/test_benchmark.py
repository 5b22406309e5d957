"""The benchmark grid trains every combination on shared data and writes tables and figures."""

from __future__ import annotations

import csv

import pytest

from encons.benchmark import main

pytestmark = pytest.mark.slow  # four end-to-end runs


def test_grid_writes_tables_and_figures(tmp_path):
    out = tmp_path / "bench"
    main(["systems=[pendulum1]", "models=[node,hnn]", "seeds=[0,1]", f"out={out}", "debug=fast",
          f"paths.cache_dir={tmp_path / 'cache'}"])
    with (out / "results.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [(r["model"], r["seed"]) for r in rows] == [("node", "0"), ("node", "1"), ("hnn", "0"), ("hnn", "1")]
    assert all(float(r["test/traj_rel_err"]) > 0 for r in rows)
    assert len(list((tmp_path / "cache").iterdir())) == 1  # one dataset, shared by every run
    for name in ("summary.csv", "traj_rel_err.png", "rel_err_vs_time.png", "energy_err_vs_time.png"):
        assert (out / name).is_file()
