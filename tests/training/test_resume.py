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
