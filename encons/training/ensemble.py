"""Seed ensembles: ``seeds=[0,1,2]`` trains one member per seed in one process, each the run ``seed=k`` would be.

Member ``k`` is built exactly as the separate run ``seed=k`` (``encons.training.build.build``: the same initial
weights); every member sees the same batches, because the data seed (``data.seed``) is shared. Each
member keeps its own optimiser and schedule (``MemberOptimizers``: one optimiser per member, stepped as
one), its own gradient clipping, its own validation metrics (logged as ``seed<k>/val/...``), its own best
checkpoint (``<member dir>/checkpoints/best-epochNNNN.ckpt``, a normal single-seed checkpoint that
``encons.load`` / ``encons.evaluate`` read) and its own test (``<member dir>/test_metrics.json``). A member
whose loss turns non-finite is reported diverged and left out from then on; the others go on.

Two paths compute the members' losses (``EnsembleModule.path``):

- ``stacked``: the members' networks (and observation models: the pixel models' autoencoders) as one stacked model
  (``encons.training.stacked``: the ensemble dimension written into the layers, or ``vmap`` over the member axis,
  folded into the batch axis), one forward and one backward for all members; for the models and settings
  ``encons.training.stacked.why_not`` accepts;
- ``loop``: each member's own ``training_step`` in turn (one backward of their sum) — every model, every
  objective, regulariser, observation and schedule, e.g. ``ReduceLROnPlateau`` on a member's own validation.

The ensemble's ``test_metrics.json`` (in the run folder) holds, per test metric, the mean over the members
that did not diverge and its ``_sd`` (sample std), ``_min`` and ``_max``, with ``members`` and ``diverged``.
"""

from __future__ import annotations

import copy
import logging
import os
import time
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import lightning.pytorch as pl
import torch
from omegaconf import DictConfig, OmegaConf, open_dict

from encons.infra import checkpoints
from encons.infra.errors import ConfigError
from encons.training import stacked as stacking
from encons.training.callbacks import MemberCheckpoints, resumed_seconds
from encons.training.members import EnsembleModule, StackedEnsemble
from encons.training.results import MEMBERS_FILE, Ensemble, Run, spread_line, summarise

if TYPE_CHECKING:
    from encons.config.check import Checked, Request

log = logging.getLogger(__name__)


def member_config(cfg: DictConfig, seed: int, output_dir: Path) -> DictConfig:
    """The config of the separate run ``seed=seed`` writing to ``output_dir``: what member ``seed`` is."""
    member = copy.deepcopy(cfg)
    with open_dict(member):
        member.seed = seed
        member.seeds = None
        member.paths.output_dir = str(output_dir)
        for node in (member.get("callbacks") or {}).values():
            if isinstance(node, DictConfig) and "dirpath" in node:
                node.dirpath = str(output_dir / "checkpoints")
        for node in (member.get("logger") or {}).values():
            if isinstance(node, DictConfig) and "save_dir" in node:
                node.save_dir = str(output_dir)
    return member


def _checkpointers(cfg: DictConfig, targets: Mapping[str, Any]) -> dict[str, DictConfig]:
    """The callbacks of ``cfg`` that are Lightning ``ModelCheckpoint``s, by class (encons'
    ``BestCheckpoint`` is one)."""
    from lightning.pytorch.callbacks import ModelCheckpoint

    return {
        name: node
        for name, node in (cfg.get("callbacks") or {}).items()
        if isinstance(node, DictConfig)
        and isinstance(cls := targets.get(str(node.get("_target_"))), type)
        and issubclass(cls, ModelCheckpoint)
    }


def _monitor(cfg: DictConfig, targets: Mapping[str, Any]) -> tuple[str, str] | None:
    """The monitored metric and mode of the run's best-checkpoint callback (None: no monitored checkpoint)."""
    for node in _checkpointers(cfg, targets).values():
        if node.get("monitor"):
            return str(node.monitor), str(node.get("mode", "min"))
    return None


