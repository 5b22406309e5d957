"""Evaluating a run's last checkpoint reproduces its test metrics; overrides change the test set."""

from __future__ import annotations

import pytest

from encons.errors import ConfigError
from encons.evaluate import evaluate


def test_evaluate_reproduces_the_run_and_extends_the_horizon(train_run, tmp_path):
    results = train_run(["model=hnn_angle", "system=pendulum1"], name="run")
    again = evaluate(tmp_path / "run", ["ckpt=last"])
    assert again["test/traj_rel_err"] == pytest.approx(results["test/traj_rel_err"], rel=1e-6)
    longer = evaluate(tmp_path / "run", ["ckpt=last", "data.test_steps=40"])
    assert longer["test/rel_err_final"] != again["test/rel_err_final"]
    assert (tmp_path / "run" / "evaluation" / "figures" / "rollout.png").is_file()


def test_evaluate_names_a_missing_run(tmp_path):
    with pytest.raises(ConfigError, match="not a training run folder"):
        evaluate(tmp_path)
