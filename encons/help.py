"""The ``--help`` of ``encons-train``: the config groups a user picks from, not internal bases
(``_chain``, ``_base``), the benchmark's ``profile`` group or the sweeps' sub-groups."""

from __future__ import annotations

from pathlib import Path

from encons.paths import config_dir

GROUPS = ("system", "model", "integrator", "regulariser", "observation", "optim", "trainer", "logger", "debug",
          "experiment")


def groups_text() -> str:
    """``group: option, ...`` for the user-facing groups of ``conf/``, then the sweeps (``-m``)."""
    def options(group: str) -> str:
        return ", ".join(sorted(p.stem for p in (Path(config_dir()) / group).glob("*.yaml")
                                if not p.name.startswith("_")))

    lines = [f"{group}: {options(group)}" for group in GROUPS]
    lines += ["", "with -m (a multirun): sweeps: " + options("sweeps"),
              "(folders on hydra.searchpath add options of their own)"]
    return "\n".join(lines)


def register() -> None:
    """Make ``${encons_help_groups:}`` (used by ``conf/hydra/default.yaml``'s help template) resolve."""
    from omegaconf import OmegaConf

    OmegaConf.register_resolver("encons_help_groups", groups_text, replace=True)
