"""Checkpoints: the one function that reads them, finding a run's, and choosing one to resume from.

Every read goes through :func:`read`, with ``torch.load(weights_only=True)``: a pickle that names
anything but tensors and plain containers is refused before any of it runs. What encons saves
(Lightning's state and the run config under :data:`CONFIG_KEY`, a plain dict) needs no other
allowed globals. A checkpoint's saved config is data: it is built only through
``encons.training.build.build``, whose trust check runs before any import.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, cast

from omegaconf import DictConfig, OmegaConf

from encons.infra.errors import ConfigError

log = logging.getLogger(__name__)
CONFIG_KEY = "encons_config"  # where a checkpoint carries its resolved run config
ENSEMBLE_KEY = "encons_ensemble"  # where an ensemble's last.ckpt keeps what Lightning does not

#: Modules whose classes a config names by ``_target_`` and that moved into layer packages (issue 49): a config
#: saved before (in a checkpoint or a run's config.yaml) names the old module, read as the new one.
MOVED = {
    f"encons.{old}.": f"encons.{new}."
    for old, new in {
        "callbacks": "training.callbacks",
        "evaluation": "numerics.evaluation",
        "integrators": "numerics.integrators",
        "lightning_io": "infra.lightning_io",
        "regularisers": "numerics.regularisers",
        "schedules": "training.schedules",
        "sweep": "tools.sweep",
    }.items()
}


def current_targets(saved: Any) -> Any:
    """``saved`` (a stored config as plain containers) with every ``_target_`` of a moved module renamed."""
    if isinstance(saved, dict):
        out = {k: current_targets(v) for k, v in saved.items()}
        target = out.get("_target_")
        if isinstance(target, str):
            old = next((o for o in MOVED if target.startswith(o)), None)
            out["_target_"] = target if old is None else MOVED[old] + target[len(old) :]
        return out
    if isinstance(saved, list):
        return [current_targets(v) for v in saved]
    return saved


def stored_config(path: str | Path) -> dict:
    """The run config the checkpoint at ``path`` carries ({} where none), its moved targets renamed."""
    return current_targets(read(path, "ckpt_path").get(CONFIG_KEY) or {})


#: The config keys a resume must share with the checkpoint's run (budget and paths may differ).
RESUME_KEYS = (
    "system",
    "model",
    "data",
    "integrator",
    "regulariser",
    "objective",
    "optimizer",
    "scheduler",
    "seed",
    "seeds",
)


def read(path: str | Path, key: str = "ckpt") -> dict[str, Any]:
    """The contents of checkpoint ``path`` (memory-mapped, on the CPU), read with ``weights_only=True``;
    a file that is missing, damaged or not a plain checkpoint is one ``ConfigError`` naming ``key``."""
    import torch

    try:
        state = torch.load(path, map_location="cpu", weights_only=True, mmap=True)
    except Exception as err:  # noqa: BLE001 - torch raises several types for a file that is not a checkpoint
        raise ConfigError(
            f"{key}={str(path)!r} is not a readable checkpoint ({type(err).__name__}); "
            f"allowed: a .ckpt written by encons"
        ) from None
    if not isinstance(state, dict) or "state_dict" not in state:
        raise ConfigError(f"{key}={str(path)!r} holds no state_dict; allowed: a .ckpt written by encons")
    return state


def find(run_dir: Path, which: str = "best") -> Path:
    """``best`` (lowest validation error), ``last``, or a path to a ``.ckpt``."""
    if which == "last":
        found = [run_dir / "checkpoints" / "last.ckpt"]
    elif which == "best":
        found = sorted((run_dir / "checkpoints").glob("best-*.ckpt"))
    else:
        found = [Path(which)]
    if not found or not found[-1].is_file():
        raise ConfigError(f"ckpt={which!r}: no such checkpoint under {run_dir}; allowed: best, last or a .ckpt path")
    return found[-1]


def resume_from(cfg: DictConfig) -> str | None:
    """The checkpoint to resume from: ``cfg.ckpt_path``, or for ``last`` the newest ``last.ckpt`` among
    the earlier runs beside this one whose saved config matches this run's :data:`RESUME_KEYS` (this run's own
    folder first: the resume line's ``hydra.run.dir``).
    Every candidate is read (and so validated) here, before Lightning opens it; a damaged one is
    skipped with one warning."""
    if cfg.ckpt_path != "last":
        if cfg.ckpt_path is not None and not Path(cfg.ckpt_path).is_file():
            raise ConfigError(f"ckpt_path={cfg.ckpt_path!r} does not exist; allowed: a .ckpt file, last or null")
        if cfg.ckpt_path is not None:
            read(cfg.ckpt_path, "ckpt_path")
        return cfg.ckpt_path
    own = Path(cfg.paths.output_dir) / "checkpoints" / "last.ckpt"  # a resume into the stopped run's own folder
    runs = Path(cfg.paths.output_dir).parent
    found = sorted(runs.glob("*/checkpoints/last.ckpt"), key=lambda p: (p == own, p.stat().st_mtime), reverse=True)
    if not found:
        raise ConfigError(
            f"ckpt_path=last: no earlier run of '{cfg.name}' has a checkpoint under {runs}; "
            f"allowed: a .ckpt file, or null to start afresh"
        )
    differences = []
    for path in found:
        try:
            diff = difference(cfg, path)
        except ConfigError:  # a damaged file (a run killed mid-write before writes were atomic, a full disk)
            log.warning(
                "ckpt_path=last: skipped %s: not a readable checkpoint; trying the earlier runs' last.ckpt", path
            )
            continue
        if diff is None:
            return str(path)
        differences.append(f"{path.parent.parent.name} has {diff}")
    if not differences:
        others = f", nor is any of the {len(found) - 1} other last.ckpt under {runs}" if len(found) > 1 else ""
        raise ConfigError(
            f"ckpt_path=last: {str(found[0])!r} is not a readable checkpoint{others}; allowed: "
            f"a .ckpt file, or null to start afresh"
        )
    raise ConfigError(
        f"ckpt_path=last: no earlier run under {runs} has this run's config (newest: {differences[0]}); "
        f"allowed: the same system/model/data/optimizer config, ckpt_path=PATH, or null"
    )


def difference(cfg: DictConfig, path: Path) -> str | None:
    """None when the checkpoint at ``path`` was trained with ``cfg``'s :data:`RESUME_KEYS`, else the first
    difference as ``key=saved where this run has value``."""
    masked = OmegaConf.masked_copy(cfg, [k for k in RESUME_KEYS if k in cfg])
    mine = cast("dict[str, Any]", OmegaConf.to_container(masked, resolve=True))  # a DictConfig's container: a dict
    saved = stored_config(path)
    diff = _first_difference({k: saved.get(k) for k in mine}, mine)
    return None if diff is None else f"{diff[0]}={diff[1]!r} where this run has {diff[2]!r}"


def _first_difference(a: Any, b: Any, key: str = "") -> tuple[str, Any, Any] | None:
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            found = _first_difference(a.get(k), b.get(k), f"{key}.{k}".lstrip("."))
            if found:
                return found
        return None
    return None if a == b else (key, a, b)


def dropped_biases(module: Any, state_dict: dict[str, Any]) -> list[str]:
    """The keys of ``state_dict`` that are biases ``module`` has set to None: an energy network's output bias,
    which never reached the loss (``encons.models.networks.mlp(out_bias=False)``) and which checkpoints written
    before 26 November 2026 still hold."""
    own = module.state_dict()
    return [
        k
        for k in state_dict
        if k not in own
        and k.endswith(".bias")
        and getattr(_submodule(module, k.rpartition(".")[0]), "bias", False) is None
    ]


def _submodule(module: Any, name: str) -> Any:
    try:
        return module.get_submodule(name)
    except AttributeError:
        return None


def load_weights(module: Any, state_dict: dict[str, Any]) -> None:
    """``module.load_state_dict(state_dict)``, leaving out :func:`dropped_biases` (a constant with no effect on
    the field), so an older checkpoint loads and scores as it did."""
    dropped = dropped_biases(module, state_dict)
    if dropped:
        log.info("left out %s: biases this version drops (they never reached the loss)", ", ".join(dropped))
    module.load_state_dict({k: v for k, v in state_dict.items() if k not in dropped})


def check_fits(module: Any, path: str) -> None:
    """Refuse a checkpoint whose parameters do not fit ``module`` (another model or size), naming the first."""
    state = read(path, "ckpt_path")
    if "optimizer_states" not in state:  # a seed ensemble member's best checkpoint: its weights alone
        raise ConfigError(
            f"ckpt_path={path!r} holds weights only (an ensemble member's best checkpoint), no optimiser "
            f"state to resume from; allowed: evaluate it (python -m encons.evaluate {path}), or resume "
            f"the ensemble with its seeds=[...] and ckpt_path=last"
        )
    saved = state["state_dict"]
    own = module.state_dict()
    old = dropped_biases(module, saved)
    if old:
        raise ConfigError(
            f"ckpt_path={path!r} holds {old[0]}, an output bias this version of encons drops (it never "
            f"reached the loss), so its optimiser state cannot resume; allowed: evaluate it "
            f"(python -m encons.evaluate), or train from scratch (ckpt_path=null)"
        )
    for name in sorted(set(saved) | set(own)):
        shapes = [tuple(d[name].shape) if name in d else None for d in (saved, own)]
        if shapes[0] != shapes[1]:
            said = ["absent" if s is None else f"shape {s}" for s in shapes]
            raise ConfigError(
                f"ckpt_path={path!r}: parameter {name} is {said[0]} in the checkpoint and {said[1]} "
                f"in this model; allowed: a checkpoint of the same model config (model.*) written by this "
                f"version of encons"
            )
