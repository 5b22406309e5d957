"""Checks on a composed config, run before anything is built: one clear error per problem."""

from __future__ import annotations

import importlib
import inspect
import math
import os
import types
import typing
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from hydra.errors import InstantiationException
from hydra.utils import get_class, instantiate
from omegaconf import DictConfig, OmegaConf, open_dict

from encons.errors import ConfigError, EnconsError
from encons.models.base import DynamicsModel
from encons.models.observation import Observation
from encons.paths import config_dir
from encons.systems.base import System


def _at_least(low: float) -> tuple[Any, str]:
    return (lambda v: v >= low), f">= {low}"


_POSITIVE = ((lambda v: v > 0), "> 0")
_COUNT = ((lambda v: v >= 1), "a positive integer")
_SEED = ((lambda v: 0 <= v < 2**32), "0..2**32-1 (numpy's seed range)")

#: Ranges of numeric keys, checked after their types (a key absent from the config is skipped);
#: every value must also be finite.
BOUNDS: dict[str, tuple[Any, str]] = {
    "seed": _SEED, "data.seed": _SEED, "horizon": _at_least(1),
    "data.dt": _POSITIVE, "data.noise": _at_least(0), "data.n_val": _at_least(0),
    "optim.lr": _POSITIVE, "optim.weight_decay": _at_least(0), "optim.patience": _at_least(0),
    "optim.factor": ((lambda v: 0 < v < 1), "in (0, 1)"),
    "regulariser.weight": _at_least(0), "integrator.rtol": _POSITIVE, "integrator.atol": _POSITIVE,
    "evaluation.rtol": _POSITIVE, "evaluation.atol": _POSITIVE, "evaluation.substeps": _COUNT,
    "evaluation.vpt_threshold": _POSITIVE,
    "model.hidden": _COUNT, "model.depth": _COUNT, "trainer.gradient_clip_val": _at_least(0),
    "observation.latent": _at_least(2), "observation.stack": _COUNT, "observation.hidden": _COUNT,
    "observation.depth": _COUNT, "observation.weight_reconstruction": _at_least(0),
    "observation.weight_prediction": _at_least(0), "observation.weight_velocity": _at_least(0),
    "system.frame_size": _at_least(4), "system.rate_scale": _at_least(0),
}


def check_bounds(cfg: DictConfig) -> None:
    """Refuse a value outside its range in :data:`BOUNDS`, naming key, value and the range."""
    for key, (fits, allowed) in BOUNDS.items():
        value = OmegaConf.select(cfg, key, default=None)
        if value is None or isinstance(value, bool) or not isinstance(value, (int, float)):
            continue
        if not (math.isfinite(value) and fits(value)):
            raise ConfigError(f"{key}={value}; allowed: {allowed}")


def compose_train(overrides: list[str], output_dir: str | Path, cache_dir: str | Path | None = None) -> DictConfig:
    """Compose ``train.yaml`` from Python as the CLI would, writing outputs to ``output_dir``."""
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=config_dir(), job_name="train"):
        cfg = compose("train", overrides=list(overrides), return_hydra_config=True)
    HydraConfig.instance().set_config(cfg)
    with open_dict(cfg):
        cfg.paths.output_dir = str(output_dir)
        if cache_dir is not None:
            cfg.paths.cache_dir = str(cache_dir)
    return cfg


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


def locate(target: str) -> Any:
    """The object ``package.module.Name[.attr]`` names (importing its module, as instantiate will), or
    None. A module that exists but fails on one of its own imports raises: its traceback helps the user."""
    parts = target.split(".")
    for split in range(len(parts) - 1, 0, -1):
        module = ".".join(parts[:split])
        try:
            obj = importlib.import_module(module)
        except ModuleNotFoundError as err:
            if err.name is None or not (module == err.name or module.startswith(f"{err.name}.")):
                raise
            continue
        try:
            for name in parts[split:]:
                obj = getattr(obj, name)
        except AttributeError:
            return None
        return obj
    return None


def check_node_types(cfg: DictConfig, key: str) -> None:
    """Type-check the values of node ``cfg[key]`` against its ``_target_``'s constructor (if importable:
    an unimportable target is reported where it is instantiated)."""
    values = OmegaConf.to_container(OmegaConf.select(cfg, key), resolve=True)
    target = locate(str(values.get("_target_", "")))  # not hydra's get_class, which logs errors of its own
    if target is None:  # reported where the config's targets are checked (encons.api.check_targets)
        return
    check_types({k: v for k, v in values.items() if not k.startswith("_")}, target, key)


