"""Optuna sweeps from the command line on tiny configs: a resumable SQLite study, a diverged trial
recorded as failed, a pruned trial, the end-of-sweep report, offline wandb runs per trial, and
the plain model × seed grid."""

from __future__ import annotations

import csv
import math
import os
import time
from pathlib import Path

import optuna
import pytest
import yaml
from optuna.trial import TrialState

from encons.training.build import compose
from tests.helpers import run_cli

TINY = ["system=pendulum1", "debug=fast", "test=false"]
NODE = ["model=node", *TINY]
PNG = b"\x89PNG"


@pytest.fixture
def cli(cli, tmp_path, monkeypatch):
    """The in-process CLI with the encons root at ``tmp_path``, as :func:`sweep`'s real process has it."""
    monkeypatch.setenv("ENCONS_ROOT", str(tmp_path))
    return cli


def sweep(tmp_path: Path, *args: str, cli=None) -> str:
    """A multirun's stdout: in this process through the ``cli`` fixture when given, else a real process."""
    proc = (
        cli("-m", *args, cwd=tmp_path)
        if cli is not None
        else run_cli("-m", *args, cwd=tmp_path, env={"ENCONS_ROOT": str(tmp_path)})
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


def stored(folder: Path, study: str) -> list[optuna.trial.FrozenTrial]:
    return optuna.load_study(study_name=study, storage=f"sqlite:///{folder / 'optuna.db'}").trials


@pytest.mark.slow
def test_sweep_reports_its_best_trial_and_a_rerun_continues_the_study(tmp_path, cli):
    args = [*NODE, "sweeps=chnn_tuning", "hydra.sweeper.n_trials=2"]
    out = sweep(tmp_path, *args, cli=cli)
    folder = tmp_path / "multirun" / "chnn_tuning-pendulum1-node"
    trials = stored(folder, "chnn_tuning-pendulum1-node")
    assert [t.state for t in trials] == [TrialState.COMPLETE] * 2
    best = min(trials, key=lambda t: t.value)
    assert math.isfinite(best.value) and f"best trial {best.number}: value {best.value:.6g}" in out
    results = yaml.safe_load((folder / "optimization_results.yaml").read_text())
    assert results["best_value"] == best.value and results["best_params"] == best.params
    rows = list(csv.DictReader((folder / "trials.csv").open()))
    assert [float(r["value"]) for r in rows] == [t.value for t in trials]
    assert {r["model.hidden"] for r in rows} == {str(t.params["model.hidden"]) for t in trials}
    for name in ("optimization_history.png", "param_importances.png"):
        assert (folder / name).read_bytes()[:4] == PNG

    sweep(tmp_path, *args, cli=cli)  # the same command again continues the stored study
    trials = stored(folder, "chnn_tuning-pendulum1-node")
    assert [t.number for t in trials] == list(range(4))
    assert all(t.state == TrialState.COMPLETE for t in trials)
    assert len({tuple(sorted(t.params.items())) for t in trials}) == 4  # the resumed sampler draws anew
    assert sorted(p.name for p in folder.glob("trial_*")) == [f"trial_{n}" for n in range(4)]


def _processes_with_env(needle: str) -> list[int]:
    found = []
    for environ in Path("/proc").glob("[0-9]*/environ"):
        try:
            if needle.encode() in environ.read_bytes():
                found.append(int(environ.parent.name))
        except OSError:
            pass
    return found


@pytest.mark.slow
def test_pruned_and_diverged_trials_are_recorded_and_wandb_logs_every_trial_offline(tmp_path):
    wandb_dir = os.environ["WANDB_DIR"]
    out = sweep(
        tmp_path,
        *NODE,
        "sweeps=optuna",
        "logger=wandb",
        "trainer.max_epochs=3",
        "hydra.sweeper.n_trials=3",
        "optimizer.lr=tag(log,interval(1e-4,10.0))",
        "sweeps.pruner.n_startup_trials=1",
        "sweeps.pruner.n_warmup_steps=0",
        "hydra.sweeper.enqueue=[{optimizer.lr:1e-3},{optimizer.lr:3.0},{optimizer.lr:1e9}]",
    )
    folder = tmp_path / "multirun" / "optuna-pendulum1-node"
    good, bad, nan = stored(folder, "optuna-pendulum1-node")
    assert good.state == TrialState.COMPLETE and sorted(good.intermediate_values) == [0, 1, 2]
    # lr = 3 blows the validation error up in the first epoch: worse than the median, stopped there
    assert bad.state == TrialState.PRUNED and list(bad.intermediate_values) == [0]
    assert bad.intermediate_values[0] > 10 * good.intermediate_values[0]
    # lr = 1e9 makes the loss NaN: failed with its reason, and the sweep still reports
    assert nan.state == TrialState.FAIL and nan.user_attrs["fail_reason"].startswith("DivergenceError: training")
    rows = list(csv.DictReader((folder / "trials.csv").open()))
    assert [r["state"] for r in rows] == ["COMPLETE", "PRUNED", "FAIL"] and "diverged" in rows[2]["fail_reason"]
    assert f"best trial 0: value {good.value:.6g}" in out

    for t in (good, bad, nan):
        runs = list((folder / f"trial_{t.number}" / "wandb").glob("offline-run-*/run-*.wandb"))
        assert len(runs) == 1
        record = runs[0].read_bytes()
        assert b'"group":"optuna-pendulum1-node"' in record and f"pendulum1-node-trial{t.number}".encode() in record
    deadline = time.monotonic() + 10
    while _processes_with_env(f"WANDB_DIR={wandb_dir}") and time.monotonic() < deadline:
        time.sleep(0.5)
    assert not _processes_with_env(f"WANDB_DIR={wandb_dir}"), "a wandb process outlived the sweep"


@pytest.mark.slow
def test_model_grid_runs_every_model_and_seed(tmp_path, cli):
    sweep(
        tmp_path,
        *TINY,
        "sweeps=model_grid",
        "hydra.sweeper.params.model='node,hnn'",
        "hydra.sweeper.params.seed='0,1'",
        "trainer.max_epochs=1",
        cli=cli,
    )
    folder = next((tmp_path / "multirun" / "model_grid-pendulum1").iterdir())
    runs = {p.name: yaml.safe_load((p / ".hydra" / "config.yaml").read_text()) for p in folder.iterdir() if p.is_dir()}
    assert sorted(runs) == ["hnn-seed0", "hnn-seed1", "node-seed0", "node-seed1"]
    assert {(c["model"]["_target_"].rsplit(".", 1)[-1], c["seed"]) for c in runs.values()} == {
        ("NODE", 0),
        ("NODE", 1),
        ("HNN", 0),
        ("HNN", 1),
    }
    assert all((folder / name / "checkpoints" / "last.ckpt").is_file() for name in runs)


@pytest.mark.slow
def test_shared_schedule_trains_every_model_under_the_swept_optimiser(tmp_path, cli):
    sweep(
        tmp_path,
        "sweeps=shared_schedule",
        "debug=fast",
        "figures=false",
        "trainer.max_epochs=1",
        "hydra.sweeper.params.model='node,chnn'",
        "optimizer.lr=3e-3",
        cli=cli,
    )
    folder = next((tmp_path / "multirun" / "shared_schedule").iterdir())
    runs = {p.name: yaml.safe_load((p / ".hydra" / "config.yaml").read_text()) for p in folder.iterdir() if p.is_dir()}
    assert sorted(runs) == [
        "chnn-cosine-lr0.003-ep1",
        "chnn-none-lr0.003-ep1",
        "node-cosine-lr0.003-ep1",
        "node-none-lr0.003-ep1",
    ]
    for name, c in runs.items():  # CHNN's own adamw_peak at 1e-2 is overridden like every model's optimiser
        assert c["optimizer"]["_target_"] == "torch.optim.AdamW" and c["optimizer"]["lr"] == 3e-3
        assert c["scheduler"].get("_target_") == (
            "encons.training.schedules.WarmupCosine" if "cosine" in name else None
        )
        assert c["system"]["n_links"] == 2 and c["trainer"]["max_epochs"] == 1 and c["evaluation"]["method"] == "rk4"
        assert "traj_rel_err" in yaml.safe_load((folder / name / "test_metrics.json").read_text())


@pytest.mark.parametrize(
    "launcher, target, parallel_key",
    [
        ("parallel", "joblib_launcher.JoblibLauncher", "n_jobs"),
        ("slurm", "submitit_launcher.SlurmLauncher", "array_parallelism"),
    ],
)
def test_launcher_configs_follow_the_sweepers_batch_size(tmp_path, launcher, target, parallel_key):
    cfg = compose(["sweeps=optuna", f"hydra/launcher={launcher}", "hydra.sweeper.n_jobs=3"], tmp_path)
    assert cfg.hydra.launcher._target_.endswith(target)
    assert cfg.hydra.launcher[parallel_key] == 3
