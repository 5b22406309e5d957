"""A run's life: train one model on one system, load a run back, evaluate it.

Each function goes one way: ``encons.training.build`` composes, ``encons.config.check.validate`` checks once,
``encons.training.build`` instantiates the checked value; Lightning trains and tests; ``encons.infra.checkpoints``
reads every checkpoint (``weights_only=True``). The attempt policy (``encons.training.attempts``) is applied
here and its facts passed down to ``build``.
"""

from __future__ import annotations

import logging
import os
import shlex
import shutil
import time
import warnings
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import cast

from omegaconf import DictConfig, OmegaConf

from encons.config.check import Checked, Request, validate
from encons.infra import checkpoints, compat
from encons.infra.errors import ConfigError, DivergenceError, Interrupted
from encons.infra.io import write_yaml
from encons.training import attempts, fitting
from encons.training.build import build, build_trainer
from encons.training.results import Ensemble, Run, member_folders, summarise

log = logging.getLogger(__name__)


@contextmanager
def log_file(path: Path) -> Iterator[None]:
    """The run's log in ``path`` (``train.log``) where nothing configured logging to a file (a script, a
    notebook, ``encons-evaluate``; Hydra's job logging writes it under the CLI), with upstream noise
    silenced (:func:`quiet_upstream`). With no handler at all, INFO records go to that file only."""
    compat.quiet_upstream()
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


def _best_checkpoint(trainer):
    """The checkpoint callback that monitors a metric and kept a file (the best-by-validation model)."""
    return next((cb for cb in trainer.checkpoint_callbacks if cb.monitor and cb.best_model_path), None)


def train(cfg: DictConfig | str | list[str], summary: bool = True, request: Request | None = None) -> Run | Ensemble:
    """Train one model on one system, then test the best-by-validation checkpoint (the one kept).

    Returns a :class:`Run` whose module holds the tested weights, whose ``metrics`` are every
    logged value as floats (``test/...`` of the tested checkpoint, ``best_epoch``, ``wall_time_s``)
    and whose ``run_dir`` holds ``config.yaml``, ``checkpoints/``, ``figures/``, ``test_metrics.json``
    and, under the CLI (Hydra's job logging), ``train.log``; under ``plain_solve`` also ``diverged_plain/`` where
    the plain inverse diverged and the run trained again with the guarded solve (``encons.training.attempts``).
    With no monitored checkpoint (``callbacks=null``) the last-epoch weights are tested.
    ``summary=False`` leaves the metrics table out of the console (it still goes to the log files).
    ``request`` (default: the one ``cfg``'s ``hydra`` node carries) names what the user chose.
    ``cfg`` may also be its overrides (``["model=hnn"]``, or one string), composed as ``encons.compose`` does.
    With ``seeds`` set, trains one member per seed in this process and returns an ``encons.training.results.Ensemble``.
    """
    from encons.infra.errors import EnconsError
    from encons.infra.progress import to_log_files

    if not isinstance(cfg, DictConfig):
        cfg = _composed(cfg)
    request = Request.of(cfg) if request is None else request
    os.environ.setdefault("WANDB_SILENT", "true")  # as the CLI: no wandb banner lines from Python either
    given = Path(cfg.paths.output_dir)
    try:
        with log_file(given / "train.log"), _into_resumed_folder(cfg, given):
            if cfg.get("seeds") is not None:  # one member per seed, in this process (encons.training.ensemble)
                from encons.training import ensemble

                return ensemble.train(cfg, summary, request)
            return _train(cfg, summary, request)
    except EnconsError as err:
        to_log_files(f"encons: error: {err}", logging.ERROR)  # the CLI prints the same line on stderr
        _prune(Path(cfg.paths.output_dir))
        raise


#: What a run folder holds before its run writes anything: Hydra's copy of the command and its log file
_BEFORE_THE_RUN = {".hydra", "train.log"}


