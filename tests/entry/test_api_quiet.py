"""A run from Python (a script, a notebook) is as quiet as the CLI and writes the same train.log;
``evaluate`` adds no Lightning lines on stderr and no empty folders."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

SCRIPT = """
import encons
cfg = encons.compose("debug=fast", "model=node", "system=pendulum1", output_dir={run!r}, cache_dir={cache!r})
run = encons.train(cfg, summary=False)
encons.evaluate(run.run_dir)
"""


@pytest.mark.slow
def test_a_python_api_run_writes_train_log_and_prints_no_warning_lines(tmp_path):
    run = tmp_path / "run"
    script = tmp_path / "script.py"
    script.write_text(textwrap.dedent(SCRIPT.format(run=str(run), cache=str(tmp_path / "cache"))))
    proc = subprocess.run(
        [sys.executable, str(script)],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={**os.environ, "ENCONS_ROOT": str(tmp_path)},
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stderr == "", proc.stderr  # no tips, LeafSpec warning or GPU/TPU lines
    log = (run / "train.log").read_text()
    assert "epoch 2 of 2" in log and "GPU available" in log and "test/traj_rel_err" in log
    assert (run / "evaluation" / "test_metrics.json").is_file() and (run / "evaluation" / "evaluate.log").is_file()
    assert not (run / "evaluation" / "checkpoints").exists()
