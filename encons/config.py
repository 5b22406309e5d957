"""Checks on a composed config, run before anything is built: one clear error per problem."""

from __future__ import annotations

import inspect
import math
import os
import types
import typing
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from omegaconf import DictConfig, ListConfig, OmegaConf, open_dict

from encons import trust
from encons.errors import ConfigError

if TYPE_CHECKING:
    from encons.build import Request
    from encons.models.base import DynamicsModel
    from encons.systems.base import System


def _at_least(low: float) -> tuple[Any, str]:
    return (lambda v: v >= low), f">= {low}"


_POSITIVE = ((lambda v: v > 0), "> 0")
_COUNT = ((lambda v: v >= 1), "a positive integer")
_SEED = ((lambda v: 0 <= v < 2**32), "0..2**32-1 (numpy's seed range)")

#: Ranges of numeric keys, checked after their types (a key absent from the config is skipped);
#: every value must be a finite number.
BOUNDS: dict[str, tuple[Any, str]] = {
    "seed": _SEED, "data.seed": _SEED, "horizon": _at_least(1),
    "data.dt": _POSITIVE, "data.noise": _at_least(0), "data.n_val": _at_least(0),
    "optimizer.lr": _POSITIVE, "optimizer.weight_decay": _at_least(0), "scheduler.patience": _at_least(0),
    "scheduler.factor": ((lambda v: 0 < v < 1), "in (0, 1)"), "scheduler.warmup": ((lambda v: 0 <= v < 1), "in [0, 1)"),
    "scheduler.pct_start": ((lambda v: 0 < v < 1), "in (0, 1)"),
    "regulariser.weight": _at_least(0), "integrator.rtol": _POSITIVE, "integrator.atol": _POSITIVE,
    "evaluation.rtol": _POSITIVE, "evaluation.atol": _POSITIVE, "evaluation.substeps": _COUNT,
    "evaluation.vpt_threshold": _POSITIVE,
    "model.hidden": _COUNT, "model.depth": _COUNT, "trainer.gradient_clip_val": _at_least(0),
    "observation.latent": _at_least(2), "observation.stack": _COUNT, "observation.hidden": _COUNT,
    "observation.depth": _COUNT, "observation.weight_reconstruction": _at_least(0),
    "observation.weight_prediction": _at_least(0), "observation.weight_velocity": _at_least(0),
    "system.frame_size": _at_least(4), "system.rate_scale": _at_least(0),
    "system.n_links": _COUNT, "system.g": _at_least(0), "system.mass": _POSITIVE, "system.masses": _POSITIVE,
    "system.length": _POSITIVE, "system.lengths": _POSITIVE, "system.cart_mass": _POSITIVE,
    "system.pole_mass": _POSITIVE, "system.half_length": _POSITIVE, "system.ell": _POSITIVE,
    "system.inertias": _POSITIVE, "system.inertia": _at_least(0), "system.d": _POSITIVE, "system.k": _POSITIVE,
    "system.stiffness": _POSITIVE, "system.a": _at_least(0), "system.damping": _at_least(0),
    "system.gamma1": _at_least(0), "system.gamma2": _at_least(0), "system.init_scale": _POSITIVE,
    "system.init_range": _at_least(0), "system.u_max": _at_least(0), "system.angle_range": _at_least(0),
    "system.phi_rate_range": _at_least(0), "system.theta_rate_range": _at_least(0),
    "system.spin_mean": ((lambda v: True), "a finite number"), "system.spin_scale": _at_least(0),
    "system.min_sin_theta": ((lambda v: 0 < v < 1), "in (0, 1)"),
}


def check_bounds(cfg: DictConfig) -> None:
    """Refuse a value outside its range in :data:`BOUNDS` (for a list, any entry), naming key, value and the range."""
    for key, (fits, allowed) in BOUNDS.items():
        value = OmegaConf.select(cfg, key, default=None)
        value = OmegaConf.to_container(value) if isinstance(value, ListConfig) else value
        every = " (every entry)" if isinstance(value, list) else ""
        for entry in value if isinstance(value, list) else [value]:
            if isinstance(entry, (str, bool)):  # a constructor annotation may not say (torch's lr: float | Tensor)
                raise ConfigError(f"{key}={value!r} has type {type(entry).__name__}; allowed: a number {allowed}{every}")
            if isinstance(entry, (int, float)) and not (math.isfinite(entry) and fits(entry)):
                raise ConfigError(f"{key}={value}; allowed: {allowed}{every}")


