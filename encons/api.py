"""The Python API: compose a config, build, train, load a run back, evaluate it, roll a model out.

    import encons
    cfg = encons.compose("model=hnn_angle", "system=pendulum1", "debug=fast")
    run = encons.train(cfg)              # Run: trained module (best checkpoint), metrics, run folder
    again = encons.load(run.run_dir)     # from the checkpoint alone: it carries its config
    encons.evaluate(again)               # the same test metrics, to the digit

The CLI (``encons.train``), ``encons.evaluate`` and ``encons.benchmark`` are thin wrappers of
these functions. Lightning and torch are imported on first use, not at import.
"""

from __future__ import annotations

import logging
import os
import re
import shlex
import time
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from omegaconf import DictConfig, OmegaConf, open_dict

from encons import threads
from encons.errors import ConfigError
from encons.paths import config_dir

if TYPE_CHECKING:
    from encons.integrators import rollout
    from encons.data.datamodule import TrajectoryDataModule
    from encons.module import DynamicsModule

__all__ = ["Run", "compose", "build", "train", "load", "evaluate", "rollout", "catalogue"]

#: Targets a config may instantiate (Hydra 1.4 execution whitelist). Add your own packages with
#: ``ENCONS_TRUSTED_TARGETS=mypkg.*,other.Class`` (comma-separated); configs are never trusted to widen it.
TRUSTED_TARGETS = ("encons.*", "lightning.pytorch.*", "optuna.pruners.*", "optuna.samplers.*")
CONFIG_KEY = "encons_config"  # where a checkpoint carries its resolved run config


def __getattr__(name: str):  # ``rollout`` re-exported without importing torch at ``import encons.api``
    if name == "rollout":
        from encons.integrators import rollout

        return rollout
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


@dataclass
class Run:
    """A trained or loaded run: the module (holding the weights of ``checkpoint``), its data and config."""

    module: DynamicsModule
    data: TrajectoryDataModule
    config: DictConfig
    run_dir: Path
    checkpoint: Path | None = None     # None: the in-memory weights (no checkpoint was kept)
    metrics: dict[str, float] = field(default_factory=dict)

    @property
    def model(self):
        """The trained ``DynamicsModel`` (roll it out with ``encons.rollout``)."""
        return self.module.model


