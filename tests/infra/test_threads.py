"""The thread policy (``encons.infra.threads``): the default a run takes, what wins over it, and how the
CLI, the API, parallel sweeps and the benchmark reach it. The environment is per process, so the
runs that start without a thread setting are subprocesses."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
import torch

from encons.entry import api
from encons.infra import threads
from encons.infra.errors import ConfigError
from encons.tools.benchmark import expand
from encons.training.build import compose

#: a subprocess that builds a tiny run through the API and prints torch's threads before and after
BUILD = """
import sys, torch, encons, encons.entry.api
before = torch.get_num_threads()
cfg = encons.compose("debug=fast", "system=pendulum1", *sys.argv[2:], output_dir=sys.argv[1] + "/run",
                     cache_dir=sys.argv[1] + "/cache")
encons.entry.api.build(cfg)
print(before, torch.get_num_threads())
"""


def _without_thread_env(**extra: str) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in threads.ENV_KEYS}
    return {**env, **extra}


def _build_threads(tmp_path, *overrides: str, env: dict) -> tuple[int, int]:
    """torch's threads in a new process before and after ``encons.training.build`` of a tiny run."""
    done = subprocess.run(
        [sys.executable, "-c", BUILD, str(tmp_path), *overrides], capture_output=True, text=True, env=env, timeout=300
    )
    assert done.returncode == 0, done.stderr
    before, after = map(int, done.stdout.split()[-2:])
    return before, after


@pytest.fixture
def torch_threads():
    """Restore torch's thread count after a test that sets it."""
    n = torch.get_num_threads()
    yield
    torch.set_num_threads(n)


@pytest.mark.slow
def test_cli_run_without_thread_setting_uses_policy_default(tmp_path):
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "encons.train",
            "debug=fast",
            "system=pendulum1",
            "model=hnn_angle",
            "logger=none",
            "test=false",
            f"hydra.run.dir={tmp_path / 'run'}",
            f"paths.cache_dir={tmp_path / 'cache'}",
        ],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env=_without_thread_env(),
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    row = next(line for line in done.stdout.splitlines() if " threads " in line)
    assert row.split("│")[2].strip() == str(threads.DEFAULT)


@pytest.mark.slow
def test_environment_setting_wins_over_policy_default(tmp_path):
    assert _build_threads(tmp_path, env=_without_thread_env(OMP_NUM_THREADS="3"))[1] == 3


def test_mkl_variable_counts_when_omp_is_unset(monkeypatch):
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.setenv("MKL_NUM_THREADS", "2")
    assert threads.choose(None) == 2 and threads.choose("auto") == 2


def test_threads_key_wins_over_environment(monkeypatch, torch_threads):
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    assert threads.apply(2) == 2 and torch.get_num_threads() == 2
    assert threads.apply(None) == 3 and torch.get_num_threads() == 3


def test_auto_is_cores_over_parallel_runs(monkeypatch):
    for key in threads.ENV_KEYS:
        monkeypatch.delenv(key, raising=False)
    monkeypatch.setattr(threads, "cores", lambda: 8)
    assert threads.choose("auto") == 8
    assert threads.choose("auto", parallel=3) == 2
    assert threads.choose("auto", parallel=16) == 1
    assert threads.choose(None, parallel=2) == threads.DEFAULT


@pytest.mark.parametrize("value", [0, -1, 2.5, "two", True])
def test_bad_threads_value_is_one_line(value):
    with pytest.raises(ConfigError, match=rf"^threads={value!r}; allowed: null .*auto"):
        threads.choose(value)


def test_bad_environment_value_names_the_variable(monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "lots")
    with pytest.raises(ConfigError, match=r"^OMP_NUM_THREADS='lots' \(environment\); allowed: a positive integer"):
        threads.choose(None)


def test_cli_bad_threads_is_one_line(cli, tmp_path):
    done = cli("debug=fast", "system=pendulum1", "threads=0", f"hydra.run.dir={tmp_path / 'run'}")
    assert done.returncode == 2
    assert done.stderr.strip().splitlines()[-1].startswith("encons: error: threads=0; allowed: null")


@pytest.mark.parametrize("threads_key, expected", [("null", threads.DEFAULT), ("3", 3), ("auto", None)])
def test_parallel_launcher_gives_each_worker_the_policy_number(monkeypatch, tmp_path, threads_key, expected):
    for key in threads.ENV_KEYS:
        monkeypatch.delenv(key, raising=False)
    cfg = api.compose(
        "hydra/launcher=parallel", "hydra.launcher.n_jobs=2", f"threads={threads_key}", output_dir=tmp_path
    )
    want = max(1, threads.cores() // 2) if expected is None else expected
    assert cfg.hydra.launcher.inner_max_num_threads == want


def test_parallel_launcher_passes_the_users_environment_on(monkeypatch, tmp_path):
    monkeypatch.setenv("OMP_NUM_THREADS", "5")
    cfg = api.compose("hydra/launcher=parallel", output_dir=tmp_path)
    assert cfg.hydra.launcher.inner_max_num_threads == 5


@pytest.mark.parametrize("given, value", [("null", None), ("2", 2), ("auto", "auto")])
def test_benchmark_threads_key_reaches_every_run(tmp_path, given, value):
    bench = compose(["profile=smoke", f"threads={given}"], config_name="benchmark")
    for run in expand(bench):
        assert api.compose(*run.overrides, output_dir=tmp_path).threads == value
    again = compose(["profile=smoke", "threads=2", 'train=["threads=1"]'], config_name="benchmark")
    assert {api.compose(*r.overrides, output_dir=tmp_path).threads for r in expand(again)} == {1}