def _type_name(hint: Any) -> str:
    if hint is type(None):
        return "null"
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return " or ".join(_type_name(h) for h in typing.get_args(hint))
    if typing.get_origin(hint) in (list, tuple, Sequence):
        args = typing.get_args(hint)
        return f"a list of {_type_name(args[0])}" if args else "a list"
    return getattr(hint, "__name__", str(hint))


def _matches(value: Any, hint: Any) -> bool:
    """Whether a config value fits a constructor annotation; annotations it cannot judge pass."""
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        return any(_matches(value, h) for h in typing.get_args(hint))
    if origin in (list, tuple, Sequence):
        args = [a for a in typing.get_args(hint) if a is not Ellipsis]
        return isinstance(value, (list, tuple)) and all(_matches(v, args[0]) for v in value[: len(value) * bool(args)])
    if hint is type(None):
        return value is None
    if hint is bool:
        return isinstance(value, bool)
    if hint is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if hint is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if hint is str:
        return isinstance(value, str)
    return True


def check_types(values: dict, target: Any, key: str) -> None:
    """Refuse a value whose type does not fit ``target``'s constructor annotation, naming key, value and type."""
    fn = target.__init__ if inspect.isclass(target) else target
    try:
        hints = typing.get_type_hints(fn)
    except Exception:  # noqa: BLE001 - an annotation that cannot be resolved cannot be judged
        return
    for name, value in values.items():
        if name in hints and not _matches(value, hints[name]):
            raise ConfigError(f"{key}.{name}={value!r} has type {type(value).__name__}; allowed: "
                              f"{_type_name(hints[name])}".removeprefix("."))


def check_node_types(cfg: DictConfig, key: str) -> None:
    """Type-check the values of node ``cfg[key]`` against its ``_target_``'s constructor."""
    values = OmegaConf.to_container(OmegaConf.select(cfg, key), resolve=True)
    if not isinstance(values.get("_target_"), str):  # e.g. observation=none with a pixel system's keys
        return
    target = trust.locate(values["_target_"], key)  # checked by build() before: trusted, importable
    check_types({k: v for k, v in values.items() if not k.startswith("_")}, target, key)


def _top_level_keys(seed: int, horizon: int, test: bool, compile: bool) -> None:
    """The annotated top-level keys of ``train.yaml`` (for ``check_types``)."""


#: (group, key) of the folders loggers and callbacks write to, checked like the run's own.
FOLDER_KEYS = (("logger", "save_dir"), ("callbacks", "dirpath"))


def check_folders(cfg: DictConfig) -> None:
    """Create the run's output folders and the cache folder, refusing a path that is a file or unwritable."""
    out = Path(cfg.paths.output_dir)
    folders = [("paths.output_dir", out), ("paths.output_dir", out / "figures"),
               ("paths.cache_dir", Path(cfg.paths.cache_dir))]  # checkpoints/: the callbacks' dirpath, if any
    for group, leaf in FOLDER_KEYS:  # folders a logger or callback writes to
        for name, node in (cfg.get(group) or {}).items():
            if isinstance(node, DictConfig) and node.get(leaf) is not None:
                folders.append((f"{group}.{name}.{leaf}", Path(node[leaf])))
    for key, folder in folders:
        blocking = next((p for p in (folder, *folder.parents) if p.exists() and not p.is_dir()), None)
        if blocking is not None:
            raise ConfigError(f"{key}={str(folder)!r}: {str(blocking)!r} is a file, not a folder; "
                              f"allowed: a folder path (move the file or pick another)")
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise ConfigError(f"{key}={str(folder)!r} cannot be created ({err.strerror}); allowed: a writable folder") from None
        if not os.access(folder, os.W_OK | os.X_OK):
            raise ConfigError(f"{key}={str(folder)!r} is not writable; allowed: a writable folder")


def apply_presets(cfg: DictConfig, request: Request) -> None:
    """Drop the keys a preset set for any model (``preset_keys``, e.g. ``debug=fast``'s ``model.hidden``)
    from a node whose ``_target_``'s constructor does not take them; a key also set on the command line stays
    (and is refused where the node is built)."""
    for full in cfg.get("preset_keys") or ():
        node_key, _, name = str(full).rpartition(".")
        node = OmegaConf.select(cfg, node_key)
        target = trust.locate(str(node.get("_target_", "")), node_key) if isinstance(node, DictConfig) and name in node else None
        if target is None or full in request.overridden():
            continue
        params = inspect.signature(target).parameters
        if name not in params and not any(p.kind is p.VAR_KEYWORD for p in params.values()):
            with open_dict(node):
                del node[name]


