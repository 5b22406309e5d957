"""The built wheel carries conf/ (with the sweeps group) and encons finds it outside a checkout."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # builds the wheel

ROOT = Path(__file__).resolve().parents[2]


def test_wheel_ships_configs_and_finds_them(tmp_path):
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "-q",
            "--no-deps",
            "--no-build-isolation",
            "-w",
            str(tmp_path / "dist"),
            str(ROOT),
        ],
        check=True,
        capture_output=True,
    )
    wheel = next((tmp_path / "dist").glob("encons-*.whl"))
    names = zipfile.ZipFile(wheel).namelist()
    assert "encons/conf/train.yaml" in names
    assert any(n.startswith("encons/conf/sweeps/") and n.endswith(".yaml") for n in names)
    zipfile.ZipFile(wheel).extractall(tmp_path / "site")
    probe = (
        "import sys; sys.path.insert(0, sys.argv[1]);"
        "from encons.training.build import compose;"
        "cfg = compose(['model=hnn', 'system=pendulum1'], sys.argv[2]);"
        "import encons; print(encons.__file__, cfg.model._target_)"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe, str(tmp_path / "site"), str(tmp_path / "run")],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert str(tmp_path / "site") in out and "encons.models.hnn.HNN" in out
