"""Signs of life when output goes to a file: one line per epoch in train.log (and on a console that is
not a terminal), and the benchmark's progress on stdout, the stream a training run logs to."""

from __future__ import annotations

import re


def test_a_run_writes_one_line_per_epoch_to_train_log_and_a_non_terminal_console(cli, tmp_path):
    proc = cli("model=node", "system=pendulum1", "debug=fast", f"hydra.run.dir={tmp_path / 'run'}", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    log = (tmp_path / "run" / "train.log").read_text()
    lines = re.findall(r"epoch (\d) of 2 \(step (\d+)\): train/loss [\d.e+-]+, val/loss [\d.e+-]+, "
                       r"val/traj_rel_err [\d.e+-]+, elapsed 0m\d\ds", log)
    assert [(int(e), int(s)) for e, s in lines] == [(1, 2), (2, 4)]        # 16 trajectories, batches of 8
    assert "ETA" in log and proc.stdout.count("epoch 2 of 2 (step 4)") == 1  # the console is a buffer here


def test_benchmark_progress_goes_to_stdout(tmp_path, capsys):
    from encons.progress import Progress

    progress = Progress(2, "benchmark run")
    progress.start("a")
    progress.done()
    captured = capsys.readouterr()
    assert "benchmark run 1 of 2 (a), elapsed 0m00s" in captured.out and captured.err == ""
