"""Where encons finds its Hydra configs: a checkout's ``conf/``, else the installed wheel's."""

from __future__ import annotations

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parents[1]  # encons/


def config_dir() -> str:
    """The primary config folder (holding ``train.yaml``; its ``sweeps`` links to ``sweeps/``).

    In a checkout that is ``<repo>/conf``; in an installed wheel, ``encons/conf``.
    """
    checkout = _PACKAGE.parent / "conf"
    return str(checkout if (checkout / "train.yaml").is_file() else _PACKAGE / "conf")