def check_config(cfg: DictConfig, request: Request) -> None:
    """Reject types, sizes, budgets and folders that cannot work, naming the key and what is allowed."""
    apply_presets(cfg, request)
    from encons.data.datamodule import TrajectoryDataModule
    from encons.integrators import Integrator

    check_types({k: cfg.get(k) for k in ("seed", "horizon", "test", "compile") if k in cfg}, _top_level_keys, "")
    check_types(OmegaConf.to_container(cfg.data, resolve=True), TrajectoryDataModule, "data")
    for key in ("system", "model", "regulariser", "observation", "optimizer", "scheduler"):
        if cfg.get(key):
            check_node_types(cfg, key)
    check_types(OmegaConf.to_container(cfg.integrator, resolve=True), Integrator, "integrator")
    clip = cfg.trainer.get("gradient_clip_val")
    if clip is not None and not _matches(clip, float):
        raise ConfigError(f"trainer.gradient_clip_val={clip!r} has type {type(clip).__name__}; allowed: float or null")
    epochs = cfg.trainer.get("max_epochs")
    if epochs is not None and (not isinstance(epochs, int) or isinstance(epochs, bool) or epochs < 1):
        raise ConfigError(f"trainer.max_epochs={epochs!r}; allowed: an integer >= 1")
    check_bounds(cfg)
    if cfg.data.get("n_val") == 0 and str(cfg.optimized_metric).startswith("val/"):
        raise ConfigError(f"data.n_val=0 leaves no validation set for optimized_metric={cfg.optimized_metric}; "
                          f"allowed: data.n_val >= 1, or optimized_metric=train/loss")
    check_folders(cfg)


def objective_of(cfg: DictConfig) -> str:
    """The run's objective: ``cfg.objective``, or when null the model's default (its first)."""
    return cfg.objective or trust.locate(cfg.model._target_, "model").objectives[0]


def check_capabilities(cfg: DictConfig, cls: type[DynamicsModel], system: System, request: Request) -> None:
    """Refuse a model × system × objective × regulariser × integrator it does not support (the
    model's class attributes, ``encons.models.base``); ``request`` names the model as the user chose it
    and says whether the user overrode the integrator."""
    name = request.choices.get("model") or cls.__name__
    chart = cfg.model.get("chart") or getattr(cls, "default_chart", None) or system.base_chart
    if chart not in system.charts:
        raise ConfigError(f"model {cls.__name__} needs the '{chart}' chart, which system '{system.name}' "
                          f"lacks; allowed: a model for its charts {list(system.charts)}")
    if getattr(cls, "needs_constraints", False) and system.layout is None:
        raise ConfigError(f"model {cls.__name__} needs holonomic constraints, which system '{system.name}' "
                          f"does not declare; allowed: a model in generalised coordinates")
    objective = objective_of(cfg)
    if objective not in cls.objectives:
        raise ConfigError(f"objective={objective} does not apply to model={name}; allowed: {', '.join(cls.objectives)}")
    if cfg.get("compile") and (cls.discrete or cfg.get("regulariser")):
        reason = f"model={name} is discrete (no field)" if cls.discrete else \
            "the regularisers take Jacobians of the field by torch.func, which is not tested on a compiled one"
        raise ConfigError(f"compile=true compiles the model's vector field, and {reason}; allowed: compile=false")
    if cfg.get("regulariser") and cls.discrete:
        raise ConfigError(f"regulariser={cfg.regulariser._target_.rsplit('.', 1)[-1].lower()} needs a vector field "
                          f"and model={name} is discrete (it steps itself); allowed: regulariser=none")
    if system.n_controls and not cls.supports_controls:
        raise ConfigError(f"model={name} cannot take control inputs, and system '{system.name}' has "
                          f"{system.n_controls}; allowed: a model that supports controls (e.g. node, lnode, symo)")
    if cls.discrete:
        overridden = [o for o in request.overrides if o.lstrip("+~").startswith("integrator")]
        if overridden:
            raise ConfigError(f"{overridden[0]} does not apply to model={name}: a discrete model advances by its "
                              f"own step; allowed: no integrator override")
