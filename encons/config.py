"""Checks on a composed config, run before anything is built: one clear error per problem."""

from __future__ import annotations

from pathlib import Path

from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from hydra.errors import InstantiationException
from hydra.utils import get_class, instantiate
from omegaconf import DictConfig, open_dict

from encons.errors import ConfigError
from encons.models.base import DynamicsModel
from encons.paths import config_dir
from encons.systems.base import System

POSITIVE_MODEL_KEYS = ("hidden", "depth")


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


def check_config(cfg: DictConfig) -> None:
    """Reject sizes and budgets that cannot work, naming the key and what is allowed."""
    for key in POSITIVE_MODEL_KEYS:
        value = cfg.model.get(key)
        if value is not None and value < 1:
            raise ConfigError(f"model.{key}={value} must be a positive integer")
    if cfg.trainer.get("max_epochs") is not None and cfg.trainer.max_epochs < 1:
        raise ConfigError(f"trainer.max_epochs={cfg.trainer.max_epochs} must be >= 1")
    if cfg.horizon < 1:
        raise ConfigError(f"horizon={cfg.horizon} must be >= 1")


def build_system(cfg: DictConfig) -> System:
    try:
        return instantiate(cfg.system)
    except InstantiationException as err:
        cause = err.__cause__
        if isinstance(cause, (ConfigError, ValueError)) or type(cause).__name__ == "DataError":
            raise cause from None
        raise


def build_model(cfg: DictConfig, system: System) -> DynamicsModel:
    """Instantiate ``cfg.model`` for ``system`` after checking that the system offers what it needs."""
    cls = get_class(cfg.model._target_)
    chart = cfg.model.get("chart") or getattr(cls, "default_chart", None) or system.base_chart
    model_name = cfg.model._target_.rsplit(".", 1)[-1]
    if chart not in system.charts:
        raise ConfigError(f"model {model_name} needs the '{chart}' chart, which system '{system.name}' "
                          f"lacks (it offers {list(system.charts)}); pick a model for those charts")
    if getattr(cls, "needs_constraints", False) and system.layout is None:
        raise ConfigError(f"model {model_name} needs holonomic constraints, which system '{system.name}' "
                          f"does not declare; use a model in generalised coordinates")
    check_capabilities(cfg, cls, system)
    try:
        return instantiate(cfg.model, system=system)
    except InstantiationException as err:
        if isinstance(err.__cause__, (ConfigError, ValueError)):
            raise ConfigError(str(err.__cause__)) from None
        raise


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
    if cfg.get("regulariser") and cls.discrete:
        raise ConfigError(f"regulariser={cfg.regulariser._target_.rsplit('.', 1)[-1].lower()} needs a vector field, "
                          f"and model={name} is discrete (it steps itself); allowed: regulariser=none")
    if system.n_controls and not cls.supports_controls:
        raise ConfigError(f"model={name} cannot take control inputs, and system '{system.name}' has "
                          f"{system.n_controls}; allowed: a model that supports controls (e.g. node, lnode, symo)")
    if cls.discrete and HydraConfig.initialized():
        overridden = [o for o in HydraConfig.get().overrides.task if o.lstrip("+~").startswith("integrator")]
        if overridden:
            raise ConfigError(f"{overridden[0]} does not apply to model={name}: a discrete model advances by its "
                              f"own step; allowed: no integrator override")


def resolve_checkpoint(cfg: DictConfig) -> str | None:
    """``ckpt_path=last``: the newest ``last.ckpt`` among earlier runs of this ``name``."""
    if cfg.ckpt_path != "last":
        if cfg.ckpt_path is not None and not Path(cfg.ckpt_path).is_file():
            raise ConfigError(f"ckpt_path={cfg.ckpt_path!r} does not exist; give a .ckpt file or 'last'")
        return cfg.ckpt_path
    runs = Path(cfg.paths.output_dir).parent
    found = sorted(runs.glob("*/checkpoints/last.ckpt"), key=lambda p: p.stat().st_mtime)
    if not found:
        raise ConfigError(f"ckpt_path=last: no earlier run of '{cfg.name}' has a checkpoint under {runs}")
    return str(found[-1])
