"""The train CLI from a fresh folder: a bad input no config group checks (a chart, an unknown key, a user file)
ends with one clear line and exit 2, a good one trains quietly. The bad value of each config group is in
test_bad_inputs.py (every entry point), the checker's wording of constructors, types and ranges in
tests/config/test_errors.py."""

from __future__ import annotations

import numpy as np
import pytest

from tests.helpers import run_cli

FAST = ["debug=fast", "logger=none"]


@pytest.mark.parametrize(
    "args, needle",
    [
        (["model.chart=polar"], "needs the 'polar' chart"),
        (["nosuchkey=3"], "nosuchkey is not a key of the config"),
        (["system=from_file", "system.path=/nonexistent/data.npz"], "does not exist"),
    ],
)
def test_bad_input_gives_one_clear_error(cli, tmp_path, args, needle):
    proc = cli(*FAST, *args, cwd=tmp_path)
    assert proc.returncode == 2
    assert needle in proc.stderr, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr


def test_malformed_user_file(cli, tmp_path):
    path = tmp_path / "bad.npz"
    np.savez(path, t=np.arange(4.0), train=np.zeros((3, 4, 3)), test=np.zeros((3, 4, 3)))
    proc = cli(*FAST, "system=from_file", f"system.path={path}", cwd=tmp_path)
    assert proc.returncode == 2 and "allowed: (N, 4, 2n)" in proc.stderr, proc.stderr[-500:]
    assert "Traceback" not in proc.stderr


@pytest.mark.slow
def test_cli_trains_quietly_and_writes_outputs(tmp_path):
    proc = run_cli("debug=fast", "model=hnn", "system=pendulum1", cwd=tmp_path, env={"ENCONS_ROOT": str(tmp_path)})
    assert proc.returncode == 0, proc.stderr[-2000:]
    run_dir = next((tmp_path / "outputs" / "pendulum1-hnn").iterdir())
    assert (run_dir / "checkpoints" / "last.ckpt").is_file()
    assert {p.name for p in (run_dir / "figures").iterdir()} == {
        "rollout.png",
        "relative_error.png",
        "energy_error.png",
        "mse_vs_time.png",
    }
    assert "test/traj_rel_err" in proc.stdout
    assert "Warning" not in proc.stderr and "💡" not in proc.stdout + proc.stderr, proc.stderr  # quiet run
    log = (run_dir / "train.log").read_text()
    assert "tested: best checkpoint by validation" in log and "test/traj_rel_err" in log  # the summary


def test_an_empty_override_value_is_one_line_naming_it(cli):
    """``hydra.sweeper.sampler.seed=$K`` with K unset reaches encons as ``...seed=``."""
    result = cli("-m", "sweeps=hamiltonian_weight", "hydra.sweeper.sampler.seed=")
    assert result.returncode == 2
    assert result.stderr.strip().splitlines()[-1] == (
        "encons: error: hydra.sweeper.sampler.seed= has no value (an unset shell "
        "variable?); allowed: hydra.sweeper.sampler.seed=VALUE, or "
        "hydra.sweeper.sampler.seed=null for none"
    )
