"""From overrides to objects, in one direction: compose → check → instantiate.

:func:`compose` is the one composition of ``conf/train.yaml`` and ``conf/benchmark.yaml``;
:func:`build` checks a composed config (targets first, then ``encons.config``'s checks) and
instantiates system → observation → model → data → LightningModule; :func:`build_trainer` the
Trainer with its loggers and callbacks. What the user asked for (group choices, command-line
overrides) travels in a :class:`Request`, never read from Hydra's process-global state here.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

from hydra.errors import InstantiationException
from omegaconf import DictConfig, OmegaConf, open_dict

from encons import attempts, trust
from encons.bounds import Count, Fraction, NonNegative, Positive, Range, Seed, declare
from encons.errors import ConfigError, EnconsError
from encons.paths import config_dir

if TYPE_CHECKING:
    from encons.data.datamodule import TrajectoryDataModule
    from encons.models.base import DynamicsModel
    from encons.models.observation import Observation
    from encons.module import TrainingModule
    from encons.systems.base import System


@dataclass(frozen=True)
class Request:
    """What the user asked for: Hydra's group choices (``model=symo``) and the command-line overrides;
    both empty for a config read back from a checkpoint."""

    choices: Mapping[str, str] = field(default_factory=dict)
    overrides: tuple[str, ...] = ()

    @classmethod
    def of(cls, cfg: DictConfig) -> Request:
        """The request a composed config carries in its ``hydra`` node (empty without one)."""
        hydra = cfg.get("hydra") if isinstance(cfg, DictConfig) else None
        if hydra is None:
            return cls()
        choices = {k: v for k, v in OmegaConf.to_container(hydra.runtime.choices).items() if isinstance(v, str)}
        return cls(choices, tuple(hydra.overrides.task))

    def overridden(self) -> set[str]:
        """The keys the overrides set (``+``/``~`` stripped)."""
        return {o.split("=", 1)[0].lstrip("+~") for o in self.overrides}


def compose(overrides: Sequence[str] = (), output_dir: str | Path | None = None,
            cache_dir: str | Path | None = None, config_name: str = "train") -> DictConfig:
    """``conf/<config_name>.yaml`` composed with ``overrides`` as the CLI would, with its ``hydra`` node.

    Its ``${hydra:...}`` values (e.g. ``name``) are resolved here, so a later compose in the same
    process cannot change them. ``output_dir`` defaults to Hydra's run folder.
    """
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.hydra_config import HydraConfig
    from hydra.errors import MissingConfigException

    from encons.errors import user_line

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
    return cfg


def _resolve_hydra_references(cfg: DictConfig) -> None:
    """Replace every ``${hydra:...}`` interpolation outside the ``hydra`` node by its value now."""
    def walk(node: Any, key: str) -> None:
        if isinstance(node, dict):
            for k, v in node.items():
                walk(v, f"{key}.{k}" if key else str(k))
        elif isinstance(node, str) and "${hydra:" in node:
            OmegaConf.update(cfg, key, OmegaConf.select(cfg, key), force_add=True)

    plain = OmegaConf.to_container(cfg, resolve=False)
    with open_dict(cfg):
        for top in [k for k in plain if k != "hydra"]:
            walk(plain[top], str(top))


def run_config(cfg: DictConfig) -> DictConfig:
    """The resolved run config without Hydra's own node: what a run is rebuilt from."""
    return OmegaConf.create(OmegaConf.to_container(
        OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"]), resolve=True))


def catalogue(group: str) -> list[str]:
    """The options of a config group, read from ``conf/<group>/*.yaml`` (e.g. ``catalogue("model")``).

    Files starting with ``_`` are bases that others inherit from, not options.
    """
    folder = Path(config_dir()) / group
    if not folder.is_dir():
        raise ConfigError(f"config group {group!r} does not exist; allowed: "
                          f"{', '.join(sorted(p.name for p in Path(config_dir()).iterdir() if p.is_dir()))}")
    return sorted(p.stem for p in folder.glob("*.yaml") if not p.name.startswith("_"))


def instantiate_node(cfg: DictConfig, key: str, request: Request = Request(), **kwargs: Any) -> Any:
    """``instantiate(cfg[key])`` with its values type-checked against the target's constructor, and any
    error the constructor raises turned into one ``ConfigError`` line naming the node (the keys the
    message names, else those the request overrides, else all).

    Hydra 1.4 re-raises the target's own exception (adding a ``full_key`` note) rather than an
    ``InstantiationException``, so both are caught here, at the one place configs become objects.
    """
    from hydra.utils import instantiate

    from encons.config import check_node

    node = OmegaConf.select(cfg, key)
    values = OmegaConf.to_container(node, resolve=True)
    check_node(cfg, key)
    try:
        with trust.whitelist():
            return instantiate(node, **kwargs)
    except EnconsError:
        raise
    except Exception as err:  # noqa: BLE001 - a constructor's own error is the user's config's doing
        cause = err.__cause__ if isinstance(err, InstantiationException) and err.__cause__ else err
        if isinstance(cause, EnconsError):
            raise cause from None
        message = str(cause).splitlines()[0] if str(cause) else type(cause).__name__
        given = {k: v for k, v in values.items() if not k.startswith("_") and not isinstance(v, dict)}
        named = ({k: v for k, v in given.items() if k.lower() in message.lower()}
                 or {k: v for k, v in given.items() if f"{key}.{k}" in request.overridden()} or given)
        shown = ", ".join(f"{key}.{k}={v}" for k, v in named.items())
        raise ConfigError(f"{shown or key}: {type(cause).__name__}: {message}; allowed: the values documented "
                          f"in conf/{key.split('.')[0]}/ for {values.get('_target_', '?')}") from None


def build_system(cfg: DictConfig, request: Request = Request()) -> System:
    """The system of ``cfg.system``."""
    return instantiate_node(cfg, "system", request)


def build_observation(cfg: DictConfig, system: System, request: Request = Request()) -> Observation:
    """The observation model of ``cfg.observation``: the identity for ``observation=none``, whose node has
    no ``_target_`` (keys a pixel system sets for its autoencoder, e.g. ``latent``, then do not apply)."""
    from encons.models.observation import Observation

    if not cfg.get("observation") or "_target_" not in cfg.observation:
        return Observation()
    return instantiate_node(cfg, "observation", request, system=system)


def build_model(cfg: DictConfig, system: System, observation: Observation | None = None,
                request: Request = Request()) -> DynamicsModel:
    """Instantiate ``cfg.model`` for ``system`` seen through ``observation`` (default: built from
    ``cfg.observation``) after checking that the (latent) system offers what it needs."""
    from encons.config import check_capabilities, objective_of

    observation = observation if observation is not None else build_observation(cfg, system, request)
    if observation.objectives is not None and objective_of(cfg) not in observation.objectives:
        raise ConfigError(f"objective={objective_of(cfg)} does not apply to observation="
                          f"{type(observation).__name__.lower()} (no true latent derivatives); allowed: "
                          f"{', '.join(observation.objectives)}")
    system = observation.latent_system(system)
    check_capabilities(cfg, trust.locate(cfg.model._target_, "model"), system, request)
    model = instantiate_node(cfg, "model", request, system=system)
    if cfg.get("compile"):
        model.compile()  # torch.compile of the module's call, i.e. the field, in place (nn.Module.compile)
    return model


@declare("", seed=Seed, horizon=Count, compile=bool, test=bool)  # ``test``: read by encons.runs.train
def build(cfg: DictConfig, request: Request | None = None) -> tuple[TrajectoryDataModule, TrainingModule]:
    """System → data → model → LightningModule from a composed config, seeded by ``cfg.seed``.

    Every ``_target_`` is checked against the trust list before anything is imported, then the
    config's types, ranges and combinations (``encons.config``), then the objects are built.
    """
    import lightning.pytorch as pl

    from encons import threads

    request = Request.of(cfg) if request is None else request
    check(cfg, request)
    _route_lightning_logs()
    threads.apply(cfg.get("threads"))  # before the data are simulated
    pl.seed_everything(cfg.seed, workers=True, verbose=False)
    return _instantiate(cfg, request)


def check(cfg: DictConfig, request: Request = Request()) -> None:
    """Every check of a composed config before anything is built: no key left ``???``, every target
    trusted (before any import), then ``encons.config``'s types, ranges and folders."""
    from encons.config import check_config

    task = OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"])
    missing = sorted(OmegaConf.missing_keys(task), key=lambda k: not _is_unset(task, k))  # "???" before what refers to it
    if missing:
        raise ConfigError(f"{missing[0]} has no value; allowed: give it one ({missing[0]}=...)")
    trust.check_targets(OmegaConf.to_container(run_config(cfg)))
    check_config(cfg, request)


def _instantiate(cfg: DictConfig, request: Request):
    from encons.config import objective_of
    from encons.data.datamodule import TrajectoryDataModule
    from encons.module import TrainingModule

    system = build_system(cfg, request)
    observation = build_observation(cfg, system, request)
    model = build_model(cfg, system, observation, request)
    objective = objective_of(cfg)
    data_cfg = {**OmegaConf.to_container(cfg.data, resolve=True), "objective": objective}
    data = TrajectoryDataModule(system, observation.data_chart(system, model.chart),
                                OmegaConf.to_container(cfg.system, resolve=True),
                                cache_dir=cfg.paths.cache_dir, **data_cfg)
    data.prepare_data()
    data.setup()
    observation.check_data(data.arrays["train"], f"the data of system '{system.name}'"
                           + (f" ({data.path})" if data.path else ""), data.chunk_len)
    test_steps = data.states["test"].shape[1] - 1
    if cfg.horizon > test_steps:
        raise ConfigError(f"horizon={cfg.horizon} exceeds the {test_steps} steps of a test trajectory; "
                          f"allowed: 1..{test_steps}")
    regulariser = instantiate_node(cfg, "regulariser", request) if cfg.get("regulariser") else None
    optimizer, scheduler = build_optimizer(cfg, model, request)
    module = TrainingModule(model, system, data.dt, instantiate_node(cfg, "integrator", request), optimizer,
                            scheduler, objective=objective, regulariser=regulariser, observation=observation,
                            horizon=cfg.horizon, model_name=cfg.get("model_name"),
                            evaluation=build_evaluation(cfg, request),
                            evaluators=build_evaluators(cfg, observation.identity, request),
                            recorded=attempts.record(cfg, model))
    return data, module


def build_evaluation(cfg: DictConfig, request: Request = Request()):
    """The run's ``evaluation`` node as an ``encons.evaluation.Evaluation`` (how test rollouts are
    integrated); a config saved before the node existed gets the default."""
    from encons.evaluation import Evaluation

    return instantiate_node(cfg, "evaluation", request) if cfg.get("evaluation") else Evaluation()


def build_evaluators(cfg: DictConfig, identity: bool = True, request: Request = Request()) -> dict:
    """The run's evaluators (``encons.evaluators``), name → object, from the ``evaluators`` node that
    ``conf/evaluators`` composes (``evaluators=[states,santos]``); a config saved before the node existed
    gets the one its test ran then (``states``, or ``pixels`` through an observation model: ``identity``
    false)."""
    from encons.evaluators import Pixels, States

    if "evaluators" not in cfg:
        return {"states": States()} if identity else {"pixels": Pixels()}
    return {name: instantiate_node(cfg, f"evaluators.{name}", request) for name in cfg.evaluators or {}}


@declare("optimizer", lr=Positive, weight_decay=NonNegative)
@declare("scheduler", patience=Annotated[int, Range(ge=0)], factor=Fraction, pct_start=Fraction)
def build_optimizer(cfg: DictConfig, model: DynamicsModel, request: Request = Request()):
    """The ``optimizer`` and ``scheduler`` partials (``conf/optimizer``, ``conf/scheduler``; the scheduler
    None when unset), each built once here on ``model``'s parameters so that a value its constructor
    refuses is one line now, not a traceback once training starts."""
    from encons.module import takes_total_steps

    optimizer = instantiate_node(cfg, "optimizer", request)
    instantiate_node(cfg, "optimizer", request, _partial_=False, params=model.parameters())
    if not cfg.get("scheduler"):
        return optimizer, None
    scheduler = instantiate_node(cfg, "scheduler", request)
    probe = {"total_steps": 100} if takes_total_steps(scheduler) else {}
    instantiate_node(cfg, "scheduler", request, _partial_=False, optimizer=optimizer(model.parameters()), **probe)
    return optimizer, scheduler


def _is_unset(cfg: DictConfig, key: str) -> bool:
    """Whether ``key`` itself is ``???`` (not an interpolation of a key that is)."""
    parent, _, leaf = key.rpartition(".")
    return OmegaConf.is_missing(OmegaConf.select(cfg, parent) if parent else cfg, leaf)


def _route_lightning_logs() -> None:
    """Under a configured root logger (Hydra's console + ``train.log``), Lightning's info lines go
    there only: drop the stderr handler ``import lightning`` adds to its package logger."""
    import logging

    if logging.getLogger().handlers:
        lightning = logging.getLogger("lightning")
        for handler in [h for h in lightning.handlers if type(h) is logging.StreamHandler]:
            lightning.removeHandler(handler)


@declare("trainer", max_epochs=Annotated[int, Range(ge=1, says="an integer >= 1")] | None, gradient_clip_val=NonNegative | None)
def build_trainer(cfg: DictConfig, request: Request = Request()):
    """The Lightning Trainer of ``cfg.trainer`` with the configured loggers and callbacks; every
    checkpoint it writes carries the resolved run config (``encons.checkpoints``) and is written
    atomically (``encons.lightning_io``); a test's results go to ``cfg.paths.output_dir``
    (``encons.callbacks.TestResults``)."""
    from encons.callbacks import ProgressBar, RunConfigInCheckpoints, TestResults
    from encons.compat import drop_wandb_anonymous
    from encons.lightning_io import AtomicCheckpointIO

    loggers = [instantiate_node(cfg, f"logger.{name}", request) for name in (cfg.get("logger") or {})]
    for lg in loggers:
        drop_wandb_anonymous(lg)
    callbacks = [instantiate_node(cfg, f"callbacks.{name}", request) for name in (cfg.get("callbacks") or {})]
    callbacks += [RunConfigInCheckpoints(run_config(cfg)), TestResults(cfg.paths.output_dir)]
    callbacks += [ProgressBar()] if cfg.trainer.get("enable_progress_bar", True) else []   # epochs from 1
    trainer = instantiate_node(cfg, "trainer", request, logger=loggers or False, callbacks=callbacks,
                               plugins=[AtomicCheckpointIO()])
    return trainer, loggers
