"""Where encons finds its Hydra configs: a checkout's ``conf/``, else the installed wheel's."""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

_CHECKOUT = Path(__file__).resolve().parents[1]


def config_dir() -> str:
    """The primary config folder (holding ``train.yaml``; ``sweeps`` links to ``sweeps/``)."""
    if (_CHECKOUT / "conf" / "train.yaml").is_file():
        return str(_CHECKOUT / "conf")
    return str(files("encons.conf"))
