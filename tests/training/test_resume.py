"""Same seed, same metrics; a resumed run ends where an uninterrupted one does; NaN keeps the checkpoint."""

from __future__ import annotations

import pytest
import torch

from encons.infra.errors import DivergenceError
from encons.training.module import TrainingModule

RUN = ["model=hnn", "system=pendulum1", "trainer.max_epochs=4"]


def test_same_seed_same_metrics(train_run):
    a, b = train_run(RUN, name="a"), train_run(RUN, name="b")
    assert a["test/traj_rel_err"] == b["test/traj_rel_err"]
    c = train_run(RUN + ["seed=1"], name="c")
    assert c["test/traj_rel_err"] != a["test/traj_rel_err"]


def test_resume_matches_uninterrupted(train_run, tmp_path):
    full = train_run(RUN, name="full")
    train_run(["model=hnn", "system=pendulum1", "trainer.max_epochs=2"], name="part")
    resumed = train_run(RUN + ["ckpt_path=last"], name="resumed")
    assert resumed["test/traj_rel_err"] == pytest.approx(full["test/traj_rel_err"], rel=1e-6)
    assert resumed["val/traj_rel_err"] == pytest.approx(full["val/traj_rel_err"], rel=1e-6)


def test_divergence_raises_and_keeps_last_good_checkpoint(train_run, tmp_path, monkeypatch):
    loss = TrainingModule.loss

    def poisoned(self, *args):
        value = loss(self, *args)
        return value * float("nan") if self.current_epoch == 2 else value

    monkeypatch.setattr(TrainingModule, "loss", poisoned)
    with pytest.raises(DivergenceError, match="training diverged") as err:
        train_run(RUN, name="nan")
    # the message names the checkpoint that exists (it said "no checkpoint was written" before)
    assert f"{tmp_path / 'nan' / 'checkpoints' / 'last.ckpt'} holds the last good weights (epoch 2)" in str(
        err.value
    )  # epochs from 1
    ckpt = torch.load(tmp_path / "nan" / "checkpoints" / "last.ckpt", weights_only=False)
    assert ckpt["epoch"] == 1
    assert all(torch.isfinite(v).all() for v in ckpt["state_dict"].values())


def test_ckpt_path_last_continues_in_the_interrupted_runs_own_folder(tmp_path):
    """Issue 51: a plain ``ckpt_path=last`` (no ``hydra.run.dir``) resumed correctly but into a new folder, leaving
    the interrupted one holding only checkpoints. Now the run goes on in its own folder, Hydra's log file with it,
    and the command's own folder (Hydra's copy of the command only) is removed."""
    from tests.helpers import run_cli

    env = {"ENCONS_ROOT": str(tmp_path)}
    small = ["model=node", "system=pendulum1", "debug=fast", "figures=false"]
    first = run_cli(*small, "trainer.max_epochs=2", cwd=tmp_path, env=env)
    assert first.returncode == 0, first.stderr[-2000:]
    (interrupted,) = (tmp_path / "outputs" / "pendulum1-node").iterdir()
    again = run_cli(*small, "trainer.max_epochs=4", "ckpt_path=last", cwd=tmp_path, env=env)
    assert again.returncode == 0, again.stderr[-2000:]
    assert list((tmp_path / "outputs" / "pendulum1-node").iterdir()) == [interrupted]
    log = (interrupted / "train.log").read_text()
    assert "epoch 2 of 2" in log and "epoch 4 of 4" in log and "continuing the run in its own folder" in log
    assert torch.load(interrupted / "checkpoints" / "last.ckpt", weights_only=True)["epoch"] == 3  # from 0


def test_a_resumed_run_counts_the_time_and_epochs_before_its_stop(train_run, tmp_path, monkeypatch):
    """A run stopped after epoch 2 and resumed to 4: its ``costs.json`` lists epochs 1–4 (``CostLine``'s state is in
    the checkpoint), and its ``wall_time_s`` covers every one of them: the first segment's epochs were slowed by
    1.5 s each, which the resumed process alone (as ``wall_time_s`` counted before) does not contain."""
    import json
    import time

    step = TrainingModule.training_step

    def slow(self, batch, batch_idx):
        if batch_idx == 0:
            time.sleep(1.5)
        return step(self, batch, batch_idx)

    monkeypatch.setattr(TrainingModule, "training_step", slow)
    train_run(["model=node", "system=pendulum1", "trainer.max_epochs=2"], name="part")
    monkeypatch.setattr(TrainingModule, "training_step", step)
    resumed = train_run(["model=node", "system=pendulum1", "trainer.max_epochs=4", "ckpt_path=last"], name="resumed")
    epochs = json.loads((tmp_path / "part" / "costs.json").read_text())["epochs"]  # it goes on in its folder
    assert [int(e["epoch"]) for e in epochs] == [1, 2, 3, 4]
    assert min(e["total"] for e in epochs[:2]) >= 1.5
    assert resumed["wall_time_s"] >= sum(e["total"] for e in epochs)
