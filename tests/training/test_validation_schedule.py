"""``validation.every`` / ``validation.criterion`` (conf/train.yaml): which epochs validate, what the best
checkpoint and the plateau schedule see, and the per-epoch cost split (``encons.training.callbacks.CostLine``)."""

from __future__ import annotations

import json

import lightning.pytorch as pl
import pytest
import torch

from encons.entry import api
from encons.infra.errors import ConfigError


class Seen(pl.Callback):
    """The epochs (from 1) that validated, and the monitored value the best checkpoint saw at each."""

    def __init__(self):
        self.epochs, self.values = [], []

    def on_validation_end(self, trainer, module):
        self.epochs.append(trainer.current_epoch + 1)
        self.values.append(float(trainer.callback_metrics[trainer.checkpoint_callback.monitor]))


def fit(tmp_path, *overrides: str):
    from encons.entry.api import build, build_trainer

    cfg = api.compose(
        "debug=fast",
        "model=hnn",
        "system=pendulum2",
        "data.n_train=8",
        "model.hidden=8",
        "trainer.max_epochs=12",
        "test=false",
        *overrides,
        output_dir=tmp_path,
        cache_dir=tmp_path / "c",
    )
    data, module = build(cfg)
    trainer, _ = build_trainer(cfg)
    seen = Seen()
    trainer.callbacks.insert(0, seen)
    trainer.fit(module, datamodule=data)
    return trainer, seen


def test_every_5_validates_on_epochs_5_10_and_the_best_checkpoint_sees_each(tmp_path):
    trainer, seen = fit(tmp_path, "validation.every=5")
    assert seen.epochs == [5, 10]
    best = trainer.checkpoint_callback
    assert best.best_model_score == pytest.approx(min(seen.values))
    epoch = 5 + 5 * seen.values.index(min(seen.values))
    assert best.best_model_path.endswith(f"best-epoch{epoch:04d}.ckpt")
    costs = json.loads((tmp_path / "costs.json").read_text())
    assert [r["epoch"] for r in costs["epochs"]] == list(range(1, 13))
    assert [r["epoch"] for r in costs["epochs"] if r["validated"]] == [5, 10]
    assert all(r["validation"] == 0.0 for r in costs["epochs"] if not r["validated"])
    # last.ckpt follows every epoch, not only the validated ones (epoch 12 validated none; counted from 0)
    assert torch.load(tmp_path / "checkpoints" / "last.ckpt", weights_only=True)["epoch"] == 11


def test_objective_criterion_logs_the_objective_and_plateau_steps_only_after_validations(tmp_path):
    trainer, seen = fit(
        tmp_path,
        "validation.every=3",
        "validation.criterion=objective",
        "objective=derivative",
        "optimized_metric=val/loss",
        "scheduler=plateau",
        "scheduler.patience=0",
        "scheduler.factor=0.5",
    )
    assert seen.epochs == [3, 6, 9, 12]
    assert "val/traj_rel_err" not in trainer.callback_metrics
    config = trainer.lr_scheduler_configs[0]
    assert config.frequency == 3
    # patience 0: each validation that does not improve halves the lr; epochs without one do not step it
    worse = sum(b >= a for a, b in zip(seen.values, seen.values[1:]))
    assert trainer.optimizers[0].param_groups[0]["lr"] == pytest.approx(1e-3 * 0.5**worse)


def test_none_runs_no_validation(tmp_path):
    trainer, seen = fit(tmp_path, "validation.criterion=none", "~callbacks.best")
    assert seen.epochs == []


@pytest.mark.parametrize(
    "overrides, says",
    [
        (["validation.criterion=objective"], "validation.criterion=objective logs no val/traj_rel_err"),
        (["validation.criterion=none"], "validation.criterion=none logs no val/traj_rel_err"),
        (["validation.every=0"], "validation.every=0; allowed: an integer >= 1"),
        (["validation.criterion=onestep"], "validation.criterion=onestep; allowed: rollout, objective, none"),
    ],
)
def test_bad_validation_is_refused_in_one_line(tmp_path, overrides, says):
    from encons.config.check import validate

    with pytest.raises(ConfigError, match=says.replace(".", r"\.")):
        validate(api.compose("debug=fast", *overrides, output_dir=tmp_path))