def train(
    cfg: DictConfig,
    summary: bool,
    request: Request,
    member_dir: Callable[[int], Path] | None = None,
    stacked: bool | None = None,
) -> Ensemble:
    """Train the ensemble ``cfg.seeds`` of ``cfg`` (see the module docstring); member ``k`` writes to
    ``member_dir(k)`` (default ``<run>/seed<k>``) and is returned as a :class:`~encons.training.results.Run`.
    ``stacked``: None picks the stacked path where ``encons.training.stacked.why_not`` and the first batch allow it;
    False forces the loop."""
    from encons.config.check import run_config, validate
    from encons.infra.io import write_json, write_yaml
    from encons.training.build import build, build_trainer
    from encons.training.fitting import fit

    started = time.perf_counter()
    # the one validation pass (the seeds and what an ensemble cannot be: encons.config.check.check_ensemble);
    # the members differ from it in seed and folders only
    checked = validate(cfg, request)
    seeds = list(cfg.seeds)
    run_dir = Path(cfg.paths.output_dir)
    dirs = [member_dir(s) if member_dir else run_dir / f"seed{s}" for s in seeds]
    configs = [member_config(cfg, s, d) for s, d in zip(seeds, dirs)]
    ens_cfg = copy.deepcopy(cfg)
    with open_dict(ens_cfg):  # the members keep their own best checkpoints (MemberCheckpoints), the ensemble its last
        best = [k for k, node in _checkpointers(cfg, checked.targets).items() if node.get("monitor")]
        ens_cfg.callbacks = {k: v for k, v in (cfg.get("callbacks") or {}).items() if k not in best}
        ens_cfg.trainer.gradient_clip_val = None
        ens_cfg.trainer.pop("gradient_clip_algorithm", None)
    trainer, loggers = build_trainer(checked.derived(ens_cfg))
    resume = checkpoints.resume_from(cfg)
    if resume is not None:
        saved_state = checkpoints.read(resume, "ckpt_path").get(checkpoints.ENSEMBLE_KEY)
        if saved_state is None:
            raise ConfigError(
                f"ckpt_path={resume} is not a seed ensemble's checkpoint (a single run's, or a member's "
                f"best weights); allowed: ckpt_path=last, or the ensemble's checkpoints/last.ckpt"
            )
        stacked = saved_state["path"] if stacked is None else stacked  # the path its checkpoint was written on
    built = [build(checked.derived(c)) for c in configs]
    data, members = built[0][0], [m for _, m in built]
    if len({str(d.cache_file) for d, _ in built}) > 1:
        raise ConfigError("the members' data differ (data.* depends on seed); allowed: a fixed data.seed with seeds")
    saved = [run_config(c) for c in configs]
    for d, c in zip(dirs, saved):
        d.mkdir(parents=True, exist_ok=True)
        write_yaml(d / "config.yaml", c)
    write_yaml(run_dir / "config.yaml", checked.resolved)
    write_json(run_dir / MEMBERS_FILE, {"seeds": seeds, "members": [os.path.relpath(d, run_dir) for d in dirs]})
    for lg in loggers:
        lg.log_hyperparams(OmegaConf.to_container(checked.resolved))
    module = _module(cfg, members, seeds, data, stacked)
    if resume is not None:
        checkpoints.check_fits(module, resume)
    monitor = _monitor(cfg, checked.targets)
    if monitor is not None:
        plain = [cast(dict, OmegaConf.to_container(c)) for c in saved]  # a DictConfig's container: a dict
        trainer.callbacks.append(MemberCheckpoints(dirs, plain, *monitor))
        keeper = trainer.callbacks[-1]
    else:
        keeper = None
    if resume is not None:  # resuming writes into the run's own checkpoints/ on purpose
        warnings.filterwarnings("ignore", message=r"Checkpoint directory .* exists and is not empty")
    log.info(
        "ensemble of %d members (seeds %s), path: %s%s",
        len(seeds),
        seeds,
        module.path,
        f"; resumed from {resume}" if resume else "",
    )
    try:
        fit(cfg, trainer, module, data, resume, request)
    finally:
        if any(type(lg).__name__ == "WandbLogger" for lg in loggers):
            import wandb

            wandb.finish()
    module.release()
    return _test_members(
        cfg, checked, module, data, trainer, MemberFiles(configs, saved, dirs), keeper, started, summary
    )


def _module(cfg: DictConfig, members: list, seeds: list[int], data, stacked: bool | str | None) -> EnsembleModule:
    """The stacked ensemble where ``encons.training.stacked`` accepts the run (its settings, then its first batch) and
    its step on the first batch measures faster than the loop's, else the loop, its path saying why.
    ``stacked``: None decides so; True takes the stacked path wherever it computes the members' losses (no
    timing); False forces the loop; a path (``module.path`` of an earlier run: a resume) takes that path again,
    so that its checkpoint fits."""
    if stacked is False or (isinstance(stacked, str) and stacked.startswith("loop")):
        return _loop(cfg, members, seeds, stacked if isinstance(stacked, str) else "loop: stacked=False")
    if len(members) == 1:
        return _loop(cfg, members, seeds, "loop: one member: nothing to stack (the path of a single run)")
    why = stacking.why_not(cfg, members)
    if why is not None:
        return _loop(cfg, members, seeds, f"loop: {why}")
    batch = next(iter(data.train_dataloader()))
    ways = [True, False] if not isinstance(stacked, str) else [stacked == "stacked (ensemble dimension)"]
    for dimension in ways:  # the ensemble dimension first (measured faster than vmap), then vmap
        module = StackedEnsemble(members, seeds, _clip(cfg), dimension)
        if dimension and module.stacked.model.dimension is None:
            why = "a parameter outside nn.Linear layers and modules that define ensemble (no ensemble dimension)"
            continue
        why = stacking.probe(module.stacked, members, batch)
        if why is None:
            break
    if why is not None:
        return _loop(cfg, members, seeds, f"loop: {why}")
    if stacked is None:
        fast, slow = stacking.step_times(module.stacked, members, batch)
        if fast >= slow:
            return _loop(
                cfg,
                members,
                seeds,
                f"loop: measured faster on the first batch ({module.path}: "
                f"{1e3 * fast:.3g} ms per step, loop: {1e3 * slow:.3g} ms)",
            )
    return module