class _DropTips(logging.Filter):
    """Drops Lightning's advertising tips ("💡 Tip: ... try installing litlogger")."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith("💡")


_DROP_TIPS = _DropTips()  # one instance, so that adding it again is a no-op


def quiet_upstream() -> None:
    """Silence upstream messages a user cannot act on: Lightning's tips, and Lightning 2.6's own
    deprecation warning about torch 2.13's pytree ``LeafSpec``. Lightning's info lines (devices,
    stop reason) go to the log (``train.log`` under the CLI), not to stderr."""
    import warnings

    warnings.filterwarnings("ignore", message=r".*isinstance\(treespec, LeafSpec\)")
    warnings.filterwarnings("ignore", message="The dirpath has changed from")  # a resume: see RunCheckpoints
    for name in ("lightning.pytorch.utilities.rank_zero", "lightning.fabric.utilities.rank_zero"):
        logging.getLogger(name).addFilter(_DROP_TIPS)  # the loggers rank_zero_info writes to


@contextmanager
def log_file(path: Path) -> Iterator[None]:
    """The run's log in ``path`` (``train.log``) where nothing configured logging to a file (a script, a
    notebook, ``encons-evaluate``; Hydra's job logging writes it under the CLI), with upstream noise
    silenced (:func:`quiet_upstream`). With no handler at all, INFO records go to that file only."""
    quiet_upstream()
    root = logging.getLogger()
    if any(isinstance(h, logging.FileHandler) for h in root.handlers):
        yield
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    handler = logging.FileHandler(path)
    handler.setFormatter(logging.Formatter("[%(asctime)s][%(name)s][%(levelname)s] - %(message)s"))
    level, bare = root.level, not root.handlers
    root.addHandler(handler)
    if bare:  # nothing else listens, so INFO cannot reach a console the user set up
        root.setLevel(logging.INFO)
    try:
        yield
    finally:
        root.removeHandler(handler)
        handler.close()
        root.setLevel(level)


def _route_lightning_logs() -> None:
    """Under a configured root logger (Hydra's console + ``train.log``), Lightning's info lines go
    there only: drop the stderr handler ``import lightning`` adds to its package logger."""
    import lightning.pytorch  # noqa: F401 - adds that handler on first import

    if logging.getLogger().handlers:
        lightning = logging.getLogger("lightning")
        for handler in [h for h in lightning.handlers if type(h) is logging.StreamHandler]:
            lightning.removeHandler(handler)


def _callable_module(name: str, function) -> None:
    """Make module ``name`` call ``function``: ``encons.train`` / ``encons.evaluate`` are both CLI
    modules and API functions, and importing a submodule replaces the package attribute."""
    import sys
    import types

    class CallableModule(types.ModuleType):
        def __call__(self, *args, **kwargs):
            return function(*args, **kwargs)

    sys.modules[name].__class__ = CallableModule


def trusted_targets() -> tuple[str, ...]:
    """The execution whitelist: encons, Lightning, and ``ENCONS_TRUSTED_TARGETS`` from the environment."""
    extra = [t.strip() for t in os.environ.get("ENCONS_TRUSTED_TARGETS", "").split(",") if t.strip()]
    return (*TRUSTED_TARGETS, *extra)


def _is_trusted(target: str, trusted: tuple[str, ...]) -> bool:
    """Hydra's rule: an exact name, or a package prefix ending in ``.*``."""
    return any(target.startswith(p[:-1]) if p.endswith(".*") else target == p for p in trusted)


def _importable(target: str) -> bool:
    """Whether ``package.module.Name[.attr]`` names an object (importing its module, as instantiate will)."""
    from encons.config import locate

    return locate(target) is not None


def check_targets(cfg: DictConfig) -> None:
    """Refuse any ``_target_`` outside :func:`trusted_targets` or not importable, naming its key."""
    trusted = trusted_targets()

    def walk(node: Any, key: str) -> None:
        if isinstance(node, Mapping):
            target = node.get("_target_")
            if isinstance(target, str) and not _is_trusted(target, trusted):
                raise ConfigError(f"{key}._target_={target!r} is not a trusted target; allowed: "
                                  f"{', '.join(trusted)} (trust your package with ENCONS_TRUSTED_TARGETS=yourpkg.*)")
            if isinstance(target, str) and not _importable(target):
                raise ConfigError(f"{key}._target_={target!r} cannot be imported; allowed: an importable "
                                  f"module.Class (your own package on PYTHONPATH)")
            for k, v in node.items():
                walk(v, f"{key}.{k}" if key else str(k))
        elif isinstance(node, list):
            for i, v in enumerate(node):
                walk(v, f"{key}[{i}]")

    walk(OmegaConf.to_container(cfg, resolve=False), "")


def catalogue(group: str) -> list[str]:
    """The options of a config group, read from ``conf/<group>/*.yaml`` (e.g. ``catalogue("model")``).

    Files starting with ``_`` are bases that others inherit from, not options.
    """
    folder = Path(config_dir()) / group
    if not folder.is_dir():
        raise ConfigError(f"config group {group!r} does not exist; allowed: "
                          f"{', '.join(sorted(p.name for p in Path(config_dir()).iterdir() if p.is_dir()))}")
    return sorted(p.stem for p in folder.glob("*.yaml") if not p.name.startswith("_"))


def compose(*overrides: str, output_dir: str | Path | None = None, cache_dir: str | Path | None = None) -> DictConfig:
    """The run config the CLI would compose from ``overrides`` (``"model=hnn"``, ``"trainer.max_epochs=5"``).

    ``output_dir`` defaults to the CLI's run folder (``outputs/<system>-<model>/<time>``).
    """
    from encons.config import compose_train

    cfg = compose_train(list(overrides), output_dir or "unset", cache_dir)
    if output_dir is None:
        with open_dict(cfg):
            cfg.paths.output_dir = str(OmegaConf.select(cfg, "hydra.run.dir"))
    return cfg


def run_config(cfg: DictConfig) -> DictConfig:
    """The resolved run config without Hydra's own node: what a run is rebuilt from."""
    return OmegaConf.create(OmegaConf.to_container(
        OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"]), resolve=True))


def build(cfg: DictConfig) -> tuple[TrajectoryDataModule, DynamicsModule]:
    """System → data → model → LightningModule from a composed config, seeded by ``cfg.seed``."""
    import lightning.pytorch as pl
    from hydra.utils import execution_whitelist

    _route_lightning_logs()
    from encons.config import build_model, build_observation, build_system, check_config, instantiate_node, objective_of
    from encons.data.datamodule import TrajectoryDataModule
    from encons.module import DynamicsModule

    check_config(cfg)
    check_targets(run_config(cfg))
    threads.apply(cfg.get("threads"))  # before the data are simulated
    pl.seed_everything(cfg.seed, workers=True, verbose=False)
    with execution_whitelist(trusted_targets()):
        system = build_system(cfg)
        observation = build_observation(cfg, system)
        model = build_model(cfg, system, observation)
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
        regulariser = instantiate_node(cfg, "regulariser") if cfg.get("regulariser") else None
        module = DynamicsModule(model, system, data.dt, instantiate_node(cfg, "integrator"), objective=objective,
                                regulariser=regulariser, observation=observation, horizon=cfg.horizon,
                                output_dir=cfg.paths.output_dir, model_name=cfg.get("model_name"),
                                evaluation=evaluation_of(cfg), **cfg.optim)
    return data, module


def evaluation_of(cfg: DictConfig):
    """The run's ``evaluation`` node as an ``encons.evaluation.Evaluation``; a config saved before the
    node existed gets the default."""
    from encons.config import instantiate_node
    from encons.evaluation import Evaluation

    return instantiate_node(cfg, "evaluation") if cfg.get("evaluation") else Evaluation()


def build_trainer(cfg: DictConfig):
    """The Lightning Trainer of ``cfg.trainer`` with the configured loggers and callbacks; every
    checkpoint it writes carries the resolved run config (see :func:`load`)."""
    from hydra.utils import execution_whitelist

    from encons.config import instantiate_node

    with execution_whitelist(trusted_targets()):
        loggers = [instantiate_node(cfg, f"logger.{name}") for name in (cfg.get("logger") or {})]
        for lg in loggers:  # Lightning 2.6 passes anonymous=None, which wandb 0.31 warns about on every run
            if getattr(lg, "_wandb_init", {}).get("anonymous", False) is None:
                del lg._wandb_init["anonymous"]
        callbacks = [instantiate_node(cfg, f"callbacks.{name}") for name in (cfg.get("callbacks") or {})]
        callbacks.append(_config_in_checkpoints(run_config(cfg)))
        trainer = instantiate_node(cfg, "trainer", logger=loggers or False, callbacks=callbacks)
    return trainer, loggers


def _config_in_checkpoints(config: DictConfig):
    from lightning.pytorch.callbacks import Callback

    class RunCheckpoints(Callback):
        """Stores the resolved run config in every checkpoint under ``encons_config``; on a resume
        into a new run folder, carries the earlier run's best checkpoint over so that the best is
        chosen among all epochs (Lightning keeps only its path when the folder changes)."""

        def on_save_checkpoint(self, trainer, pl_module, checkpoint: dict) -> None:
            checkpoint[CONFIG_KEY] = OmegaConf.to_container(config)

        def on_train_start(self, trainer, pl_module) -> None:
            best = next((cb for cb in trainer.checkpoint_callbacks if cb.monitor), None)
            if trainer.ckpt_path is None or best is None:
                return
            import shutil

            import torch

            state = torch.load(trainer.ckpt_path, map_location="cpu", weights_only=True)["callbacks"]
            state = state.get(best.state_key, {})
            old = Path(state.get("best_model_path") or "")
            if state.get("dirpath") == best.dirpath or not old.is_file() or state.get("best_model_score") is None:
                return
            new = Path(best.dirpath) / old.name
            if trainer.is_global_zero:
                new.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(old, new)
            trainer.strategy.barrier()
            best.best_model_path = best.kth_best_model_path = str(new)
            best.best_model_score = best.kth_value = state["best_model_score"]
            best.best_k_models = {str(new): state["best_model_score"]}

    return RunCheckpoints()


def _best_checkpoint(trainer):
    """The checkpoint callback that monitors a metric and kept a file (the best-by-validation model)."""
    return next((cb for cb in trainer.checkpoint_callbacks if cb.monitor and cb.best_model_path), None)


def train(cfg: DictConfig, summary: bool = True) -> Run:
    """Train one model on one system, then test the best-by-validation checkpoint (the one kept).

    Returns a :class:`Run` whose module holds the tested weights, whose ``metrics`` are every
    logged value as floats (``test/...`` of the tested checkpoint, ``best_epoch``, ``wall_time_s``)
    and whose ``run_dir`` holds ``config.yaml``, ``checkpoints/``, ``figures/``, ``test_metrics.json``
    and, under the CLI (Hydra's job logging), ``train.log``.
    With no monitored checkpoint (``callbacks=null``) the last-epoch weights are tested.
    ``summary=False`` leaves the metrics table out of the console (it still goes to the log files).
    """
    from encons.errors import EnconsError
    from encons.report import to_log_files

    try:
        with log_file(Path(cfg.paths.output_dir) / "train.log"):
            return _train(cfg, summary)
    except EnconsError as err:
        to_log_files(f"encons: error: {err}", logging.ERROR)  # the CLI prints the same line on stderr
        raise


def _train(cfg: DictConfig, summary: bool) -> Run:
    import torch

    from encons.config import check_checkpoint, check_config, resolve_checkpoint
    from encons.errors import Interrupted
    from encons.report import print_summary

    started = time.perf_counter()
    check_config(cfg)
    _route_lightning_logs()  # before the Trainer prints its device lines
    trainer, loggers = build_trainer(cfg)  # before any data: an accelerator, logger or callback that cannot work
    data, module = build(cfg)
    resume = resolve_checkpoint(cfg)
    if resume is not None:
        check_checkpoint(module, resume)
    run_dir = Path(cfg.paths.output_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    config = run_config(cfg)
    OmegaConf.save(config, run_dir / "config.yaml")
    for lg in loggers:
        lg.log_hyperparams(OmegaConf.to_container(config))
    tested = None
    try:
        _fit(cfg, trainer, module, data, resume)
        results = {k: float(v) for k, v in trainer.callback_metrics.items()}
        best = _best_checkpoint(trainer)
        if best is not None:
            tested = Path(best.best_model_path)
            results[f"best/{best.monitor}"] = float(best.best_model_score)
            results["best_epoch"] = float(torch.load(tested, map_location="cpu", weights_only=True)["epoch"])
        if cfg.test:
            trainer.test(module, datamodule=data, ckpt_path=str(tested) if tested else None, verbose=False)
            if trainer.received_sigterm:  # Lightning finishes a one-batch test stage before it looks
                raise Interrupted(f"SIGTERM during test; the trained checkpoints are complete, test them: "
                                  f"python -m encons.evaluate {shlex.quote(str(run_dir))}")
            results.update({f"test/{k}": v for k, v in module.test_metrics.items()})
        elif tested is not None:
            module.load_state_dict(torch.load(tested, map_location="cpu", weights_only=True)["state_dict"])
    finally:
        _finish_wandb(loggers)
    results["wall_time_s"] = time.perf_counter() - started
    results["threads"] = float(torch.get_num_threads())  # what wall_time_s ran on (encons.threads)
    if trainer.is_global_zero:
        print_summary(module.run_title(), results, run_dir, note=f"{_which(tested, results)}; {module.evaluation.describe()}",
                      console=summary)
    return Run(module, data, config, run_dir, tested, results)


def _fit(cfg: DictConfig, trainer, module, data, resume: str | None) -> None:
    """``trainer.fit``, with a monitored metric the module never logs named as the user's key, and
    SIGTERM (Lightning stops after the epoch, with a ``SystemExit`` of status 0) as :class:`Interrupted`."""
    from lightning.fabric.utilities.exceptions import MisconfigurationException
    from lightning.pytorch.utilities.exceptions import SIGTERMException

    from encons.errors import Interrupted

    try:
        trainer.fit(module, datamodule=data, ckpt_path=resume)
    except SIGTERMException:
        raise Interrupted(_resume_line(cfg, trainer.current_epoch)) from None
    except MisconfigurationException as err:
        logged = re.search(r"could not find the monitored key in the returned metrics: \[([^]]*)\]", str(err))
        if logged is None:
            raise
        names = [n.strip(" '") for n in logged.group(1).split(",") if "/" in n]
        raise ConfigError(f"optimized_metric={cfg.optimized_metric!r} is not a metric this run logs; allowed: "
                          f"{', '.join(names)}") from None


def _resume_line(cfg: DictConfig, epoch: int) -> str:
    """What an interrupted fit says: where it stopped and the command that continues it in the same folder."""
    from hydra.core.hydra_config import HydraConfig

    run_dir = Path(cfg.paths.output_dir)
    last = run_dir / "checkpoints" / "last.ckpt"
    given = list(HydraConfig.get().overrides.task) if HydraConfig.initialized() else []
    kept = [o for o in given if not o.lstrip("+~").startswith(("ckpt_path=", "hydra.run.dir="))]
    if not last.is_file():
        return f"SIGTERM during fit, epoch {epoch}, before the first checkpoint; start again: " + \
            shlex.join(["python", "-m", "encons.train", *given])
    return (f"SIGTERM during fit, epoch {epoch} (checkpoints/last.ckpt holds the last whole epoch); resume: "
            + shlex.join(["python", "-m", "encons.train", *kept, f"ckpt_path={last}", f"hydra.run.dir={run_dir}"]))


def _which(ckpt: Path | None, results: dict[str, float]) -> str:
    if ckpt is None:
        return "tested: last-epoch weights (no monitored checkpoint)"
    epoch = f", epoch {int(results['best_epoch'])}" if "best_epoch" in results else ""
    return f"tested: best checkpoint by validation ({ckpt.name}{epoch})"


def _finish_wandb(loggers: list) -> None:
    if any(type(lg).__name__ == "WandbLogger" for lg in loggers):
        import wandb

        wandb.finish()


def find_checkpoint(run_dir: Path, which: str = "best") -> Path:
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


def load(path: str | Path, overrides: Iterable[str] = (), ckpt: str = "best") -> Run:
    """A run back from its folder (checkpoint ``ckpt``: best, last or a path) or from a ``.ckpt`` file.

    The config comes from the checkpoint itself (``encons_config``), else from ``config.yaml``
    beside ``checkpoints/``; ``overrides`` (``"data.test_steps=400"``) change it before building.
    Data are re-simulated from the config if the cache is gone. Results go to ``<run>/evaluation``.
    """
    import torch

    path = Path(path)
    if path.is_file():
        ckpt_file, run_dir = path, path.parent.parent
    elif path.is_dir() and ((path / "checkpoints").is_dir() or (path / "config.yaml").is_file()):
        run_dir, ckpt_file = path, find_checkpoint(path, ckpt)
    else:
        raise ConfigError(f"{str(path)!r} is not a training run folder (no checkpoints/) or a .ckpt file; allowed: a run folder that train wrote, or its .ckpt")
    try:
        state = torch.load(ckpt_file, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises several types for a file that is not a checkpoint
        raise ConfigError(f"ckpt={str(ckpt_file)!r} is not a readable checkpoint ({type(err).__name__})") from None
    if CONFIG_KEY in state:
        cfg = OmegaConf.create(state[CONFIG_KEY])
    elif (run_dir / "config.yaml").is_file():
        cfg = OmegaConf.load(run_dir / "config.yaml")
    else:
        raise ConfigError(f"checkpoint {str(ckpt_file)!r} carries no config and has no config.yaml beside it")
    cfg = OmegaConf.merge(cfg, OmegaConf.from_dotlist(list(overrides)))
    cfg.paths.output_dir = str(run_dir / "evaluation")
    cfg.logger, cfg.callbacks = None, None
    data, module = build(cfg)
    try:
        module.load_state_dict(state["state_dict"])
    except RuntimeError:
        raise ConfigError(f"overrides {list(overrides)} change the model, so the weights of {ckpt_file.name} no "
                          f"longer fit; allowed: overrides of data.*, horizon, integrator.*, evaluation.*") from None
    module.eval()
    return Run(module, data, cfg, run_dir, ckpt_file)


def evaluate(run: Run | str | Path, overrides: Iterable[str] = (), ckpt: str = "best") -> dict[str, float]:
    """Test a run (a :class:`Run`, a run folder or a ``.ckpt``) on its test set; return ``test/...`` metrics.

    Overrides change the evaluation, e.g. ``data.test_steps=1000``: a longer test horizon. Metrics
    such as ``traj_rel_err`` sum over the first ``horizon`` steps; add ``horizon=1000`` to score
    the whole trajectory. Figures and ``test_metrics.json`` go to ``<run>/evaluation``.
    """
    from encons.report import print_summary

    if not isinstance(run, Run) or list(overrides):
        run = load(run.checkpoint if isinstance(run, Run) else run, overrides, ckpt)
    config = run.config.copy()
    config.logger, config.callbacks = None, None
    run.module.output_dir = run.run_dir / "evaluation"
    with log_file(run.module.output_dir / "evaluate.log"):
        _route_lightning_logs()
        trainer, _ = build_trainer(config)
        trainer.test(run.module, datamodule=run.data, verbose=False)
    run.metrics = {f"test/{k}": v for k, v in run.module.test_metrics.items()}
    note = f"tested: {run.checkpoint.name if run.checkpoint else 'in-memory weights'}; {run.module.evaluation.describe()}"
    steps = run.data.states["test"].shape[1] - 1
    if steps > run.module.horizon:
        note += (f"; traj_rel_err sums the first {run.module.horizon} of {steps} test steps "
                 f"(add horizon={steps} to score the whole trajectory)")
    print_summary(run.module.run_title(), run.metrics, run.module.output_dir, note=note)
    return run.metrics
