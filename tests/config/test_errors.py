"""Every bad input a user can give ends as one line naming the key, and faults are survived.

In-process cases check the error and its wording; a few run the CLI to check the whole path: exit
code 2, no traceback, the one line last on stderr.
"""

from __future__ import annotations

import os
import stat

import numpy as np
import pytest
import torch

from encons.data import store
from encons.infra import io as atomic
from encons.infra.errors import ConfigError, DataError, EnconsError
from encons.training.build import compose
from tests.helpers import run_cli


def build_with(tmp_path, *overrides: str):
    from encons.entry.api import build

    return build(compose(["debug=fast", *overrides], tmp_path / "run", tmp_path / "cache"))


def refused(tmp_path, overrides, key, error=EnconsError):
    with pytest.raises(error) as err:
        build_with(tmp_path, *overrides)
    line = str(err.value)
    assert "\n" not in line and key in line and "allowed" in line, line
    return line


# class 1: errors raised inside the constructors Hydra instantiates
@pytest.mark.parametrize(
    "overrides, key",
    [
        (["system=pendulum1", "system.n_links=0"], "system.n_links=0"),
        (["system=pendulum1", "system.masses=[1,2]"], "system.masses=[1, 2]"),
        (["system=pendulum2", "system.lengths=[1,-1]"], "system.lengths"),
        (["system=mass_spring", "system.mass=-1"], "system.mass=-1"),
        (["system=damped_pendulum", "system.damping=-0.1"], "system.damping=-0.1"),
        (["model.activation=nope"], "model.activation='nope'"),
        (["model=inn_node", "model.blocks=0"], "model.blocks=0"),
        (["regulariser=hamiltonian", "regulariser.weight=-1"], "regulariser.weight=-1"),
        (["regulariser=hamiltonian", "regulariser.jacobian=sideways"], "regulariser.jacobian='sideways'"),
        (["integrator.method=rk5"], "integrator.method='rk5' is unknown; allowed:"),
        (["system=gyroscope", "system.inertias=[1,2]"], "system.inertias"),
    ],
)
def test_constructor_errors_are_one_line(tmp_path, overrides, key):
    refused(tmp_path, overrides, key, ConfigError)


# class 2: wrong types, named with key, value and the expected type
@pytest.mark.parametrize(
    "overrides, key, expected",
    [
        (["seed=abc"], "seed='abc'", "int"),
        (["data.dt=abc"], "data.dt='abc'", "float"),
        (["data.n_train=2.5"], "data.n_train=2.5", "int"),
        (["data.noise=[1]"], "data.noise=[1]", "float"),
        (["regulariser=hamiltonian", "regulariser.weight=abc"], "regulariser.weight='abc'", "float"),
        (["optimizer.lr=fast"], "optimizer.lr='fast'", "number"),
        (["horizon=1.5"], "horizon=1.5", "int"),
        (["system=pendulum1", "system.n_links=2.5"], "system.n_links=2.5", "int"),
        (["model.hidden=[1,2]"], "model.hidden=[1, 2]", "int"),
        (["integrator.substeps=2.5"], "integrator.substeps=2.5", "int"),
        (["trainer.max_epochs=1.5"], "trainer.max_epochs=1.5", "integer"),
        (["test=maybe"], "test='maybe'", "bool"),
    ],
)
def test_wrong_types_name_key_value_and_type(tmp_path, overrides, key, expected):
    assert expected in refused(tmp_path, overrides, key, ConfigError)


# class 3: nonsense is refused, not silently fixed
@pytest.mark.parametrize(
    "overrides, key",
    [
        (["data.test_steps=0"], "data.test_steps=0"),
        (["data.test_steps=-3"], "data.test_steps=-3"),
        (["data.test_steps=5"], "data.test_steps=5"),
        (["horizon=50"], "horizon=50"),
        (["horizon=0"], "horizon=0"),
        (["data.chunk_len=1"], "data.chunk_len=1; allowed: [2, "),
        (["data.n_train=0"], "data.n_train=0; allowed: >= 1"),
        (["model.depth=0"], "model.depth=0"),
    ],
)
def test_nonsense_is_refused(tmp_path, overrides, key):
    refused(tmp_path, overrides, key)