def _loop(cfg: DictConfig, members: list, seeds: list[int], why: str) -> EnsembleModule:
    module = EnsembleModule(members, seeds, _clip(cfg))
    module.path = why
    return module


def _ensemble_figures(members: list, seeds: list[int], folder: Path) -> None:
    """Each evaluator's figures of the members' spread (``Evaluator.ensemble_figures``), in the ensemble's
    ``figures/``."""
    from encons.evaluators.figures import save_png

    first = members[0]
    for name, evaluator in first.evaluators.items():
        figures = evaluator.ensemble_figures(first, [m.evaluators[name] for m in members], seeds)
        for stem, fig in figures.items():
            save_png(fig, folder / f"{stem}.png", layout=False)


def _clip(cfg: DictConfig) -> tuple[float | None, str | None]:
    return cfg.trainer.get("gradient_clip_val"), cfg.trainer.get("gradient_clip_algorithm")


@dataclass(frozen=True)
class MemberFiles:
    """Per member, in seed order: its run config (composed), the config its checkpoints carry, its folder."""

    configs: list[DictConfig]
    saved: list[DictConfig]
    dirs: list[Path]


def _test_members(
    cfg: DictConfig,
    checked: Checked,
    module: EnsembleModule,
    data,
    trainer: pl.Trainer,
    files: MemberFiles,
    keeper: MemberCheckpoints | None,
    started: float,
    summary: bool,
) -> Ensemble:
    """Test each member that did not diverge on its best checkpoint (else its last weights), as its separate
    run would; write the ensemble's ``test_metrics.json`` and summary."""
    from encons.infra.io import write_json
    from encons.training.build import build_trainer
    from encons.training.summary import print_summary

    seeds, configs, saved, dirs = module.seeds, files.configs, files.saved, files.dirs
    fit_metrics = {k: float(v) for k, v in trainer.callback_metrics.items()}
    before = resumed_seconds(trainer)
    runs, per_member, diverged = [], {}, {seeds[i]: why for i, why in module.diverged.items()}
    for i, (member, c, d) in enumerate(zip(module.members, configs, dirs)):
        prefix = f"seed{seeds[i]}/"
        results = {k.removeprefix(prefix): v for k, v in fit_metrics.items() if k.startswith(prefix)}
        if i in module.diverged:
            runs.append(Run(member, data, saved[i], d, None, {}))
            continue
        tested = keeper.best[i][1] if keeper is not None and i in keeper.best else None
        if keeper is not None and tested is not None:  # tested: a path only where there is a keeper
            state = checkpoints.read(tested)
            member.load_state_dict(state["state_dict"])
            results[f"best/{keeper.monitor}"] = keeper.best[i][0]
            results["best_epoch"] = float(state["epoch"] + 1)  # from 1, as the log counts
        if cfg.test:
            test_cfg = copy.deepcopy(c)
            with open_dict(test_cfg):
                test_cfg.callbacks, test_cfg.logger = None, None
                test_cfg.trainer.enable_progress_bar = False
                test_cfg.trainer.enable_model_summary = False
            tester, _ = build_trainer(checked.derived(test_cfg))
            tester.test(member, datamodule=data, verbose=False, weights_only=True)
            results.update({f"test/{k}": v for k, v in member.test_metrics.items()})
        results["wall_time_s"] = time.perf_counter() - started + before  # the segments before a resume too
        results["threads"] = float(torch.get_num_threads())
        per_member[seeds[i]] = results
        runs.append(Run(member, data, saved[i], d, tested, results, checked=checked.derived(c)))
    metrics = summarise(per_member)
    run_dir = Path(cfg.paths.output_dir)
    scored = [module.members[i] for i in range(len(seeds)) if seeds[i] in per_member]
    if cfg.test and cfg.get("figures", True) and len(scored) > 1:
        _ensemble_figures(scored, [s for s in seeds if s in per_member], run_dir / "figures")
    tests = summarise(
        {s: {k.removeprefix("test/"): v for k, v in r.items() if k.startswith("test/")} for s, r in per_member.items()}
    )
    write_json(run_dir / "test_metrics.json", {**tests, "members": len(seeds), "diverged": len(diverged)})
    metrics["members"], metrics["diverged"] = float(len(seeds)), float(len(diverged))
    note = (
        f"{spread_line(metrics, len(per_member))}; ensemble of seeds {seeds} ({module.path}); _sd: sample std, "
        f"_min/_max; member folders: {', '.join(str(d) for d in dirs)}"
        + "".join(f"; seed {s} diverged: {w}" for s, w in diverged.items())
    )
    shown = {k: v for k, v in metrics.items() if not k.endswith(("_min", "_max"))}
    print_summary(f"{module.members[0].run_title()} × {len(seeds)} seeds", shown, run_dir, note=note, console=summary)
    return Ensemble(
        runs, seeds, diverged, metrics, run_dir, module.path, per_member, time.perf_counter() - started + before
    )
