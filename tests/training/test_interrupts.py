"""Bad settings found before any data, and an interrupted run that says so: SIGTERM (what a scheduler
sends) ends a run with a non-zero exit and the command that resumes it in the same folder."""

from __future__ import annotations

import json
import os
import shlex
import signal
import subprocess
import sys
import time

import pytest
import torch


@pytest.mark.skipif(torch.cuda.is_available(), reason="the accelerator error needs a machine without a GPU")
def test_a_full_size_run_is_refused_with_the_accelerator_error_before_any_data_is_simulated(cli, tmp_path):
    started = time.perf_counter()
    proc = cli(
        "model=hnn",
        "system=pendulum2",
        "trainer.accelerator=gpu",
        f"paths.cache_dir={tmp_path / 'cache'}",
        f"hydra.run.dir={tmp_path / 'run'}",
        cwd=tmp_path,
    )
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert proc.stderr.startswith("encons: error: trainer.accelerator=gpu") and "allowed:" in proc.stderr
    assert "simulating" not in proc.stdout and not any((tmp_path / "cache").glob("*.npz"))
    assert time.perf_counter() - started < 60  # not after the 1000 trajectories of pendulum2


def _wait_for(path, text, proc, timeout=300):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        if path.is_file() and text in path.read_text():
            return
        time.sleep(0.2)
    raise AssertionError(f"{text!r} never reached {path}")


@pytest.mark.slow
@pytest.mark.parametrize(
    "stop, status, extra", [(signal.SIGTERM, 143, []), (signal.SIGINT, 130, ["seeds=[0,1]"])]
)  # Ctrl-C; an ensemble
def test_sigterm_during_fit_exits_non_zero_prints_the_resume_command_and_resuming_continues(
    tmp_path, stop, status, extra
):
    run = tmp_path / "run"
    args = [
        "model=node",
        "system=pendulum1",
        "debug=fast",
        "figures=false",
        "trainer.max_epochs=30",
        f"hydra.run.dir={run}",
        f"paths.cache_dir={tmp_path / 'cache'}",
        *extra,
    ]
    env = {**os.environ, "ENCONS_ROOT": str(tmp_path)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "encons.train", *args],
        cwd=tmp_path,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    _wait_for(run / "train.log", "epoch 3 of 30", proc)
    proc.send_signal(stop)
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == status, err[-2000:]
    line = err.strip().splitlines()[-1]
    assert line.startswith(f"encons: interrupted: {stop.name} during fit"), err[-2000:]
    command = line.split("resume: ", 1)[1]
    assert f"hydra.run.dir={run}" in command and f"ckpt_path={run / 'checkpoints' / 'last.ckpt'}" in command
    assert not (run / "test_metrics.json").exists()
    stopped = torch.load(run / "checkpoints" / "last.ckpt", weights_only=True, map_location="cpu")["epoch"]
    assert 2 <= stopped < 29

    resumed = subprocess.run(
        shlex.split(command.replace("python", shlex.quote(sys.executable), 1)),
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert "exists and is not empty" not in resumed.stderr + resumed.stdout  # resuming is no warning
    log = (run / "train.log").read_text()
    assert "epoch 30 of 30" in log and f"epoch {stopped + 2} of 30" in log  # the same run, continued
    assert torch.load(run / "checkpoints" / "last.ckpt", weights_only=True, map_location="cpu")["epoch"] == 29
    assert json.loads((run / "test_metrics.json").read_text())["traj_rel_err"] > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cache", "run"]  # no second run folder


@pytest.mark.slow
def test_an_ensemble_killed_mid_epoch_loses_at_most_that_epoch(tmp_path):
    """kill -9 (no signal handler runs): the ensemble's last.ckpt holds the last whole epoch, and the resume
    command continues from the epoch after it, in the same folder, to the end."""
    run = tmp_path / "run"
    args = [
        "model=node",
        "system=pendulum1",
        "debug=fast",
        "figures=false",
        "trainer.max_epochs=30",
        "seeds=[0,1]",
        f"hydra.run.dir={run}",
        f"paths.cache_dir={tmp_path / 'cache'}",
    ]
    env = {**os.environ, "ENCONS_ROOT": str(tmp_path)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "encons.train", *args],
        cwd=tmp_path,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    _wait_for(run / "train.log", "epoch 4 of 30", proc)
    proc.kill()
    proc.wait(timeout=60)
    stopped = torch.load(run / "checkpoints" / "last.ckpt", weights_only=True, map_location="cpu")["epoch"]
    # epoch 4's line is logged before its last.ckpt is written: a kill between the two leaves epoch 3's (index 2)
    assert 2 <= stopped < 29 and not (run / "test_metrics.json").exists()
    resumed = subprocess.run(
        [sys.executable, "-m", "encons.train", *args, f"ckpt_path={run / 'checkpoints' / 'last.ckpt'}"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    log = (run / "train.log").read_text()
    assert f"resumed from {run / 'checkpoints' / 'last.ckpt'}" in log
    after = log[log.index("resumed from") :]
    assert f"epoch {stopped + 2} of 30" in after and f"epoch {stopped + 1} of 30" not in after  # lost no whole epoch
    assert "epoch 30 of 30" in after and json.loads((run / "test_metrics.json").read_text())["members"] == 2