def test_a_file_without_training_trajectories_is_refused(tmp_path):
    t = np.arange(11) * 0.1
    np.savez(tmp_path / "one.npz", t=t, train=np.zeros((1, 11, 2)), test=np.zeros((1, 11, 2)))
    line = refused(tmp_path, ["system=from_file", f"system.path={tmp_path / 'one.npz'}"], "one.npz", DataError)
    assert "no train trajectories" in line


# class 4: checkpoints
def test_divergence_without_a_checkpoint_says_so(train_run, monkeypatch):
    from encons.infra.errors import DivergenceError
    from encons.training.module import TrainingModule

    loss = TrainingModule.loss
    monkeypatch.setattr(TrainingModule, "loss", lambda self, batch: loss(self, batch) * float("nan"))
    with pytest.raises(DivergenceError, match="no checkpoint was written") as err:
        train_run(["model=node", "system=pendulum1"], name="nan0")
    assert "resume with ckpt_path=last" not in str(err.value)


def test_resuming_a_checkpoint_of_another_shape_names_the_parameter(train_run, tmp_path):
    train_run(["model=node", "system=pendulum1", "trainer.max_epochs=1"], name="small")
    ckpt = tmp_path / "small" / "checkpoints" / "last.ckpt"
    with pytest.raises(
        ConfigError,
        match=r"parameter model\.net\.0\.bias is shape \(16,\) in the checkpoint "
        r"and shape \(32,\) in this model; allowed",
    ) as err:
        train_run(["model=node", "system=pendulum1", "model.hidden=32", f"ckpt_path={ckpt}"], name="wide")
    assert "\n" not in str(err.value)
    (tmp_path / "junk.ckpt").write_bytes(b"not a checkpoint")
    with pytest.raises(ConfigError, match="not a readable checkpoint"):
        train_run(["model=node", "system=pendulum1", f"ckpt_path={tmp_path / 'junk.ckpt'}"], name="junk")


def test_ckpt_path_last_resumes_only_a_run_of_the_same_config(train_run, tmp_path):
    train_run(["model=node", "system=pendulum1", "trainer.max_epochs=1"], name="node")
    train_run(["model=hnn", "system=pendulum1", "trainer.max_epochs=1"], name="hnn")  # newer, another model
    train_run(["model=node", "system=pendulum1", "trainer.max_epochs=2", "ckpt_path=last"], name="again")
    # the node run's epoch 0 was resumed (the newer hnn checkpoint would not even load): one more epoch, in the node
    # run's own folder (the resuming run's is removed)
    assert torch.load(tmp_path / "node" / "checkpoints" / "last.ckpt", weights_only=False)["epoch"] == 1
    assert not (tmp_path / "again").exists()
    with pytest.raises(
        ConfigError,
        match=r"ckpt_path=last: no earlier run .* has this run's config \(newest: "
        r"node has model.hidden=16 where this run has 24\); allowed",
    ):
        train_run(["model=node", "system=pendulum1", "model.hidden=24", "ckpt_path=last"], name="other")


# class 5: files and folders
@pytest.mark.parametrize("where", ["output", "checkpoints", "figures", "cache"])
def test_a_file_where_a_folder_belongs_is_one_line(tmp_path, where):
    out, cache = tmp_path / "run", tmp_path / "cache"
    blocker = {"output": out, "checkpoints": out / "checkpoints", "figures": out / "figures", "cache": cache}[where]
    blocker.parent.mkdir(parents=True, exist_ok=True)
    blocker.write_text("not a folder")
    with pytest.raises(ConfigError, match="is a file, not a folder; allowed"):
        from encons.entry.api import build

        build(compose(["debug=fast"], out, cache))


