"""Helpers shared by the tests: the CLI in a subprocess or in this process, and the catalogue of runnable systems."""

from __future__ import annotations

import contextlib
import functools
import io
import logging
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

from hydra.core.global_hydra import GlobalHydra
from omegaconf import OmegaConf

from encons.entry import api

#: Santos et al. §7's integration (500 steps × 16 starts: minutes) at a size a tiny run can afford.
SANTOS_TINY = ["evaluators.santos.steps=20", "evaluators.santos.n_trajectories=4"]


def run_cli(*args: str, cwd: Path | None = None, env: dict | None = None) -> subprocess.CompletedProcess:
    """``python -m encons.train ARGS`` in a subprocess; returns the completed process."""
    return subprocess.run(
        [sys.executable, "-m", "encons.train", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        env={**os.environ, **(env or {})},
        timeout=600,
    )


def in_process(module: str, argv: list[str], monkeypatch) -> SimpleNamespace:
    """``python -m module ARGV`` run in this process through its ``encons.entry.cli`` function -> exit code,
    stdout and stderr. Output goes to buffers that stay open: loggers set up during the call (Hydra's,
    Optuna's) may keep them."""
    from encons.entry import cli

    entry = {
        "encons.train": cli.train,
        "encons.evaluate": cli.evaluate,
        "encons.benchmark": cli.benchmark,
        "encons.report": cli.report,
        "encons.sweep": cli.sweep_report,
    }[module]
    monkeypatch.setattr(sys, "argv", [module, *argv])
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level  # Hydra's job logging replaces them
    out, err, code = io.StringIO(), io.StringIO(), 0
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            entry()
    except SystemExit as stop:
        code = stop.code
    finally:
        GlobalHydra.instance().clear()
        root.handlers[:], root.level = handlers, level
    return SimpleNamespace(returncode=code, stdout=out.getvalue(), stderr=err.getvalue())


@functools.cache
def simulated_systems() -> tuple[str, ...]:
    """Systems of the catalogue whose config is complete (``from_file`` needs the user's ``system.path``).
    Composed once per process (three test modules ask at collection; ~0.4 s per system)."""
    return tuple(
        s
        for s in api.catalogue("system")
        if not OmegaConf.missing_keys(api.compose(f"system={s}", output_dir=".").system)
    )
