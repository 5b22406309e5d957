"""Signs of life when output goes to a file: one line per epoch in train.log (and on a console that is
not a terminal), and the benchmark's progress on stdout, the stream a training run logs to."""

from __future__ import annotations

import re


def test_a_run_writes_one_line_per_epoch_to_train_log_and_a_non_terminal_console(cli, tmp_path):
    proc = cli("model=node", "system=pendulum1", "debug=fast", f"hydra.run.dir={tmp_path / 'run'}", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    log = (tmp_path / "run" / "train.log").read_text()
    lines = re.findall(
        r"epoch (\d) of 2 \(step (\d+)\): train/loss [\d.e+-]+, val/loss [\d.e+-]+, "
        r"val/traj_rel_err [\d.e+-]+, elapsed 0m\d\ds",
        log,
    )
    assert [(int(e), int(s)) for e, s in lines] == [(1, 2), (2, 4)]  # 16 trajectories, batches of 8
    assert "ETA" in log and proc.stdout.count("epoch 2 of 2 (step 4)") == 1  # the console is a buffer here


def test_benchmark_progress_goes_to_stdout(tmp_path, capsys):
    from encons.infra.progress import Progress

    progress = Progress(2, "benchmark run")
    progress.start("a")
    progress.done()
    captured = capsys.readouterr()
    assert "benchmark run 1 of 2 (a), elapsed 0m00s" in captured.out and captured.err == ""


def test_epoch_lines_reach_the_console_at_most_once_per_every_s_but_every_epoch_reaches_train_log(cli, tmp_path):
    proc = cli(
        "model=node",
        "system=pendulum1",
        "debug=fast",
        "trainer.max_epochs=4",
        "callbacks.epoch_line.every_s=1e9",
        f"hydra.run.dir={tmp_path / 'run'}",
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    log = (tmp_path / "run" / "train.log").read_text()
    assert [int(e) for e in re.findall(r"epoch (\d) of 4 \(step", log)] == [1, 2, 3, 4]
    assert [int(e) for e in re.findall(r"epoch (\d) of 4 \(step", proc.stdout)] == [1, 4]  # first and last only


def test_a_frozen_validation_metric_is_reported_once_as_a_stall(train_run, caplog):
    """optimizer.lr=1e-30 (the bounds refuse 0): AdamW's steps of ~1e-30 leave float32 weights as they are."""
    import logging

    with caplog.at_level(logging.WARNING, logger="encons"):
        train_run(
            [
                "model=node",
                "system=pendulum1",
                "optimizer.lr=1e-30",
                "trainer.max_epochs=5",
                "callbacks.stall.patience=2",
            ],
            name="frozen",
        )
    stalls = [r.getMessage() for r in caplog.records if r.getMessage().startswith("stalled:")]
    assert len(stalls) == 1, stalls
    assert re.match(
        r"stalled: val/traj_rel_err has stayed at [\d.e+-]+ \(within 1e-06 relative\) for 2 validations "
        r"since epoch 1 \(now epoch 3, step 6\); the model is not learning\. Likely remedies: another "
        r"optimizer\.lr .*, or objective=derivative",
        stalls[0],
    ), stalls[0]
