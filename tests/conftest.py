"""Shared fixtures: seeded random state, an isolated environment (wandb, caches) and tiny training runs
(helpers without fixtures live in ``tests/helpers.py``)."""

from __future__ import annotations

import os
import random
from collections import Counter

import numpy as np
import pytest
import torch
from hydra.core.global_hydra import GlobalHydra

torch.set_default_dtype(torch.float32)
torch.set_num_threads(1)  # tiny tensors: threads only contend (about 4× faster on 2 shared cores)


@pytest.fixture(autouse=True)
def seeded():
    """Every test starts from the same random state: draws without their own generator are seeded."""
    random.seed(0)
    np.random.seed(0)
    torch.manual_seed(0)


@pytest.fixture(autouse=True)
def isolated_env(tmp_path_factory, monkeypatch):
    """Keep wandb offline and its files, and every cache, inside a temporary folder."""
    home = tmp_path_factory.mktemp("home")
    for key in ("WANDB_DIR", "WANDB_CACHE_DIR", "WANDB_CONFIG_DIR", "WANDB_DATA_DIR"):
        monkeypatch.setenv(key, str(home))
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_SILENT", "true")
    monkeypatch.setenv("ENCONS_ROOT", str(home))
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    yield
    GlobalHydra.instance().clear()


@pytest.fixture
def cli(monkeypatch):
    """``encons.train``'s CLI in this process: ``cli(*args, cwd=...)`` -> (exit code, stdout, stderr).

    The same ``encons.entry.cli.train()`` as ``python -m encons.train`` (Hydra, the one-line errors, exit 2) without a
    new interpreter importing Lightning for each case; ``tests.helpers.run_cli`` runs a real process."""
    from tests.helpers import in_process

    def run(*args: str, cwd=None):
        if cwd is not None:
            monkeypatch.chdir(cwd)
        return in_process("encons.train", list(args), monkeypatch)

    return run


@pytest.fixture
def train_run(tmp_path):
    """Run ``encons.entry.api.train`` on a tiny config: ``train_run(["model=hnn", ...])`` -> metrics. Without figures
    unless ``figures`` (drawing them is ~2.6 s of a 3.4 s tiny run, benchmarks/reports/figures; the tests of
    figures ask for them)."""
    from encons.entry import api

    def run(overrides: list[str], name: str = "run", fast: bool = True, figures: bool = False) -> dict[str, float]:
        cfg = api.compose(
            *(["debug=fast"] if fast else []),
            f"figures={str(figures).lower()}",
            *overrides,
            output_dir=tmp_path / name,
            cache_dir=tmp_path / "cache",
        )
        return api.train(cfg).metrics

    return run


#: The only reasons a test may skip under CI (ENCONS_STRICT_SKIPS=1, set by .ci/run): hardware this machine
#: lacks or has, and a model × system pair the model's class declares it cannot serve. A dependency the
#: project installs cannot be "missing": such a skip fails the session.
ALLOWED_SKIPS = ("no CUDA device", "needs a machine without a GPU", "declared incompatibility: ")
_skips: Counter = Counter()


def pytest_collection_modifyitems(items):
    """The slow tests first (a stable sort, the same on every xdist worker): the minute-long ones then start
    while there is work left to steal, instead of one of them running alone at the end (CI: 2 workers)."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


def pytest_runtest_logreport(report):
    if report.skipped and not hasattr(report, "wasxfail"):  # an expected failure reports as skipped: not a skip
        longrepr = report.longrepr
        reason = longrepr[2] if isinstance(longrepr, tuple) else str(longrepr)
        _skips[reason.removeprefix("Skipped: ")] += 1


def _disallowed() -> list[str]:
    return [r for r in _skips if not any(a in r for a in ALLOWED_SKIPS)]


def pytest_terminal_summary(terminalreporter):
    if _skips:
        terminalreporter.section("skip reasons")
        for reason, count in sorted(_skips.items(), key=lambda rc: -rc[1]):
            allowed = "" if reason not in _disallowed() else "   <- not an allowed skip"
            terminalreporter.write_line(f"{count:4d} × {reason[:160]}{allowed}")


def pytest_sessionfinish(session, exitstatus):
    if os.environ.get("ENCONS_STRICT_SKIPS") and _disallowed() and exitstatus == 0:
        session.exitstatus = pytest.ExitCode.TESTS_FAILED