def instantiate_node(cfg: DictConfig, key: str, **kwargs: Any) -> Any:
    """``instantiate(cfg[key])`` with its values type-checked against the target's constructor, and any
    error the constructor raises turned into one ``ConfigError`` line naming the node.

    Hydra 1.4 re-raises the target's own exception (adding a ``full_key`` note) rather than an
    ``InstantiationException``, so both are caught here, at the one place configs become objects.
    """
    node = OmegaConf.select(cfg, key)
    values = OmegaConf.to_container(node, resolve=True)
    check_node_types(cfg, key)
    try:
        return instantiate(node, **kwargs)
    except EnconsError:
        raise
    except Exception as err:  # noqa: BLE001 - a constructor's own error is the user's config's doing
        cause = err.__cause__ if isinstance(err, InstantiationException) and err.__cause__ else err
        if isinstance(cause, EnconsError):
            raise cause from None
        message = str(cause).splitlines()[0] if str(cause) else type(cause).__name__
        given = {k: v for k, v in values.items() if not k.startswith("_") and not isinstance(v, dict)}
        named = ({k: v for k, v in given.items() if k.lower() in message.lower()}  # the keys it names,
                 or {k: v for k, v in given.items() if f"{key}.{k}" in _overridden()} or given)  # or the user set
        shown = ", ".join(f"{key}.{k}={v}" for k, v in named.items())
        raise ConfigError(f"{shown or key}: {type(cause).__name__}: {message}; allowed: the values documented "
                          f"in conf/{key.split('.')[0]}/ for {values.get('_target_', '?')}") from None


def _overridden() -> set[str]:
    """The keys this run's command line overrides (empty outside Hydra)."""
    if not HydraConfig.initialized():
        return set()
    return {o.split("=", 1)[0].lstrip("+~") for o in HydraConfig.get().overrides.task}


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


def apply_presets(cfg: DictConfig) -> None:
    """Drop the keys a preset set for any model (``preset_keys``, e.g. ``debug=fast``'s ``model.hidden``)
    from a node whose ``_target_``'s constructor does not take them; a key also set on the command line stays
    (and is refused where the node is built)."""
    for full in cfg.get("preset_keys") or ():
        node_key, _, name = str(full).rpartition(".")
        node = OmegaConf.select(cfg, node_key)
        target = locate(str(node.get("_target_", ""))) if isinstance(node, DictConfig) and name in node else None
        if target is None or full in _overridden():
            continue
        params = inspect.signature(target).parameters
        if name not in params and not any(p.kind is p.VAR_KEYWORD for p in params.values()):
            with open_dict(node):
                del node[name]


def check_config(cfg: DictConfig) -> None:
    """Reject types, sizes, budgets and folders that cannot work, naming the key and what is allowed."""
    apply_presets(cfg)
    from encons.data.datamodule import TrajectoryDataModule
    from encons.integrators import Integrator

    from encons.module import DynamicsModule

    check_types({k: cfg.get(k) for k in ("seed", "horizon", "test", "compile") if k in cfg}, _top_level_keys, "")
    check_types(OmegaConf.to_container(cfg.data, resolve=True), TrajectoryDataModule, "data")
    check_types(OmegaConf.to_container(cfg.optim, resolve=True), DynamicsModule, "optim")
    for key in ("system", "model", "regulariser", "observation"):
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


def build_system(cfg: DictConfig) -> System:
    """The system of ``cfg.system``."""
    return instantiate_node(cfg, "system")


def build_observation(cfg: DictConfig, system: System) -> Observation:
    """The observation model of ``cfg.observation``: the identity for ``observation=none``, whose node has
    no ``_target_`` (keys a pixel system sets for its autoencoder, e.g. ``latent``, then do not apply)."""
    if not cfg.get("observation") or "_target_" not in cfg.observation:
        return Observation()
    return instantiate_node(cfg, "observation", system=system)


def build_model(cfg: DictConfig, system: System, observation: Observation | None = None) -> DynamicsModel:
    """Instantiate ``cfg.model`` for ``system`` seen through ``observation`` (default: built from
    ``cfg.observation``) after checking that the (latent) system offers what it needs."""
    observation = observation if observation is not None else build_observation(cfg, system)
    if observation.objectives is not None and objective_of(cfg) not in observation.objectives:
        raise ConfigError(f"objective={objective_of(cfg)} does not apply to observation="
                          f"{type(observation).__name__.lower()} (no true latent derivatives); allowed: "
                          f"{', '.join(observation.objectives)}")
    system = observation.latent_system(system)
    cls = get_class(cfg.model._target_)
    chart = cfg.model.get("chart") or getattr(cls, "default_chart", None) or system.base_chart
    model_name = cfg.model._target_.rsplit(".", 1)[-1]
    if chart not in system.charts:
        raise ConfigError(f"model {model_name} needs the '{chart}' chart, which system '{system.name}' "
                          f"lacks; allowed: a model for its charts {list(system.charts)}")
    if getattr(cls, "needs_constraints", False) and system.layout is None:
        raise ConfigError(f"model {model_name} needs holonomic constraints, which system '{system.name}' "
                          f"does not declare; allowed: a model in generalised coordinates")
    check_capabilities(cfg, cls, system)
    model = instantiate_node(cfg, "model", system=system)
    if cfg.get("compile"):
        model.compile()  # torch.compile of the module's call, i.e. the field, in place (nn.Module.compile)
    return model


