"""``trainer=ddp`` with two CPU processes (gloo): each process trains on half of every batch and
the gradients are averaged, so 2 × batch 8 must retrace one process with batch 16 exactly."""

from __future__ import annotations

import json
import re

import pytest

from tests.helpers import run_cli

pytestmark = pytest.mark.slow  # two training processes (gloo) and a reference run

RUN = ["model=node", "system=pendulum1", "debug=fast", "trainer.max_epochs=3"]


def test_two_process_ddp_matches_one_process_with_the_whole_batch(train_run, tmp_path):
    proc = run_cli(*RUN, "trainer=ddp", "trainer.accelerator=cpu", "trainer.devices=2", "data.batch_size=8",
                   f"hydra.run.dir={tmp_path / 'ddp'}", cwd=tmp_path, env={"ENCONS_ROOT": str(tmp_path)})
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Initializing distributed: GLOBAL_RANK: 1, MEMBER: 2/2" in proc.stderr + proc.stdout
    ddp = json.loads((tmp_path / "ddp" / "test_metrics.json").read_text())
    single = train_run(RUN + ["data.batch_size=16"], name="single")
    for key, value in ddp.items():
        assert value == pytest.approx(single[f"test/{key}"], rel=1e-5, abs=1e-8), key  # oracle/*: ~1e-10, float noise
    val = float(re.search(r"best/val/traj_rel_err\s*│\s*([0-9.e+-]+)", proc.stdout).group(1))  # 4 digits
    assert val == pytest.approx(single["best/val/traj_rel_err"], rel=1e-3)
    halves = train_run(RUN + ["data.batch_size=8"], name="two_steps")  # what DDP must not be
    assert ddp["traj_rel_err"] != pytest.approx(halves["test/traj_rel_err"], rel=1e-5)
