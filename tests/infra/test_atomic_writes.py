"""Atomic writes: a disk that fills half-way through a write keeps the earlier file, leaves no
partial file, and ends in one ``WriteError`` naming the folder."""

from __future__ import annotations

import errno
import json
import os

import numpy as np
import pytest
import torch

from encons.infra import io as atomic
from encons.infra.errors import EnconsError, WriteError


class _FillingFile:
    """A file on a disk with ``room`` bytes left: the write that crosses it writes what fits, then
    raises ENOSPC, as ``write(2)`` on a full disk does."""

    def __init__(self, f, room: int):
        self._f, self._room = f, room

    def write(self, data):
        if len(data) > self._room:
            self._f.write(data[: self._room])
            self._room = 0
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self._room -= len(data)
        return self._f.write(data)

    def __getattr__(self, name):
        return getattr(self._f, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._f.close()


@pytest.fixture
def full_disk(monkeypatch):
    """``full_disk(room, suffix="", after=0)``: from now on, each file ``encons.infra.io`` writes whose name ends
    with ``suffix``, after the first ``after`` of them, fills after ``room`` bytes."""
    real, mkstemp = os.fdopen, atomic.tempfile.mkstemp

    def fill(room: int, suffix: str = "", after: int = 0) -> None:
        names = {}

        def named(*args, prefix: str = "", **kwargs):  # the temporary's prefix holds the final name
            fd, tmp = mkstemp(*args, prefix=prefix, **kwargs)
            names[fd] = prefix.split(f".{atomic._host()}.")[0]
            return fd, tmp

        def fdopen(fd, *args, **kwargs):
            nonlocal after
            f = real(fd, *args, **kwargs)
            if not names.pop(fd, "").endswith(suffix):
                return f
            after -= 1
            return f if after >= 0 else _FillingFile(f, room)

        monkeypatch.setattr(atomic.tempfile, "mkstemp", named)
        monkeypatch.setattr(atomic.os, "fdopen", fdopen)

    return fill


def _checkpoint(path, epoch):
    from encons.infra.lightning_io import AtomicCheckpointIO

    AtomicCheckpointIO().save_checkpoint({"epoch": epoch, "state_dict": {"w": torch.full((2000,), float(epoch))}}, path)


def _report(path, value):
    from encons.tools.report import write_csv

    write_csv(path, [{"model": "hnn", "test/traj_rel_err": value}] * 200)


def _figure(path, value):
    from encons.evaluators import figures

    fig, ax = figures.subplots(figsize=(2, 2))
    ax.plot(np.arange(100) * value)
    figures.save_png(fig, path)


WRITERS = {  # name: (file, write(path, version), read(path) -> what a reader sees)
    "checkpoint": ("last.ckpt", _checkpoint, lambda p: torch.load(p, weights_only=True)["epoch"]),
    "metrics": (
        "test_metrics.json",
        lambda p, v: atomic.write_json(p, {"traj_rel_err": [v] * 500}),
        lambda p: json.loads(p.read_text())["traj_rel_err"][0],
    ),
    "curves": (
        "test_curves.npz",
        lambda p, v: atomic.save_npz(p, rel_err=np.full(3000, float(v))),
        lambda p: float(np.load(p)["rel_err"][0]),
    ),
    "report": ("summary.csv", _report, lambda p: p.read_text().splitlines()[1]),
    "figure": ("rollout.png", _figure, lambda p: p.read_bytes()),
}


@pytest.mark.parametrize("name", WRITERS)
def test_a_write_that_fills_the_disk_keeps_the_earlier_file(tmp_path, full_disk, name):
    file, write, read = WRITERS[name]
    path = tmp_path / "out" / file
    write(path, 1)
    before = read(path)
    full_disk(room=512)
    with pytest.raises(WriteError) as caught:
        write(path, 2)
    line = str(caught.value)
    assert "\n" not in line and f"folder={str(path.parent)!r}" in line and "No space left on device" in line
    assert read(path) == before  # the earlier file, whole
    assert sorted(p.name for p in path.parent.iterdir()) == [file]  # no partial file, no temporary


def test_a_killed_writers_temporary_is_removed_by_the_next_write(tmp_path):
    host = atomic._host()
    dead = tmp_path / f".x.json.{host}.999999999.abc{atomic.TMP_SUFFIX}"
    live = tmp_path / f".x.json.{host}.{os.getpid()}.abc{atomic.TMP_SUFFIX}"
    for f in (dead, live):
        f.write_bytes(b"part")
    atomic.write_json(tmp_path / "x.json", {})
    assert not dead.exists() and live.exists()


def test_a_read_only_folder_is_one_line(tmp_path, monkeypatch):
    def read_only(*args, **kwargs):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS))

    monkeypatch.setattr(atomic.tempfile, "mkstemp", read_only)
    with pytest.raises(WriteError, match=r"folder=.*: cannot write x\.json \(Read-only file system\); allowed: "):
        atomic.write_json(tmp_path / "x.json", {})
    assert not (tmp_path / "x.json").exists()


