"""One test per upstream workaround in ``encons.infra.compat``: an upgrade that breaks one fails here."""

from __future__ import annotations

import warnings
from types import SimpleNamespace

import pytest
import torch

from encons.infra import compat


def test_torchdiffeq_methods_and_which_are_fixed_step():
    methods, fixed = compat.ode_methods()
    assert {"dopri5", "rk4", "euler", "midpoint"} <= set(methods)
    assert {"rk4", "euler", "midpoint"} <= set(fixed) and "dopri5" not in fixed


def test_optuna_sweeper_parses_a_search_space():
    import optuna

    space, fixed, fixed_overrides = compat.optuna_search_space(
        ["optimizer.lr=tag(log, interval(1e-4, 1e-2))", "seed=3", "model=choice(hnn, node)"]
    )
    assert isinstance(space["optimizer.lr"], optuna.distributions.FloatDistribution) and space["optimizer.lr"].log
    assert isinstance(space["model"], optuna.distributions.CategoricalDistribution)
    assert fixed == {"seed": "3"} and fixed_overrides == []


def test_a_failed_jobs_exception_is_read_without_reraising():
    from hydra.core.utils import JobReturn, JobStatus

    err = ValueError("boom")
    ret = JobReturn(status=JobStatus.FAILED, _return_value=err)
    assert compat.job_exception(ret) is err
    with pytest.raises(ValueError):
        ret.return_value  # noqa: B018 - the public property re-raises: why compat reads the field


def test_wandb_logger_loses_lightnings_anonymous_none(tmp_path):
    from lightning.pytorch.loggers import WandbLogger

    logger = WandbLogger(offline=True, save_dir=str(tmp_path))
    assert logger._wandb_init.get("anonymous", "absent") is None  # what Lightning 2.6 passes
    compat.drop_wandb_anonymous(logger)
    assert "anonymous" not in logger._wandb_init


def test_lightnings_missing_monitor_message_lists_the_logged_metrics():
    from lightning.fabric.utilities.exceptions import MisconfigurationException
    from lightning.pytorch.callbacks import ModelCheckpoint

    trainer = SimpleNamespace(
        fit_loop=SimpleNamespace(epoch_loop=SimpleNamespace(val_loop=SimpleNamespace(_has_run=True)))
    )
    with pytest.raises(MisconfigurationException) as err:
        ModelCheckpoint(monitor="val/nope")._save_topk_checkpoint(
            trainer, {"val/loss": torch.tensor(1.0), "train/loss": torch.tensor(2.0), "epoch": torch.tensor(0)}
        )
    assert compat.logged_metric_names(err.value) == ["val/loss", "train/loss"]
    assert compat.logged_metric_names(ValueError("other")) is None


def test_quiet_upstream_drops_lightnings_tips():
    import logging

    compat.quiet_upstream()
    logger = logging.getLogger("lightning.pytorch.utilities.rank_zero")
    tip = logging.LogRecord(logger.name, logging.INFO, __file__, 0, "💡 Tip: try litlogger", (), None)
    info = logging.LogRecord(logger.name, logging.INFO, __file__, 0, "GPU available: False", (), None)
    assert not logger.filter(tip) and logger.filter(info)


def test_quiet_upstream_keeps_lightnings_device_lines_off_the_console_but_in_the_log_file(tmp_path):
    import io
    import logging

    root = logging.getLogger()
    console, file = logging.StreamHandler(io.StringIO()), logging.FileHandler(tmp_path / "train.log")
    root.addHandler(console)
    root.addHandler(file)
    level, root.level = root.level, logging.INFO
    try:
        compat.quiet_upstream()
        compat.quiet_upstream()  # twice: one filter per handler
        name = "lightning.pytorch.utilities.rank_zero"  # what reaches the root's handlers from Lightning's logger
        for line in ("GPU available: False, used: False", "TPU available: False, using: 0 TPU cores", "kept"):
            record = logging.LogRecord(name, logging.INFO, __file__, 0, line, (), None)
            console.handle(record)
            file.handle(record)
    finally:
        root.removeHandler(console)
        root.removeHandler(file)
        file.close()
        root.setLevel(level)
    assert console.stream.getvalue() == "kept\n" and len(console.filters) == 1
    assert "GPU available" in (tmp_path / "train.log").read_text()