def objective_of(cfg: DictConfig) -> str:
    """The run's objective: ``cfg.objective``, or when null the model's default (its first)."""
    return cfg.objective or get_class(cfg.model._target_).objectives[0]


def check_capabilities(cfg: DictConfig, cls: type[DynamicsModel], system: System) -> None:
    """Refuse a model × system × objective × regulariser × integrator it does not support (the
    model's class attributes, ``encons.models.base``)."""
    name = HydraConfig.get().runtime.choices.get("model") if HydraConfig.initialized() else None
    name = name or cls.__name__
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
    if cls.discrete and HydraConfig.initialized():
        overridden = [o for o in HydraConfig.get().overrides.task if o.lstrip("+~").startswith("integrator")]
        if overridden:
            raise ConfigError(f"{overridden[0]} does not apply to model={name}: a discrete model advances by its "
                              f"own step; allowed: no integrator override")


RESUME_KEYS = ("system", "model", "data", "integrator", "regulariser", "objective", "optim", "seed")


def resolve_checkpoint(cfg: DictConfig) -> str | None:
    """The checkpoint to resume from: ``cfg.ckpt_path``, or for ``last`` the newest ``last.ckpt`` among
    the earlier runs beside this one whose saved config (system, model, data, integrator, regulariser,
    objective, optim, seed) matches this run's; the training budget and paths may differ."""
    if cfg.ckpt_path != "last":
        if cfg.ckpt_path is not None and not Path(cfg.ckpt_path).is_file():
            raise ConfigError(f"ckpt_path={cfg.ckpt_path!r} does not exist; allowed: a .ckpt file, last or null")
        return cfg.ckpt_path
    runs = Path(cfg.paths.output_dir).parent
    found = sorted(runs.glob("*/checkpoints/last.ckpt"), key=lambda p: p.stat().st_mtime, reverse=True)
    if not found:
        raise ConfigError(f"ckpt_path=last: no earlier run of '{cfg.name}' has a checkpoint under {runs}; "
                          f"allowed: a .ckpt file, or null to start afresh")
    differences = []
    for path in found:
        diff = checkpoint_difference(cfg, path)
        if diff is None:
            return str(path)
        differences.append(f"{path.parent.parent.name} has {diff}")
    raise ConfigError(f"ckpt_path=last: no earlier run under {runs} has this run's config (newest: {differences[0]}); "
                      f"allowed: the same system/model/data/optim config, ckpt_path=PATH, or null")


def checkpoint_difference(cfg: DictConfig, path: Path) -> str | None:
    """None when the checkpoint at ``path`` was trained with ``cfg``'s ``RESUME_KEYS``, else the first
    difference as ``key=saved where this run has value``."""
    import torch

    mine = OmegaConf.to_container(OmegaConf.masked_copy(cfg, [k for k in RESUME_KEYS if k in cfg]), resolve=True)
    saved = torch.load(path, map_location="cpu", weights_only=False, mmap=True).get("encons_config") or {}
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


def check_checkpoint(module: Any, path: str) -> None:
    """Refuse a checkpoint whose parameters do not fit ``module`` (another model or size), naming the first."""
    import torch

    try:
        saved = torch.load(path, map_location="cpu", weights_only=False, mmap=True)["state_dict"]
    except Exception as err:  # noqa: BLE001 - any unreadable file is the same user error
        raise ConfigError(f"ckpt_path={path!r} is not a readable Lightning checkpoint ({type(err).__name__}); "
                          f"allowed: a .ckpt written by encons") from None
    own = module.state_dict()
    for name in sorted(set(saved) | set(own)):
        shapes = [tuple(d[name].shape) if name in d else None for d in (saved, own)]
        if shapes[0] != shapes[1]:
            said = ["absent" if s is None else f"shape {s}" for s in shapes]
            raise ConfigError(f"ckpt_path={path!r}: parameter {name} is {said[0]} in the checkpoint and {said[1]} "
                              f"in this model; allowed: a checkpoint of the same model config (model.*)")