def test_the_csv_logger_keeps_its_last_whole_table_when_the_disk_fills(tmp_path, full_disk):
    from encons.infra.lightning_io import CSVLogger

    logger = CSVLogger(tmp_path, name="csv")
    logger.log_hyperparams({"model": {"hidden": 16}})
    logger.log_metrics({"train/loss": 1.0}, step=0)
    logger.save()
    table = tmp_path / "csv" / "version_0" / "metrics.csv"
    before = table.read_text()
    full_disk(room=8, suffix="metrics.csv")
    logger.log_metrics({"train/loss": 0.5, "val/loss": 0.7}, step=1)
    with pytest.raises(WriteError, match="cannot write metrics.csv"):
        logger.save()
    assert table.read_text() == before and before.splitlines() == ["step,train/loss", "0,1.0"]
    assert sorted(p.name for p in table.parent.iterdir()) == ["hparams.yaml", "metrics.csv"]


def test_a_disk_that_fills_during_training_keeps_the_last_good_checkpoints(tmp_path, full_disk):
    from encons.entry import api

    cfg = api.compose("debug=fast", "trainer.max_epochs=3", output_dir=tmp_path / "run", cache_dir=tmp_path / "cache")
    full_disk(room=20_000, suffix=".ckpt", after=2)  # epoch 0 writes best and last; epoch 1's first write fills it
    with pytest.raises(WriteError) as caught:
        api.train(cfg)
    folder = tmp_path / "run" / "checkpoints"
    line = str(caught.value)
    assert "\n" not in line and line.startswith(f"folder={str(folder)!r}: cannot write ") and "No space left" in line
    assert sorted(p.name for p in folder.iterdir()) == [
        "best-epoch0001.ckpt",
        "last.ckpt",
    ]  # no partial file (epochs counted from 1)
    for kept in folder.iterdir():
        assert torch.load(kept, weights_only=True)["epoch"] == 0


def test_resume_skips_a_damaged_last_checkpoint_with_one_warning(tmp_path, caplog):
    import shutil

    from encons.entry import api
    from encons.infra import checkpoints

    def compose(name, *overrides):
        return api.compose(
            "debug=fast",
            "trainer.max_epochs=1",
            *overrides,
            output_dir=tmp_path / "runs" / name,
            cache_dir=tmp_path / "cache",
        )

    api.train(compose("good"), summary=False)
    shutil.copytree(tmp_path / "runs" / "good", tmp_path / "runs" / "cut")
    damaged = tmp_path / "runs" / "cut" / "checkpoints" / "last.ckpt"
    damaged.write_bytes(damaged.read_bytes()[:5000])  # the newest: tried first
    cfg = compose("resumed", "trainer.max_epochs=2", "ckpt_path=last")
    with caplog.at_level("WARNING"):
        assert checkpoints.resume_from(cfg) == str(tmp_path / "runs" / "good" / "checkpoints" / "last.ckpt")
    warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING" and str(damaged) in r.getMessage()]
    assert len(warnings) == 1 and "\n" not in warnings[0], caplog.text
    run = api.train(cfg, summary=False)  # resumes from it, in its folder (the resuming run's own is removed)
    assert run.run_dir == tmp_path / "runs" / "good" and not (tmp_path / "runs" / "resumed").exists()

    shutil.rmtree(tmp_path / "runs" / "good")
    with pytest.raises(EnconsError) as caught:  # nothing readable left: refused in one line
        api.train(compose("again", "ckpt_path=last"), summary=False)
    assert (
        "\n" not in str(caught.value) and "ckpt_path=last" in str(caught.value) and "; allowed: " in str(caught.value)
    )
