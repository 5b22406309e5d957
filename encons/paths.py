"""Where encons finds its Hydra configs: a checkout's ``conf/`` and ``sweeps/``, else the wheel's."""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

_CHECKOUT = Path(__file__).resolve().parents[1]


def config_dir() -> str:
    """The primary config folder (holding ``train.yaml``)."""
    if (_CHECKOUT / "conf" / "train.yaml").is_file():
        return str(_CHECKOUT / "conf")
    return str(files("encons.conf"))


def sweeps_root() -> str:
    """The folder whose ``sweeps/`` sub-folder is the ``sweeps`` config group."""
    if (_CHECKOUT / "sweeps").is_dir() and (_CHECKOUT / "conf").is_dir():
        return str(_CHECKOUT)
    return str(Path(str(files("encons"))))
