"""The scored model is the kept one: ``train`` tests the best checkpoint and ``evaluate`` agrees."""

from __future__ import annotations

import json

import pytest

from encons.entry import api
from encons.infra.errors import ConfigError

RUN = ["model=hnn_angle", "system=pendulum1", "trainer.max_epochs=3"]


def test_train_and_evaluate_report_identical_metrics_of_the_best_checkpoint(train_run, tmp_path):
    results = train_run(RUN, name="run")
    ckpts = tmp_path / "run" / "checkpoints"
    best = next(ckpts.glob("best-*.ckpt"))
    assert best.name == f"best-epoch{int(results['best_epoch']):04d}.ckpt"
    again = api.evaluate(tmp_path / "run")  # ckpt=best by default
    assert again == {k: v for k, v in results.items() if k.startswith("test/")}
    saved = json.loads((tmp_path / "run" / "test_metrics.json").read_text())
    assert {f"test/{k}": v for k, v in saved.items()} == again
    if results["best_epoch"] != 3:  # the last (third) epoch is not the best: last.ckpt must score differently
        last = api.evaluate(tmp_path / "run", ckpt="last")
        assert last["test/traj_rel_err"] != again["test/traj_rel_err"]


def test_longer_test_horizon_and_whole_trajectory_score(train_run, tmp_path):
    train_run(RUN, name="run")
    short = api.evaluate(tmp_path / "run", ["figures=true"])  # the run drew none (train_run); evaluate may
    longer = api.evaluate(tmp_path / "run", ["data.test_steps=40"])
    assert longer["test/traj_rel_err"] == pytest.approx(short["test/traj_rel_err"], rel=1e-5)  # first 4 steps
    assert longer["test/rel_err_final"] != short["test/rel_err_final"]
    whole = api.evaluate(tmp_path / "run", ["data.test_steps=40", "horizon=40"])
    assert whole["test/traj_rel_err"] > longer["test/traj_rel_err"]
    assert (tmp_path / "run" / "evaluation" / "figures" / "rollout.png").is_file()
    # each evaluation keeps its own folder: the second and third did not overwrite the first one's metrics
    first = json.loads((tmp_path / "run" / "evaluation" / "test_metrics.json").read_text())
    assert first["traj_rel_err"] == pytest.approx(short["test/traj_rel_err"])
    saved = json.loads((tmp_path / "run" / "evaluation-3" / "test_metrics.json").read_text())
    assert saved["traj_rel_err"] == pytest.approx(whole["test/traj_rel_err"])


def test_evaluate_refuses_overrides_that_change_the_model(train_run, tmp_path):
    train_run(RUN, name="run")
    with pytest.raises(ConfigError, match="change the model"):
        api.evaluate(tmp_path / "run", ["model.hidden=7"])


def test_evaluate_names_a_missing_run(tmp_path):
    with pytest.raises(ConfigError, match="not a training run folder"):
        api.evaluate(tmp_path)
    (tmp_path / "checkpoints").mkdir()
    with pytest.raises(ConfigError, match="ckpt='best': no such checkpoint"):
        api.evaluate(tmp_path)
    (tmp_path / "junk.ckpt").write_text("not a checkpoint")
    with pytest.raises(ConfigError, match="not a readable checkpoint"):
        api.evaluate(tmp_path / "junk.ckpt")
