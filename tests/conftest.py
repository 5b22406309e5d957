"""Shared fixtures: an isolated environment (wandb, caches) and tiny end-to-end training runs."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import open_dict

from encons.paths import config_dir

torch.set_default_dtype(torch.float32)


@pytest.fixture(autouse=True)
def isolated_env(tmp_path_factory, monkeypatch):
    """Keep wandb offline and its files, and every cache, inside a temporary folder."""
    home = tmp_path_factory.mktemp("home")
    for key in ("WANDB_DIR", "WANDB_CACHE_DIR", "WANDB_CONFIG_DIR", "WANDB_DATA_DIR"):
        monkeypatch.setenv(key, str(home))
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_SILENT", "true")
    monkeypatch.setenv("ENCONS_ROOT", str(home))
    yield
    GlobalHydra.instance().clear()


def compose_train(overrides: list[str], output_dir: Path, fast: bool = True):
    """Compose ``train.yaml`` as the CLI would, with outputs under ``output_dir``."""
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=config_dir(), job_name="test"):
        cfg = compose("train", overrides=(["debug=fast"] if fast else []) + overrides, return_hydra_config=True)
    HydraConfig.instance().set_config(cfg)
    with open_dict(cfg):
        cfg.paths.output_dir = str(output_dir)
        cfg.paths.cache_dir = str(output_dir.parent / "cache")
    return cfg


@pytest.fixture
def train_run(tmp_path):
    """Run ``encons.train.train`` on a tiny config: ``train_run(["model=hnn", ...])`` -> metrics."""
    from encons.train import train

    def run(overrides: list[str], name: str = "run", fast: bool = True) -> dict[str, float]:
        return train(compose_train(overrides, tmp_path / name, fast))

    return run


def run_cli(*args: str, cwd: Path | None = None, env: dict | None = None) -> subprocess.CompletedProcess:
    """``python -m encons.train ARGS`` in a subprocess; returns the completed process."""
    return subprocess.run([sys.executable, "-m", "encons.train", *args], capture_output=True, text=True,
                          cwd=cwd, env={**os.environ, **(env or {})}, timeout=600)
