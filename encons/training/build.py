"""From overrides to objects, in one direction: compose → validate → instantiate.

:func:`compose` is the one composition of ``conf/train.yaml`` and ``conf/benchmark.yaml`` (presets
applied there); ``encons.config.check.validate`` checks a composed config once and returns its
``Checked`` value; :func:`build` instantiates one, without checking or looking a target up again, system →
observation → model → data → LightningModule; :func:`build_trainer` the Trainer with its loggers and
callbacks. Every builder takes the ``Checked`` value only (``encons.build`` of the API validates a plain
config first). What the user asked for (group choices, command-line overrides) travels in the
``encons.config.check.Request`` it carries, never read from Hydra's process-global state here.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, cast

from hydra.errors import InstantiationException
from omegaconf import DictConfig, OmegaConf, open_dict

from encons.config.check import (
    Checked,
    Request,
    apply_presets,
    run_config,  # noqa: F401 - where scripts have imported it from
    validate,
)
from encons.infra.bounds import Count, Fraction, NonNegative, Positive, Range, Seed, declare
from encons.infra.errors import ConfigError, EnconsError
from encons.infra.paths import config_dir

if TYPE_CHECKING:
    from encons.data.datamodule import TrajectoryDataModule
    from encons.models.base import DynamicsModel
    from encons.models.observation import Observation
    from encons.systems.base import System
    from encons.training.module import TrainingModule


def compose(
    overrides: Sequence[str] = (),
    output_dir: str | Path | None = None,
    cache_dir: str | Path | None = None,
    config_name: str = "train",
) -> DictConfig:
    """``conf/<config_name>.yaml`` composed with ``overrides`` as the CLI would, with its ``hydra`` node.

    Its ``${hydra:...}`` values (e.g. ``name``) are resolved here, so a later compose in the same
    process cannot change them. ``output_dir`` defaults to Hydra's run folder.
    """
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.hydra_config import HydraConfig
    from hydra.errors import MissingConfigException

    from encons.infra import threads
    from encons.infra.errors import user_line

    threads.register()  # the parallel launcher's ${encons_threads:...}
    if isinstance(overrides, str):
        overrides = [overrides]
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=config_dir(), job_name=config_name):
        try:
            cfg = hydra_compose(config_name, overrides=list(overrides), return_hydra_config=True)
        except MissingConfigException as err:
            raise ConfigError(user_line(err)) from None
    HydraConfig.instance().set_config(cfg)  # ${hydra:...} resolves against it, just below
    with open_dict(cfg):
        if "paths" in cfg:
            cfg.paths.output_dir = str(output_dir if output_dir is not None else cfg.hydra.run.dir)
            if cache_dir is not None:
                cfg.paths.cache_dir = str(cache_dir)
    _resolve_hydra_references(cfg)
    apply_presets(cfg, Request.of(cfg))
    return cfg


def _resolve_hydra_references(cfg: DictConfig) -> None:
    """Replace every ``${hydra:...}`` interpolation outside the ``hydra`` node by its value now."""

    def walk(node: Any, key: str) -> None:
        if isinstance(node, dict):
            for k, v in node.items():
                walk(v, f"{key}.{k}" if key else str(k))
        elif isinstance(node, str) and "${hydra:" in node:
            OmegaConf.update(cfg, key, OmegaConf.select(cfg, key), force_add=True)

    plain = cast("dict[str, Any]", OmegaConf.to_container(cfg, resolve=False))  # a DictConfig's: a dict
    with open_dict(cfg):
        for top in [k for k in plain if k != "hydra"]:
            walk(plain[top], str(top))


def catalogue(group: str) -> list[str]:
    """The options of a config group, read from ``conf/<group>/*.yaml`` (e.g. ``catalogue("model")``).

    Files starting with ``_`` are bases that others inherit from, not options.
    """
    folder = Path(config_dir()) / group
    if not folder.is_dir():
        raise ConfigError(
            f"config group {group!r} does not exist; allowed: "
            f"{', '.join(sorted(p.name for p in Path(config_dir()).iterdir() if p.is_dir()))}"
        )
    return sorted(p.stem for p in folder.glob("*.yaml") if not p.name.startswith("_"))


def _checked(value: Any, builder: str) -> Checked:
    """``value`` if it passed ``encons.config.check.validate``; a plain config is a caller's mistake."""
    if not isinstance(value, Checked):
        raise TypeError(
            f"{builder} takes a Checked config (encons.config.check.validate(cfg)), not {type(value).__name__}; "
            f"encons.build and encons.build_trainer validate a plain one first"
        )
    return value


def instantiate_node(checked: Checked, key: str, **kwargs: Any) -> Any:
    """``instantiate(cfg[key])`` of a checked config (``encons.config.check.validate`` checked its values), any
    error the constructor raises turned into one ``ConfigError`` line naming the node (the keys the message
    names, else those the request overrides, else all).

    Hydra 1.4 re-raises the target's own exception (adding a ``full_key`` note) rather than an
    ``InstantiationException``, so both are caught here, at the one place configs become objects.
    """
    from hydra.utils import instantiate

    checked = _checked(checked, "instantiate_node")
    trusted, request = checked.trusted, checked.request
    node = OmegaConf.select(checked.cfg, key)
    values = cast("dict[str, Any]", OmegaConf.to_container(node, resolve=True))  # a DictConfig's: a dict
    try:
        return instantiate(node, _execution_whitelist_=list(trusted), **kwargs)  # Hydra refuses the rest
    except EnconsError:
        raise
    except Exception as err:  # noqa: BLE001 - a constructor's own error is the user's config's doing
        cause = err.__cause__ if isinstance(err, InstantiationException) and err.__cause__ else err
        if isinstance(cause, EnconsError):
            raise cause from None
        message = str(cause).splitlines()[0] if str(cause) else type(cause).__name__
        given = {k: v for k, v in values.items() if not k.startswith("_") and not isinstance(v, dict)}
        named = (
            {k: v for k, v in given.items() if k.lower() in message.lower()}
            or {k: v for k, v in given.items() if f"{key}.{k}" in request.overridden()}
            or given
        )
        shown = ", ".join(f"{key}.{k}={v}" for k, v in named.items())
        raise ConfigError(
            f"{shown or key}: {type(cause).__name__}: {message}; allowed: the values documented "
            f"in conf/{key.split('.')[0]}/ for {values.get('_target_', '?')}"
        ) from None


def build_system(checked: Checked) -> System:
    """The system of ``cfg.system``."""
    return instantiate_node(_checked(checked, "build_system"), "system")


def build_observation(checked: Checked, system: System) -> Observation:
    """The observation model of ``cfg.observation``: the identity for ``observation=none``, whose node has
    no ``_target_`` (keys a pixel system sets for its autoencoder, e.g. ``latent``, then do not apply)."""
    from encons.models.observation import Observation

    node = _checked(checked, "build_observation").cfg.get("observation")
    if not node or "_target_" not in node:
        return Observation()
    return instantiate_node(checked, "observation", system=system)


def build_model(checked: Checked, system: System, observation: Observation | None = None) -> DynamicsModel:
    """Instantiate ``cfg.model`` for ``system`` seen through ``observation`` (default: built from
    ``cfg.observation``) after checking what only the built system can say: that it offers what the
    model needs (``encons.config.check.check_fit``; the model's other capabilities were checked by
    ``validate``)."""
    from encons.config.check import check_fit

    checked = _checked(checked, "build_model")
    observation = observation if observation is not None else build_observation(checked, system)
    system = observation.latent_system(system)
    check_fit(checked.cfg, checked.model, system, checked.request)
    model = instantiate_node(checked, "model", system=system)
    if checked.cfg.get("compile"):
        model.compile()  # torch.compile of the module's call, i.e. the field, in place (nn.Module.compile)
    return model


@declare("", seed=Seed, horizon=Count, compile=bool, test=bool)  # ``test``: read by encons.training.runs.train
def build(checked: Checked, recorded: Mapping[str, float] | None = None) -> tuple[TrajectoryDataModule, TrainingModule]:
    """System → data → model → LightningModule from a checked config (``encons.config.check.validate``),
    seeded by ``cfg.seed``, its folders made. ``recorded``: facts of the run the test reports beside its
    scores (``encons.training.attempts.record``), passed down by the run."""
    import lightning.pytorch as pl

    from encons.infra import allocator, threads

    checked = _checked(checked, "build")
    make_folders(checked.cfg)
    _route_lightning_logs()
    threads.apply(checked.cfg.get("threads"))  # before the data are simulated
    allocator.keep_freed_memory()
    pl.seed_everything(checked.cfg.seed, workers=True, verbose=False)
    return _instantiate(checked, recorded)


def check(cfg: DictConfig, request: Request = Request()) -> Checked:
    """``encons.config.check.validate`` (kept under this name): every check of a composed config before anything is
    built."""
    return validate(cfg, request)


#: (group, key) of the folders loggers and callbacks write to, made and refused like the run's own.
FOLDER_KEYS = (("logger", "save_dir"), ("callbacks", "dirpath"))


def make_folders(cfg: DictConfig) -> None:
    """Create the run's output folders, the cache folder and those of its loggers and callbacks, refusing a
    path that is a file or unwritable."""
    out = Path(cfg.paths.output_dir)
    folders = [
        ("paths.output_dir", out),
        ("paths.output_dir", out / "figures"),
        ("paths.cache_dir", Path(cfg.paths.cache_dir)),
    ]  # checkpoints/: the callbacks' dirpath, if any
    for group, leaf in FOLDER_KEYS:  # folders a logger or callback writes to
        for name, node in (cfg.get(group) or {}).items():
            if isinstance(node, DictConfig) and node.get(leaf) is not None:
                folders.append((f"{group}.{name}.{leaf}", Path(node[leaf])))
    for key, folder in folders:
        blocking = next((p for p in (folder, *folder.parents) if p.exists() and not p.is_dir()), None)
        if blocking is not None:
            raise ConfigError(
                f"{key}={str(folder)!r}: {str(blocking)!r} is a file, not a folder; "
                f"allowed: a folder path (move the file or pick another)"
            )
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise ConfigError(
                f"{key}={str(folder)!r} cannot be created ({err.strerror}); allowed: a writable folder"
            ) from None
        if not os.access(folder, os.W_OK | os.X_OK):
            raise ConfigError(f"{key}={str(folder)!r} is not writable; allowed: a writable folder")


def _instantiate(checked: Checked, recorded: Mapping[str, float] | None):
    from encons.data.datamodule import TrajectoryDataModule
    from encons.training.module import TrainingModule

    cfg = checked.cfg
    system = build_system(checked)
    observation = build_observation(checked, system)
    model = build_model(checked, system, observation)
    objective = checked.objective
    data_cfg = {**cast(dict, OmegaConf.to_container(cfg.data, resolve=True)), "objective": objective}  # a dict
    data = TrajectoryDataModule(
        system,
        observation.data_chart(system, model.chart),
        cast(dict, OmegaConf.to_container(cfg.system, resolve=True)),  # a DictConfig's container: a dict
        cache_dir=cfg.paths.cache_dir,
        **data_cfg,
    )
    data.prepare_data()
    data.setup()
    observation.check_data(
        data.arrays["train"],
        f"the data of system '{system.name}'" + (f" ({data.path})" if data.path else ""),
        data.chunk_len,
    )
    test_steps = data.states["test"].shape[1] - 1
    if cfg.horizon > test_steps:
        raise ConfigError(
            f"horizon={cfg.horizon} exceeds the {test_steps} steps of a test trajectory; allowed: 1..{test_steps}"
        )
    regulariser = instantiate_node(checked, "regulariser") if cfg.get("regulariser") else None
    optimizer, scheduler = build_optimizer(checked, model)
    module = TrainingModule(
        model,
        system,
        data.dt,
        instantiate_node(checked, "integrator"),
        optimizer,
        scheduler,
        objective=objective,
        regulariser=regulariser,
        observation=observation,
        horizon=cfg.horizon,
        model_name=cfg.get("model_name"),
        evaluation=build_evaluation(checked),
        evaluators=build_evaluators(checked, observation.identity),
        recorded=recorded,
        validation=cfg.validation.criterion,
    )
    return data, module


def build_evaluation(checked: Checked):
    """The run's ``evaluation`` node as an ``encons.numerics.evaluation.Evaluation`` (how test rollouts are
    integrated); a config saved before the node existed gets the default."""
    from encons.numerics.evaluation import Evaluation

    return (
        instantiate_node(checked, "evaluation")
        if _checked(checked, "build_evaluation").cfg.get("evaluation")
        else Evaluation()
    )


def build_evaluators(checked: Checked, identity: bool = True) -> dict:
    """The run's evaluators (``encons.evaluators``), name → object, from the ``evaluators`` node that
    ``conf/evaluators`` composes (``evaluators=[states,santos]``); a config saved before the node existed
    gets the one its test ran then (``states``, or ``pixels`` through an observation model: ``identity``
    false)."""
    from encons.evaluators import Pixels, States

    cfg = _checked(checked, "build_evaluators").cfg
    if "evaluators" not in cfg:
        return {"states": States()} if identity else {"pixels": Pixels()}
    return {name: instantiate_node(checked, f"evaluators.{name}") for name in cfg.evaluators or {}}


@declare("optimizer", lr=Positive, weight_decay=NonNegative)
@declare("scheduler", patience=Annotated[int, Range(ge=0)], factor=Fraction, pct_start=Fraction)
def build_optimizer(checked: Checked, model: DynamicsModel):
    """The ``optimizer`` and ``scheduler`` partials (``conf/optimizer``, ``conf/scheduler``; the scheduler
    None when unset), each built once here on ``model``'s parameters so that a value its constructor
    refuses is one line now, not a traceback once training starts."""
    from encons.training.module import takes_total_steps

    optimizer = instantiate_node(checked, "optimizer")
    instantiate_node(checked, "optimizer", _partial_=False, params=model.parameters())
    if not _checked(checked, "build_optimizer").cfg.get("scheduler"):
        return optimizer, None
    scheduler = instantiate_node(checked, "scheduler")
    probe = {"total_steps": 100} if takes_total_steps(scheduler) else {}
    instantiate_node(checked, "scheduler", _partial_=False, optimizer=optimizer(model.parameters()), **probe)
    return optimizer, scheduler


def _route_lightning_logs() -> None:
    """Under a configured root logger (Hydra's console + ``train.log``), Lightning's info lines go
    there only: drop the stderr handler ``import lightning`` adds to its package logger."""
    import logging

    if logging.getLogger().handlers:
        lightning = logging.getLogger("lightning")
        for handler in [h for h in lightning.handlers if type(h) is logging.StreamHandler]:
            lightning.removeHandler(handler)


@declare("", figures=bool)
@declare(
    "trainer",
    max_epochs=Annotated[int, Range(ge=1, says="an integer >= 1")] | None,
    gradient_clip_val=NonNegative | None,
)
def build_trainer(checked: Checked):
    """The Lightning Trainer of ``cfg.trainer`` with the configured loggers and callbacks of a checked config
    (``encons.config.check.validate``), its folders made; every checkpoint it writes carries the resolved run config
    (``encons.infra.checkpoints``) and is written atomically (``encons.infra.lightning_io``); a test's results go to
    ``cfg.paths.output_dir`` (``encons.training.callbacks.TestResults``; its figures unless ``figures=false``)."""
    from encons.infra.compat import drop_wandb_anonymous
    from encons.infra.lightning_io import AtomicCheckpointIO
    from encons.training.callbacks import ProgressBar, RunConfigInCheckpoints, TestResults

    checked = _checked(checked, "build_trainer")
    cfg = checked.cfg
    make_folders(cfg)
    _route_lightning_logs()  # before the Trainer prints its device lines
    loggers = [instantiate_node(checked, f"logger.{name}") for name in (cfg.get("logger") or {})]
    for lg in loggers:
        drop_wandb_anonymous(lg)
    callbacks = [instantiate_node(checked, f"callbacks.{name}") for name in (cfg.get("callbacks") or {})]
    callbacks += [RunConfigInCheckpoints(checked.resolved), TestResults(cfg.paths.output_dir, cfg.get("figures", True))]
    callbacks += [ProgressBar()] if cfg.trainer.get("enable_progress_bar", True) else []  # epochs from 1
    none: dict[str, Any] = (
        {"limit_val_batches": 0} if cfg.validation.criterion == "none" else {}
    )  # validation.criterion=none
    trainer = instantiate_node(
        checked, "trainer", logger=loggers or False, callbacks=callbacks, plugins=[AtomicCheckpointIO()], **none
    )
    return trainer, loggers