@contextmanager
def _into_resumed_folder(cfg: DictConfig, given: Path) -> Iterator[None]:
    """``ckpt_path=last`` continues the interrupted run in its own folder: where the checkpoint it resumes lies in
    an earlier run's folder (the user did not name it by ``hydra.run.dir``), ``cfg.paths.output_dir`` becomes that
    folder and the log files follow it; this invocation's own folder, holding nothing but Hydra's copy of the
    command, is removed at the end (kept, with whatever it holds, when it holds more)."""
    if cfg.get("ckpt_path") != "last":
        yield
        return
    resumed = Path(checkpoints.resume_from(cfg) or given).parent.parent  # <run>/checkpoints/last.ckpt
    if resumed.resolve() == given.resolve():
        yield
        return
    cfg.paths.output_dir = str(resumed)
    compat.retarget_file_logs(given / "train.log", resumed / "train.log")  # they stay there: given is removed
    log.info("ckpt_path=last: continuing the run in its own folder %s (this command's %s is removed)", resumed, given)
    try:
        yield
    finally:
        if given.is_dir() and {p.name for p in given.iterdir()} <= _BEFORE_THE_RUN:
            shutil.rmtree(given, ignore_errors=True)


def _prune(run_dir: Path) -> None:
    """After a failed run: the empty folders made for it (checkpoints/, figures/, the run folder) removed;
    a folder that keeps a file (train.log, ending in the error line) says why it is there."""
    for folder in (run_dir / "checkpoints", run_dir / "figures", run_dir):
        if folder.is_dir() and not any(folder.iterdir()):
            folder.rmdir()


def _composed(overrides: object) -> DictConfig:
    """The config of ``overrides`` (a ``key=value`` string or a list of them), as ``encons.compose`` gives it."""
    from encons.training.build import compose

    items = [overrides] if isinstance(overrides, str) else overrides
    if not isinstance(items, (list, tuple)) or not all(isinstance(o, str) for o in items):
        raise ConfigError(
            f"cfg={overrides!r} has type {type(overrides).__name__}; allowed: a config from "
            f"encons.compose(...), or its overrides as key=value strings"
        )
    return compose(list(items))


def _train(cfg: DictConfig, summary: bool, request: Request | None) -> Run:
    """Validate the run once, then train its attempts (``encons.training.attempts``) until one does not diverge;
    the last one's divergence is the run's error."""
    started = time.perf_counter()
    checked = validate(cfg, request)
    planned = attempts.plan(cfg, checked.request, checked.model)
    derived = [checked if a.cfg is cfg else checked.derived(a.cfg) for a in planned]  # the policy's changes
    for attempt, attempt_checked in zip(planned[:-1], derived):
        try:
            return _attempt(attempt, attempt_checked, summary, started)
        except DivergenceError as err:
            aside = attempts.set_aside(Path(cfg.paths.output_dir))
            why = f"the plain inverse (model.guard=0) diverged first ({str(err).split(';')[0]}; its files: {aside})"
            log.warning("%s; training again from scratch at model.guard=%g", why, cfg.model.guard)
            planned[-1] = replace(planned[-1], why=why)
    return _attempt(planned[-1], derived[-1], summary, started)