def test_a_damaged_cache_is_rebuilt_and_said(tmp_path, caplog):
    data, _ = build_with(tmp_path)
    cache = data.cache_file
    good = data.states["test"].clone()
    cache.write_bytes(b"PK\x03\x04 truncated")
    with caplog.at_level("WARNING"):
        data2, _ = build_with(tmp_path)
    assert "damaged, rebuilding" in caplog.text
    assert torch.equal(data2.states["test"], good)


def test_cache_files_are_group_readable_and_orphans_of_dead_writers_go(tmp_path):
    t = torch.arange(3, dtype=torch.float64)
    dead = tmp_path / f"x.{atomic._host()}.999999999.abc{atomic.TMP_SUFFIX}"
    other_host = tmp_path / f"x.elsewhere.1.abc{atomic.TMP_SUFFIX}"
    live = tmp_path / f"x.{atomic._host()}.{os.getpid()}.abc{atomic.TMP_SUFFIX}"
    for f in (dead, other_host, live):
        f.write_bytes(b"")
    store.save(tmp_path / "x.npz", t, {"train": torch.zeros(1, 3, 2), "test": torch.zeros(1, 3, 2)}, "angle")
    assert not dead.exists() and other_host.exists() and live.exists()
    assert os.stat(tmp_path / "x.npz").st_mode & stat.S_IRGRP


