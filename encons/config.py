"""Checks on a composed config, run before anything is built: one clear error per problem."""

from __future__ import annotations

import inspect
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from omegaconf import DictConfig, OmegaConf, open_dict

from encons import bounds, trust
from encons.errors import ConfigError

if TYPE_CHECKING:
    from encons.build import Request
    from encons.models.base import DynamicsModel
    from encons.systems.base import System


def check_node(cfg: DictConfig, key: str, target: Any = None) -> None:
    """Check the values of node ``cfg[key]`` (``""``: the top level) against the declarations of its
    ``_target_``'s constructor (or ``target``'s) and those of the functions that read it
    (``encons.bounds.DECLARED``), by ``encons.bounds.check``."""
    node = OmegaConf.select(cfg, key) if key else cfg
    if not isinstance(node, DictConfig):
        return
    declared = dict(bounds.DECLARED.get(key, {}))
    if key:
        values = OmegaConf.to_container(node, resolve=True)
        name = values.get("_target_")
        target = target or (trust.locate(name, key) if isinstance(name, str) else None)  # trusted: build() checked
        declared = {**(bounds.hints(target) if target is not None else {}), **declared}
    else:
        values = {k: node.get(k) for k in declared if k in node}
    bounds.check({k: v for k, v in values.items() if not k.startswith("_")}, declared, key)


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
    (and is refused where the node is built). ``preset_keys`` maps each group that sets presets to its keys
    (``{debug: [model.hidden, model.depth]}``), so that the groups' mappings merge where lists would
    replace each other (``experiment=paper debug=fast``); a list is one group's (a config saved before)."""
    presets = cfg.get("preset_keys") or {}
    for full in dict.fromkeys(k for keys in (presets.values() if isinstance(presets, DictConfig) else [presets])
                              for k in keys or ()):
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

    check_node(cfg, "")
    check_node(cfg, "data", TrajectoryDataModule)
    for key in ("system", "model", "regulariser", "observation", "optimizer", "scheduler", "integrator",
                "evaluation", "trainer"):
        if cfg.get(key):
            check_node(cfg, key)
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
