"""The ``--help`` of ``encons-train``: the config groups a user picks from, in the order of
``conf/train.yaml``'s defaults list, not internal bases (``_chain``, ``_base``), Hydra's and the paths'
groups, the benchmark's ``profile`` group or the sweeps' sub-groups."""

from __future__ import annotations

from pathlib import Path
from typing import cast

from encons.infra.paths import config_dir

NOT_CHOSEN = ("hydra", "paths", "sweeps")  # Hydra's own, the run folders, and the sweeps (listed apart)


def groups() -> dict[str, object]:
    """The groups ``conf/train.yaml``'s defaults list picks from, in its order, less ``NOT_CHOSEN``, with
    their default choice (a list for a group of which a run takes several, e.g. ``evaluators``)."""
    from omegaconf import OmegaConf

    defaults = OmegaConf.load(Path(config_dir()) / "train.yaml").defaults
    entries = cast(list, OmegaConf.to_container(defaults))  # a ListConfig's container: a list
    return {k: v for e in entries if isinstance(e, dict) for k, v in e.items() if k not in NOT_CHOSEN}


def groups_text() -> str:
    """``group: option, ...`` for the user-facing groups of ``conf/``, then the sweeps (``-m``)."""

    def options(group: str) -> str:
        return ", ".join(
            sorted(p.stem for p in (Path(config_dir()) / group).glob("*.yaml") if not p.name.startswith("_"))
        )

    def name(group: str, default: object) -> str:
        return f"{group} (a list, default [{','.join(default)}])" if isinstance(default, list) else group

    lines = [f"{name(group, default)}: {options(group)}" for group, default in groups().items()]
    lines += [
        "",
        "with -m (a multirun): sweeps: " + options("sweeps"),
        "(folders on hydra.searchpath add options of their own)",
    ]
    return "\n".join(lines)


def register() -> None:
    """Make ``${encons_help_groups:}`` (used by ``conf/hydra/default.yaml``'s help template) resolve."""
    from omegaconf import OmegaConf

    OmegaConf.register_resolver("encons_help_groups", groups_text, replace=True)