def test_quiet_upstream_drops_the_dataloader_workers_advice_of_many_core_machines(monkeypatch):
    import warnings

    from lightning.pytorch.trainer.connectors import data_connector
    from torch.utils.data import DataLoader

    monkeypatch.setattr(data_connector, "suggested_max_num_workers", lambda devices: 15)  # a 16-core machine
    trainer = type("Trainer", (), {"num_devices": 1, "reload_dataloaders_every_n_epochs": 0})()
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        data_connector._worker_check(trainer, DataLoader(range(4)), "train_dataloader")
        assert any("does not have many workers" in str(w.message) for w in seen)  # Lightning gives it
        seen.clear()
        compat.quiet_upstream()
        data_connector._worker_check(trainer, DataLoader(range(4)), "train_dataloader")
    assert not seen


def test_the_progress_bar_numbers_epochs_from_one():
    import pickle

    from encons.training.callbacks import ProgressBar

    bar = ProgressBar()
    bar._trainer = SimpleNamespace(max_epochs=3)  # what Lightning's trainer property reads
    assert bar._get_train_description(0).strip() == "Epoch 1/3"  # Lightning 2.6 says "Epoch 0/2"
    assert type(pickle.loads(pickle.dumps(bar))) is ProgressBar  # a spawned process gets it too


def test_the_csv_logger_writes_through_its_atomic_writer(tmp_path):
    from encons.infra.lightning_io import CSVLogger

    logger = CSVLogger(str(tmp_path), name="run", version=0)
    logger.log_metrics({"val/loss": 1.5}, step=0)
    logger.save()
    assert type(logger.experiment).__name__ == "_AtomicExperimentWriter"
    assert (tmp_path / "run" / "version_0" / "metrics.csv").read_text().splitlines()[0] == "step,val/loss"


DDP_STRIDES = (
    "Grad strides do not match bucket view strides. This may indicate grad was not created according to the "
    "gradient layout contract, or that the param's strides changed since DDP was constructed.  This is not an "
    "error, but may impair performance.\ngrad.sizes() = {sizes}, strides() = {grad}\n"
    "bucket_view.sizes() = {sizes}, strides() = {bucket} (Triggered internally at reducer.cpp:335.)"
)


@pytest.mark.parametrize(
    "sizes, grad, bucket, shown",
    [
        ("[1, 16]", "[1, 1]", "[16, 1]", False),  # SyMo's M(q) of one coordinate (issue 51): the same memory order
        ("[16, 1]", "[1, 16]", "[1, 1]", False),
        ("[4, 16]", "[1, 4]", "[16, 1]", True),  # a transposed matrix: a real layout difference still warns
    ],
)
def test_quiet_upstream_drops_ddps_stride_warning_only_for_a_row_or_a_column(sizes, grad, bucket, shown):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        compat.quiet_upstream()
        warnings.warn(DDP_STRIDES.format(sizes=sizes, grad=grad, bucket=bucket), UserWarning)
    assert bool(caught) is shown


def test_retarget_file_logs_moves_a_file_handler_to_append_to_another_file(tmp_path):
    import logging

    (tmp_path / "new").mkdir()
    (tmp_path / "new" / "train.log").write_text("earlier run\n")
    handler = logging.FileHandler(tmp_path / "old.log")
    root = logging.getLogger()
    root.addHandler(handler)
    try:
        assert compat.retarget_file_logs(tmp_path / "old.log", tmp_path / "new" / "train.log") == [handler]
        root.warning("resumed")
        handler.flush()
    finally:
        root.removeHandler(handler)
        handler.close()
    assert (tmp_path / "new" / "train.log").read_text() == "earlier run\nresumed\n"
    assert (tmp_path / "old.log").read_text() == ""
