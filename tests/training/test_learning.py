"""Short runs that must learn: validation error falls, and energy structure beats a plain field."""

from __future__ import annotations

import lightning.pytorch as pl

from encons.entry import api


class ValHistory(pl.Callback):
    def __init__(self):
        self.errors: list[float] = []

    def on_validation_epoch_end(self, trainer, module):
        self.errors.append(float(trainer.callback_metrics["val/traj_rel_err"]))


def test_short_run_cuts_validation_error_fivefold(tmp_path):
    """CHNN on the 1-pendulum at its default optimiser (warm-up + cosine, lr 1e-2), 12 epochs."""
    cfg = api.compose(
        "model=chnn",
        "system=pendulum1",
        "debug=fast",
        "data.n_train=32",
        "data.n_val=8",
        "data.n_test=4",
        "data.n_steps=20",
        "data.batch_size=8",
        "model.hidden=32",
        "trainer.max_epochs=12",
        "test=false",
        "~callbacks",
        output_dir=tmp_path / "run",
        cache_dir=tmp_path / "cache",
    )
    data, module = api.build(cfg)
    trainer, _ = api.build_trainer(cfg)
    history = ValHistory()
    trainer.callbacks.append(history)
    trainer.fit(module, datamodule=data)
    assert len(history.errors) == 12
    assert history.errors[-1] * 5 <= history.errors[0], history.errors


def test_hnn_drifts_less_in_energy_than_node(train_run):
    """Lim & Kasim Task 1 protocol at a tiny budget: 462-step test rollouts of the mass-spring."""
    budget = [
        "system=mass_spring",
        "logger=none",
        "data.n_train=64",
        "data.n_val=8",
        "data.n_test=16",
        "data.batch_size=16",
        "model.hidden=32",
        "model.depth=2",
        "trainer.max_epochs=15",
        "objective=derivative",
        "optimizer.lr=1e-2",
        "trainer.enable_progress_bar=false",
        "evaluation.rtol=1e-7",
        "evaluation.atol=1e-9",
    ]  # a floor far below both models' errors, at 1/3 the cost
    hnn = train_run(["model=hnn", *budget], name="hnn", fast=False)
    node = train_run(["model=node", *budget], name="node", fast=False)
    assert hnn["test/energy_rmse_median"] * 3 < node["test/energy_rmse_median"], (hnn, node)
