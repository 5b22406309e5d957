"""Helpers shared by the tests: the CLI in a subprocess, and the catalogue of runnable systems."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from omegaconf import OmegaConf

from encons import api


def run_cli(*args: str, cwd: Path | None = None, env: dict | None = None) -> subprocess.CompletedProcess:
    """``python -m encons.train ARGS`` in a subprocess; returns the completed process."""
    return subprocess.run([sys.executable, "-m", "encons.train", *args], capture_output=True, text=True,
                          cwd=cwd, env={**os.environ, **(env or {})}, timeout=600)


def simulated_systems() -> list[str]:
    """Systems of the catalogue whose config is complete (``from_file`` needs the user's ``system.path``)."""
    return [s for s in api.catalogue("system")
            if not OmegaConf.missing_keys(api.compose(f"system={s}", output_dir=".").system)]