# classes 6–7 through the CLI's main: exit 2, the one line last (in this process; one real process below)
@pytest.mark.parametrize(
    "args, key",
    [
        (["-m", "sweeps=optuna", "hydra.sweeper.n_trials=0"], "hydra.sweeper.n_trials=0"),
        (["-m", "sweeps=optuna", "sweeps.storage=mysql://u@localhost/x"], "sweeps.storage='mysql://u@localhost/x'"),
        (["-m", "seed=-1"], "seed=-1"),
        (
            ["-m", "sweeps=optuna", "seed=-1", "optimizer.lr=tag(log,interval(1e-4,1e-2))"],
            "hydra.sweeper.sampler.seed=-1",
        ),
        (
            [
                "-m",
                "sweeps=optuna",
                "hydra.sweeper.n_trials=2",
                "data.n_train=-1",
                "optimizer.lr=tag(log,interval(1e-4,1e-2))",
            ],
            "first: ConfigError: data.n_train=-1",
        ),
        (["seed=["], "seed=["),
    ],
)
def test_cli_ends_with_the_one_line(cli, tmp_path, args, key):
    proc = cli(
        "debug=fast", *args, f"hydra.run.dir={tmp_path / 'run'}", f"hydra.sweep.dir={tmp_path / 'multi'}", cwd=tmp_path
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("encons: error: ") and key in last and "allowed" in last, last


@pytest.mark.slow
def test_a_real_cli_process_exits_2_with_the_one_line_last(tmp_path):
    """A sweep whose trials fail in a real interpreter (Hydra's and Optuna's logging live): exit 2, the line
    last. The single-run path is the in-process cases above (the same ``encons.entry.cli.train``)."""
    proc = run_cli(
        "debug=fast",
        "-m",
        "sweeps=optuna",
        "hydra.sweeper.n_trials=2",
        "data.n_train=-1",
        "optimizer.lr=tag(log,interval(1e-4,1e-2))",
        f"hydra.run.dir={tmp_path / 'run'}",
        cwd=tmp_path,
        env={"ENCONS_ROOT": str(tmp_path)},
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("encons: error: ") and "first: ConfigError: data.n_train=-1" in last and "allowed" in last, (
        last
    )


def test_a_sweep_dir_without_sweeps_dir_creates_the_study_folder(cli, tmp_path):
    proc = cli(
        "-m",
        "sweeps=optuna",
        "debug=fast",
        "figures=false",
        "test=false",
        "hydra.sweeper.n_trials=1",
        "trainer.max_epochs=1",
        f"hydra.sweep.dir={tmp_path / 'elsewhere'}",
        f"sweeps.dir={tmp_path / 'new' / 'study'}",
        "optimizer.lr=tag(log,interval(1e-4,1e-2))",
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert (tmp_path / "new" / "study" / "optuna.db").is_file()


# ranges: declared beside each parameter (encons.infra.bounds), every value finite
@pytest.mark.parametrize(
    "overrides, key",
    [
        (["seed=-1"], "seed=-1"),
        (["seed=4294967296"], "seed=4294967296"),
        (["data.seed=-5"], "data.seed=-5"),
        (["data.noise=-1"], "data.noise=-1"),
        (["data.n_val=-1"], "data.n_val=-1"),
        (["data.n_val=0"], "data.n_val=0"),
        (["optimizer.weight_decay=-1"], "optimizer.weight_decay=-1"),
        (["scheduler=plateau", "scheduler.factor=2"], "scheduler.factor=2"),
        (["scheduler=cosine", "scheduler.warmup=1.5"], "scheduler.warmup=1.5"),
        (["integrator=dopri5", "integrator.rtol=-1"], "integrator.rtol=-1"),
        (["integrator=dopri5", "integrator.atol=0"], "integrator.atol=0"),
        (["regulariser=hamiltonian", "regulariser.weight=nan"], "regulariser.weight=nan"),
        (["regulariser=hamiltonian", "regulariser.weight=inf"], "regulariser.weight=inf"),
        (["trainer.gradient_clip_val=-1"], "trainer.gradient_clip_val=-1"),
        (["trainer.gradient_clip_val=abc"], "trainer.gradient_clip_val='abc'"),
    ],
)
def test_values_out_of_range_are_one_line(tmp_path, overrides, key):
    assert refused(tmp_path, overrides, key, ConfigError).startswith(key)


# class 1 for the trainer, loggers and callbacks (built by encons.entry.api.build_trainer)
@pytest.mark.parametrize(
    "overrides, key",
    [
        (["trainer.accelerator=tpu"], "trainer.accelerator=tpu"),
        (["trainer.devices=abc"], "trainer.devices=abc"),
        (["+trainer.precision=13"], "trainer.precision=13"),
        (["callbacks.best.mode=sideways"], "callbacks.best.mode=sideways"),
        (["callbacks.best.save_top_k=abc"], "callbacks.best.save_top_k='abc'"),
        (["logger=csv", "+logger.csv.flush_logs_every_n_steps=abc"], "logger.csv.flush_logs_every_n_steps='abc'"),
        (["logger=csv", "+logger.csv.bogus=1"], "logger.csv"),
    ],
)
def test_trainer_logger_and_callback_errors_are_one_line(tmp_path, overrides, key):
    from encons.entry.api import build_trainer

    with pytest.raises(ConfigError) as err:
        build_trainer(compose(["debug=fast", *overrides], tmp_path / "run", tmp_path / "cache"))
    line = str(err.value)
    assert "\n" not in line and key in line and "allowed" in line, line


@pytest.mark.parametrize(
    "overrides, key",
    [
        (["callbacks.best.dirpath=/proc/encons"], "callbacks.best.dirpath='/proc/encons'"),
        (["logger=csv", "logger.csv.save_dir=/proc/encons"], "logger.csv.save_dir='/proc/encons'"),
    ],
)
def test_folders_of_loggers_and_callbacks_are_checked(tmp_path, overrides, key):
    refused(tmp_path, overrides, key, ConfigError)


def test_an_unlogged_optimized_metric_names_the_logged_ones(train_run):
    with pytest.raises(
        ConfigError,
        match=r"validation.criterion=rollout logs no val/nope, which this run monitors "
        r".*; allowed: .*val/traj_rel_err",
    ):
        train_run(["model=node", "system=pendulum1", "trainer.max_epochs=1", "optimized_metric=val/nope"])


# class 6 in-process: the sweeper's own keys, and the study a report reads
def test_sweeper_keys_are_one_line(tmp_path):
    from omegaconf import OmegaConf

    from encons.tools.sweep import OptunaSweeper

    def sweeper(sampler=None, **keys):
        args = (
            dict(
                direction="minimize",
                storage=None,
                study_name="s",
                n_trials=1,
                n_jobs=1,
                max_failure_rate=0.5,
                params=None,
            )
            | keys
        )
        return OptunaSweeper(OmegaConf.create(sampler or {"_target_": "optuna.samplers.TPESampler"}), **args)

    for keys, key in (
        (dict(n_jobs=-1), "hydra.sweeper.n_jobs=-1"),
        (dict(direction="up"), "hydra.sweeper.direction='up'"),
    ):
        with pytest.raises(ConfigError, match=f"^{key}.*; allowed: "):
            sweeper(**keys)
    with pytest.raises(ConfigError, match=r"^hydra.sweeper.sampler.seed=-1 .*allowed: an integer"):
        sweeper({"_target_": "optuna.samplers.TPESampler", "seed": -1})._sampler(0)
    with pytest.raises(ConfigError, match=r"^hydra.sweeper.sampler='optuna.samplers.TPESampler': TypeError: .*bogus"):
        sweeper({"_target_": "optuna.samplers.TPESampler", "bogus": 1})._sampler(0)


def test_a_missing_study_names_the_stored_ones(tmp_path):
    import optuna

    from encons.tools.sweep import load_study

    url = f"sqlite:///{tmp_path / 'db' / 'optuna.db'}"
    (tmp_path / "db").mkdir()
    optuna.create_study(storage=url, study_name="kept")
    with pytest.raises(ConfigError, match=r"^study='gone' is not in .*; allowed: kept$"):
        load_study(url, "gone")
    assert load_study(url, "kept").study_name == "kept"


@pytest.mark.parametrize(
    "module, args, line",
    [
        (
            "encons.benchmark",
            ["profile=smoke", "train=[trainer.max_epochs=150]"],
            "encons: error: train=[trainer.max_epochs=150]: a list element holding '=' needs quotes; allowed: "
            "'train=[\"trainer.max_epochs=150\"]' (quoted as shown)",
        ),
        (
            "encons.train",
            ["trainer.max_epoch=3"],
            "encons: error: trainer.max_epoch is not a key of the config, did you mean trainer.max_epochs; allowed: "
            "the keys `--cfg job` prints, or +trainer.max_epoch=VALUE to add one",
        ),
        (
            "encons.train",
            ["modl.hidden=3"],
            "encons: error: modl.hidden is not a key of the config, did you mean model.hidden; allowed:",
        ),
    ],
)
def test_an_unquoted_list_and_a_misspelt_key_get_a_one_line_hint(tmp_path, monkeypatch, module, args, line):
    """Issue 51: Hydra's parse error of an unquoted `train=[k=v]` and a key one letter off."""
    from tests.helpers import in_process

    monkeypatch.chdir(tmp_path)
    proc = in_process(module, [*args, f"out={tmp_path / 'b'}"] if module == "encons.benchmark" else args, monkeypatch)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith(line), proc.stderr


def test_a_ckpt_path_to_a_text_file_is_the_only_line_printed(cli, tmp_path):
    """Issue 51: the data were simulated (their log lines printed) before the checkpoint was read."""
    (tmp_path / "notes.txt").write_text("not a checkpoint\n")
    proc = cli(
        "debug=fast",
        "model=node",
        "system=pendulum1",
        f"ckpt_path={tmp_path / 'notes.txt'}",
        f"paths.cache_dir={tmp_path / 'cache'}",
        f"hydra.run.dir={tmp_path / 'run'}",
        cwd=tmp_path,
    )
    assert proc.returncode == 2 and not (tmp_path / "cache").exists()
    assert (proc.stdout + proc.stderr).strip().splitlines() == [
        f"encons: error: ckpt_path={str(tmp_path / 'notes.txt')!r} is not a readable checkpoint (RuntimeError); "
        f"allowed: a .ckpt written by encons"
    ]


def test_evaluate_of_a_folder_that_does_not_exist_says_so(tmp_path, monkeypatch):
    from tests.helpers import in_process

    proc = in_process("encons.evaluate", [str(tmp_path / "nope")], monkeypatch)
    assert proc.returncode == 2 and proc.stderr.strip() == (
        f"encons: error: {str(tmp_path / 'nope')!r} does not "
        f"exist; allowed: a run folder that train wrote, or its .ckpt"
    )