def _attempt(attempt: attempts.Attempt, checked: Checked, summary: bool, started: float) -> Run:
    """One training of the run (``encons.training.attempts.Attempt``) from its checked config (the run's own, or the
    one the attempt policy derived from it), its time counted from ``started``."""
    import torch

    from encons.training.callbacks import resumed_seconds
    from encons.training.summary import print_summary

    cfg, request = checked.cfg, checked.request
    trainer, loggers = build_trainer(checked)  # before any data: an accelerator, logger or callback that cannot work
    data, module = build(checked, recorded=attempts.record(cfg, checked.model))
    resume = checkpoints.resume_from(cfg)
    if resume is not None:
        checkpoints.check_fits(module, resume)
        # resuming writes into the run's own checkpoints/ on purpose; Lightning warns of it at every resume
        warnings.filterwarnings("ignore", message=r"Checkpoint directory .* exists and is not empty")
    run_dir = Path(cfg.paths.output_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    config = checked.resolved.copy()
    write_yaml(run_dir / "config.yaml", config)
    for lg in loggers:
        lg.log_hyperparams(OmegaConf.to_container(config))
    tested = None
    try:
        fitting.fit(cfg, trainer, module, data, resume, request)
        before = resumed_seconds(trainer)  # now: testing a checkpoint restores the callbacks' state of that file
        results = {k: float(v) for k, v in trainer.callback_metrics.items()}
        best = _best_checkpoint(trainer)
        if best is not None:
            tested = Path(best.best_model_path)
            results[f"best/{best.monitor}"] = float(best.best_model_score)
            results["best_epoch"] = float(checkpoints.read(tested)["epoch"] + 1)  # from 1, as the log counts
        if cfg.test:
            trainer.test(
                module, datamodule=data, ckpt_path=str(tested) if tested else None, verbose=False, weights_only=True
            )
            if trainer.received_sigterm:  # Lightning finishes a one-batch test stage before it looks
                raise Interrupted(
                    f"SIGTERM during test; the trained checkpoints are complete, test them: "
                    f"python -m encons.evaluate {shlex.quote(str(run_dir))}"
                )
            results.update({f"test/{k}": v for k, v in module.test_metrics.items()})
        elif tested is not None:
            module.load_state_dict(checkpoints.read(tested)["state_dict"])
    finally:
        _finish_wandb(loggers)
    # this process's training and test, and the segments before the checkpoint it resumed from
    results["wall_time_s"] = time.perf_counter() - started + before
    results["threads"] = float(torch.get_num_threads())  # what wall_time_s ran on (encons.infra.threads)
    if trainer.is_global_zero:
        note = "; ".join(
            filter(
                None,
                (
                    _which(tested, results),
                    module.evaluation.describe(),
                    attempt.describe(),
                    horizon_note(module, data) if cfg.test else "",
                ),
            )
        )
        print_summary(module.run_title(), results, run_dir, note=note, console=summary)
    return Run(module, data, config, run_dir, tested, results, checked=checked)


def _which(ckpt: Path | None, results: dict[str, float]) -> str:
    if ckpt is None:
        return "tested: last-epoch weights (no monitored checkpoint)"
    epoch = f", epoch {int(results['best_epoch'])}" if "best_epoch" in results else ""
    return f"tested: best checkpoint by validation ({ckpt.name}{epoch})"


def _finish_wandb(loggers: list) -> None:
    if any(type(lg).__name__ == "WandbLogger" for lg in loggers):
        import wandb

        wandb.finish()


def load(path: str | Path, overrides: Iterable[str] = (), ckpt: str = "best") -> Run | Ensemble:
    """A run back from its folder (checkpoint ``ckpt``: best, last or a path) or from a ``.ckpt`` file; a seed
    ensemble's folder (or its ``last.ckpt``) gives an ``encons.training.results.Ensemble`` of its members: with
    ``ckpt=best`` each member's own best checkpoint, with ``last`` or the ensemble's ``.ckpt`` every member's
    weights from that one file.

    The config comes from the checkpoint itself (``encons_config``), else from ``config.yaml``
    beside ``checkpoints/``; ``overrides`` (``"data.test_steps=400"``) change it before building.
    Data are re-simulated from the config if the cache is gone. Results go to ``<run>/evaluation``.
    """
    path = Path(path)
    if path.is_dir() and (ensemble := _ensemble(path, overrides, ckpt)) is not None:
        return ensemble
    if path.is_file():
        ckpt_file, run_dir = path, path.parent.parent
    elif path.is_dir() and ((path / "checkpoints").is_dir() or (path / "config.yaml").is_file()):
        run_dir, ckpt_file = path, checkpoints.find(path, ckpt)
    else:
        raise ConfigError(
            f"{str(path)!r} is not a training run folder (no checkpoints/) or a .ckpt file; allowed: a run folder "
            f"that train wrote, or its .ckpt"
        )
    state = checkpoints.read(ckpt_file)
    if checkpoints.ENSEMBLE_KEY in state:  # an ensemble's own checkpoint: its members, each from its slice of the file
        found = member_folders(run_dir)
        if found is None:
            raise ConfigError(
                f"{str(ckpt_file)!r} is a seed ensemble's checkpoint, and {str(run_dir)!r} has no members.json; "
                f"allowed: the checkpoint inside the ensemble's folder that wrote it"
            )
        return _ensemble_from(run_dir, found, ckpt_file, state, overrides)
    return _run_from(run_dir, ckpt_file, state, overrides)


def _run_from(run_dir: Path, ckpt_file: Path, state: dict, overrides: Iterable[str]) -> Run:
    """The run of folder ``run_dir`` built from its config and given the weights of checkpoint ``state``."""
    if checkpoints.CONFIG_KEY in state:
        cfg = OmegaConf.create(checkpoints.current_targets(state[checkpoints.CONFIG_KEY]))
    elif (run_dir / "config.yaml").is_file():
        cfg = OmegaConf.create(
            checkpoints.current_targets(OmegaConf.to_container(OmegaConf.load(run_dir / "config.yaml")))
        )
    else:
        raise ConfigError(f"checkpoint {str(ckpt_file)!r} carries no config and has no config.yaml beside it")
    cfg = cast(DictConfig, OmegaConf.merge(cfg, _key_overrides(cfg, overrides)))  # two DictConfigs merge to one
    cfg.paths.output_dir = str(run_dir / "evaluation")
    cfg.logger, cfg.callbacks = None, None
    checked = validate(cfg)
    data, module = build(checked, recorded=attempts.record(cfg, checked.model))
    try:
        checkpoints.load_weights(module, state["state_dict"])
    except RuntimeError:
        raise ConfigError(
            f"overrides {list(overrides)} change the model, so the weights of {ckpt_file.name} no "
            f"longer fit; allowed: overrides of data.*, horizon, integrator.*, evaluation.*"
        ) from None
    module.eval()
    return Run(module, data, cfg, run_dir, ckpt_file, checked=checked)


def _ensemble(path: Path, overrides: Iterable[str], ckpt: str) -> Ensemble | None:
    """The seed ensemble of folder ``path``, its members loaded (None: ``path`` is not an ensemble's folder):
    ``best`` from each member's own best checkpoint, else from the ensemble's checkpoint ``ckpt``."""
    found = member_folders(path)
    if found is None:
        return None
    seeds, folders = found
    missing = [str(f) for f in folders if not f.is_dir()]
    if missing:
        raise ConfigError(
            f"{str(path)!r} is a seed ensemble whose member folder {missing[0]!r} is gone; allowed: "
            f"an ensemble folder with its members, or one member's folder"
        )
    if ckpt != "best":
        ckpt_file = checkpoints.find(path, ckpt)
        state = checkpoints.read(ckpt_file)
        if checkpoints.ENSEMBLE_KEY not in state:
            raise ConfigError(
                f"ckpt={ckpt}: {str(ckpt_file)!r} is not the checkpoint of the ensemble {str(path)!r}; allowed: best, "
                f"last, or a .ckpt the ensemble wrote"
            )
        return _ensemble_from(path, found, ckpt_file, state, overrides)
    members = cast("list[Run]", [load(f, overrides, ckpt) for f in folders])  # a member's folder holds one run
    return Ensemble(members, seeds, {}, {}, path)


def _ensemble_from(
    path: Path, found: tuple[list[int], list[Path]], ckpt_file: Path, state: dict, overrides: Iterable[str]
) -> Ensemble:
    """The ensemble of folder ``path`` (its seeds and member folders ``found``, ``member_folders``) with every
    member's weights from the ensemble's checkpoint ``state`` (its ``members.<k>.`` entries, which the stacked path
    keeps current: ``StackedEnsemble.on_save_checkpoint``); each member's config from its own folder."""
    seeds, folders = found
    saved = list(state[checkpoints.ENSEMBLE_KEY].get("seeds", seeds))
    if saved != list(seeds):
        raise ConfigError(
            f"{str(ckpt_file)!r} holds seeds {saved}, the ensemble folder {str(path)!r} seeds {list(seeds)}; "
            f"allowed: the checkpoint of this ensemble"
        )
    weights = state["state_dict"]
    members = []
    for k, folder in enumerate(folders):
        prefix = f"members.{k}."
        own = {name.removeprefix(prefix): value for name, value in weights.items() if name.startswith(prefix)}
        members.append(_run_from(folder, ckpt_file, {"state_dict": own}, overrides))
    return Ensemble(members, seeds, {}, {}, path)


def _key_overrides(cfg: DictConfig, overrides: Iterable[str]) -> DictConfig:
    """``key=value`` overrides of a saved run config; one that names a whole group (``model=hnn``) or is
    not ``key=value`` is refused: a saved config has no groups left to choose from."""
    overrides = list(overrides)
    for item in overrides:
        key, eq, _ = item.partition("=")
        if not eq or not key:
            raise ConfigError(f"{item!r} is not a key=value override; allowed: key=value (data.test_steps=400)")
        if isinstance(OmegaConf.select(cfg, key.lstrip("+")), DictConfig):
            raise ConfigError(
                f"{item}: {key} is a whole group of the saved run, which evaluation cannot swap; "
                f"allowed: overrides of its keys (data.test_steps=400, horizon=400, integrator.method=...)"
            )
    return OmegaConf.from_dotlist(overrides)


def _new_evaluation_folder(run_dir: Path) -> Path:
    """``<run>/evaluation``, or ``evaluation-2``, ``-3``, ... when an earlier evaluation holds metrics: a second
    evaluate (other overrides, another checkpoint) never overwrites the first one's."""
    out, k = run_dir / "evaluation", 1
    while (out / "test_metrics.json").exists():
        k += 1
        out = run_dir / f"evaluation-{k}"
    return out


def evaluate(run: Run | Ensemble | str | Path, overrides: Iterable[str] = (), ckpt: str = "best") -> dict[str, float]:
    """Test a run (a :class:`Run`, a run folder or a ``.ckpt``) on its test set; return ``test/...`` metrics. A
    seed ensemble (its folder, or an ``encons.training.results.Ensemble``) is tested member by member: the members' mean
    and spread (``_sd``, ``_min``, ``_max``).

    Overrides change the evaluation, e.g. ``data.test_steps=1000``: a longer test horizon. Metrics
    such as ``traj_rel_err`` sum over the first ``horizon`` steps; add ``horizon=1000`` to score
    the whole trajectory. Figures and ``test_metrics.json`` go to ``<run>/evaluation`` (``evaluation-2``, ...
    when an earlier evaluation is there).
    """
    from encons.training.summary import print_summary

    if isinstance(run, (str, Path)) or list(overrides):
        source = run.run_dir if isinstance(run, Ensemble) else run.checkpoint if isinstance(run, Run) else run
        if source is None:  # found by mypy: load(None) raised a TypeError here
            raise ConfigError(
                f"overrides {list(overrides)} rebuild the run from its checkpoint, and this run kept none (its "
                f"weights are in memory only); allowed: evaluate it without overrides, or a run that keeps checkpoints"
            )
        run = load(source, overrides, ckpt)
    if isinstance(run, Ensemble):
        return _evaluate_ensemble(run)
    config = run.config.copy()
    config.logger, config.callbacks = None, None
    out = _new_evaluation_folder(run.run_dir)
    config.paths.output_dir = str(out)
    with log_file(out / "evaluate.log"):
        trainer, _ = build_trainer(run.checked.derived(config) if run.checked is not None else validate(config))
        trainer.test(run.module, datamodule=run.data, verbose=False, weights_only=True)
    run.metrics = {f"test/{k}": v for k, v in run.module.test_metrics.items()}
    note = (
        f"tested: {run.checkpoint.name if run.checkpoint else 'in-memory weights'}; "
        f"{run.module.evaluation.describe()}; {horizon_note(run.module, run.data)}"
    )
    print_summary(run.module.run_title(), run.metrics, out, note=note)
    return run.metrics


def _evaluate_ensemble(ensemble: Ensemble) -> dict[str, float]:
    """Every member evaluated as a run of its own, then the members' mean, ``_sd``, ``_min`` and ``_max``,
    written to ``<ensemble>/evaluation`` (``-2``, ... beside earlier ones) and returned as ``test/...``."""
    from encons.infra.io import write_json
    from encons.training.summary import print_summary

    per_member = {seed: evaluate(member) for seed, member in zip(ensemble.seeds, ensemble.members)}
    metrics = summarise(per_member)
    out = _new_evaluation_folder(ensemble.run_dir)
    write_json(out / "test_metrics.json", {k.removeprefix("test/"): v for k, v in metrics.items()})
    shown = {k: v for k, v in metrics.items() if not k.endswith(("_min", "_max"))}
    print_summary(
        f"{ensemble.members[0].module.run_title()} × {len(ensemble.seeds)} seeds",
        shown,
        out,
        note=f"members: {', '.join(str(m.run_dir) for m in ensemble.members)}; each as its own evaluate",
    )
    ensemble.metrics = metrics
    return metrics


def horizon_note(module, data) -> str:
    """The scored horizon, said beside every summary: traj_rel_err sums the first ``horizon`` steps of each
    test window, traj_rel_err_window all of them."""
    steps = data.states["test"].shape[1] - 1
    if steps <= module.horizon:
        return f"traj_rel_err sums all {steps} steps of each test window (horizon={module.horizon})"
    return (
        f"traj_rel_err sums the first {module.horizon} of {steps} steps of each test window (horizon="
        f"{module.horizon}, the papers' protocol); traj_rel_err_window sums all {steps}"
    )
