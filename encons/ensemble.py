"""Seed ensembles: ``seeds=[0,1,2]`` trains one member per seed in one process, each the run ``seed=k`` would be.

Member ``k`` is built exactly as the separate run ``seed=k`` (``encons.build.build``: the same initial
weights); every member sees the same batches, because the data seed (``data.seed``) is shared. Each
member keeps its own optimiser and schedule (``MemberOptimizers``: one optimiser per member, stepped as
one), its own gradient clipping, its own validation metrics (logged as ``seed<k>/val/...``), its own best
checkpoint (``<member dir>/checkpoints/best-epochNNNN.ckpt``, a normal single-seed checkpoint that
``encons.load`` / ``encons.evaluate`` read) and its own test (``<member dir>/test_metrics.json``). A member
whose loss turns non-finite is reported diverged and left out from then on; the others go on.

Two paths compute the members' losses (``EnsembleModule.path``):

- ``stacked``: the members' networks as one stacked model (``encons.stacked``: ``torch.func.stack_module_state``
  + ``functional_call`` + ``vmap`` over the member axis, folded into the batch axis), one forward and one
  backward for all members; for the models and settings ``encons.stacked.why_not`` accepts;
- ``loop``: each member's own ``training_step`` in turn (one backward of their sum) — every model, every
  objective, regulariser, observation and schedule, e.g. ``ReduceLROnPlateau`` on a member's own validation.

The ensemble's ``test_metrics.json`` (in the run folder) holds, per test metric, the mean over the members
that did not diverge and its ``_sd`` (sample std), ``_min`` and ``_max``, with ``members`` and ``diverged``.
"""

from __future__ import annotations

import copy
import json
import logging
import math
import os
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import lightning.pytorch as pl
import torch
from omegaconf import DictConfig, OmegaConf, open_dict

from encons import attempts, checkpoints
from encons import stacked as stacking
from encons.module import takes_total_steps
from encons.errors import ConfigError, DivergenceError

if TYPE_CHECKING:
    from encons.config import Request

log = logging.getLogger(__name__)
ENSEMBLE_KEY = "encons_ensemble"  # where an ensemble's last.ckpt keeps what Lightning does not
MEMBERS_FILE = "members.json"  # in an ensemble's folder: its seeds and member folders (relative), for load/evaluate


def check_seeds(seeds: Any) -> list[int]:
    """The ``seeds`` list, refused in one line unless it is a non-empty list of distinct integer seeds."""
    values = list(seeds) if isinstance(seeds, (list, tuple)) or OmegaConf.is_list(seeds) else None
    if (not values or not all(isinstance(s, int) and not isinstance(s, bool) and 0 <= s < 2**32 for s in values)
            or len(set(values)) != len(values)):
        raise ConfigError(f"seeds={seeds}; allowed: a non-empty list of distinct integer seeds in 0..2**32-1, "
                          f"e.g. seeds=[0,1,2]")
    return values


def refuse(cfg: DictConfig, request: Request) -> None:
    """Refuse, in one line each, what an ensemble cannot be: data that differ per seed, DDP, an explicit ``seed``
    beside ``seeds``. (``train`` refuses the plain-inverse retry once the config is checked: it needs the model.)"""
    if "seed" in request.overridden():
        raise ConfigError(f"seed={cfg.seed} beside seeds={list(cfg.seeds)}: the members' seeds are the list; "
                          f"allowed: one of seed=K or seeds=[...]")
    devices, strategy = cfg.trainer.get("devices", 1), str(cfg.trainer.get("strategy", "auto"))
    if (isinstance(devices, int) and devices > 1) or devices in ("auto", -1) or "ddp" in strategy:
        raise ConfigError(f"trainer.devices={devices} trainer.strategy={strategy} with seeds: an ensemble trains "
                          f"its members in one process on one device; allowed: trainer.devices=1 (no DDP) with seeds")
    if "${seed" in str(OmegaConf.to_yaml(OmegaConf.masked_copy(cfg, ["data"]), resolve=False)):
        raise ConfigError("data.seed follows seed, so each member would train on other data; allowed: a fixed "
                          "data.seed with seeds (the members share their batches)")


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
    """The callbacks of ``cfg`` that are Lightning ``ModelCheckpoint``s, by class (encons' ``BestCheckpoint`` is one)."""
    from lightning.pytorch.callbacks import ModelCheckpoint

    return {name: node for name, node in (cfg.get("callbacks") or {}).items() if isinstance(node, DictConfig)
            and isinstance(cls := targets.get(str(node.get("_target_"))), type) and issubclass(cls, ModelCheckpoint)}


def _monitor(cfg: DictConfig, targets: Mapping[str, Any]) -> tuple[str, str] | None:
    """The monitored metric and mode of the run's best-checkpoint callback (None: no monitored checkpoint)."""
    for node in _checkpointers(cfg, targets).values():
        if node.get("monitor"):
            return str(node.monitor), str(node.get("mode", "min"))
    return None


class MemberOptimizers(torch.optim.Optimizer):
    """The members' optimisers stepped as one (Lightning counts one optimiser step per batch): ``step`` steps
    those of ``active`` members; ``param_groups`` are the members' own group dicts, so a member's scheduler
    acts on its own members' groups only."""

    def __init__(self, optimizers: Sequence[torch.optim.Optimizer]):  # noqa: D107 - no Optimizer.__init__: the groups are the members'
        self.optimizers = list(optimizers)
        self.active = list(range(len(self.optimizers)))
        self.defaults = dict(self.optimizers[0].defaults)
        self.param_groups = [g for opt in self.optimizers for g in opt.param_groups]
        self.state = {}
        self._optimizer_step_pre_hooks, self._optimizer_step_post_hooks = {}, {}
        self._optimizer_state_dict_pre_hooks, self._optimizer_state_dict_post_hooks = {}, {}
        self._optimizer_load_state_dict_pre_hooks, self._optimizer_load_state_dict_post_hooks = {}, {}

    def step(self, closure: Callable[[], Any] | None = None) -> Any:
        loss = closure() if closure is not None else None
        for i in self.active:
            self.optimizers[i].step()
        return loss

    def zero_grad(self, set_to_none: bool = True) -> None:
        for opt in self.optimizers:
            opt.zero_grad(set_to_none=set_to_none)

    def state_dict(self) -> dict:
        return {"members": [opt.state_dict() for opt in self.optimizers]}

    def load_state_dict(self, state_dict: dict) -> None:
        for opt, state in zip(self.optimizers, state_dict["members"]):
            opt.load_state_dict(state)


@dataclass
class Schedule:
    """One member's scheduler as Lightning would step it: per optimiser ``step`` or per ``epoch``, on a
    ``monitor``ed metric (``ReduceLROnPlateau``) or not."""

    scheduler: Any
    interval: str = "epoch"
    monitor: str | None = None


class EnsembleModule(pl.LightningModule):
    """Trains ``members`` (``encons.module.TrainingModule``, one per seed of ``seeds``) on the same batches,
    each as its separate run would train (see the module docstring). ``clip`` is the trainer's gradient
    clipping (value, algorithm), applied per member."""

    def __init__(self, members: Sequence[pl.LightningModule], seeds: Sequence[int],
                 clip: tuple[float | None, str | None] = (None, None)):
        super().__init__()
        self.members = torch.nn.ModuleList(members)
        self.seeds = list(seeds)
        self.clip = clip
        self.automatic_optimization = False
        self.diverged: dict[int, str] = {}     # member index -> why
        self.path = "loop"
        self.schedules: list[Schedule | None] = []
        self.rng = [torch.get_rng_state() for _ in members]  # each member's torch RNG, as its own run left it
        for i, member in enumerate(self.members):
            member.log = self._member_logger(i)

    def _member_logger(self, i: int) -> Callable[..., None]:
        def log_member(name: str, value: Any, prog_bar: bool = False, **kwargs: Any) -> None:
            self.log(f"seed{self.seeds[i]}/{name}", value, **kwargs)
        return log_member

    def release(self) -> None:
        """Give every member back its own ``log`` (after training: each is tested as a run of its own)."""
        for member in self.members:
            member.__dict__.pop("log", None)

    @property
    def active(self) -> list[int]:
        return [i for i in range(len(self.members)) if i not in self.diverged]

    def setup(self, stage: str) -> None:
        for member in self.members:  # Lightning attaches direct children only; members sit in a ModuleList
            member.trainer = self.trainer

    def configure_optimizers(self):
        """Each member's own ``configure_optimizers`` (its optimiser partial and scheduler), stepped as one."""
        optimizers = []
        for member in self.members:
            conf = member.configure_optimizers()
            if isinstance(conf, dict):
                sched = conf["lr_scheduler"]
                optimizers.append(conf["optimizer"])
                self.schedules.append(Schedule(sched["scheduler"], sched.get("interval", "epoch"), sched.get("monitor")))
            else:
                optimizers.append(conf)
                self.schedules.append(None)
        return MemberOptimizers(optimizers)

    def _swap_rng(self, i: int, run: Callable[[], Any]) -> Any:
        """``run()`` with member ``i``'s torch RNG state (saved back after): its draws are its own seed's."""
        outer = torch.get_rng_state()
        torch.set_rng_state(self.rng[i])
        try:
            return run()
        finally:
            self.rng[i] = torch.get_rng_state()
            torch.set_rng_state(outer)

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        """What Lightning does not keep of an ensemble (its ``last.ckpt``): each member's RNG and schedules
        (stepped here, not by Lightning) and which members diverged."""
        checkpoint[ENSEMBLE_KEY] = {"seeds": list(self.seeds), "rng": list(self.rng), "diverged": dict(self.diverged),
                                    "schedules": self.schedule_states(), "path": self.path}

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        self.__dict__["restored"] = checkpoint.get(ENSEMBLE_KEY)  # applied once the optimisers exist

    def on_train_start(self) -> None:
        state = self.__dict__.pop("restored", None)
        if state is None:
            return
        self.rng, self.diverged = list(state["rng"]), {int(i): why for i, why in state["diverged"].items()}
        self.load_schedule_states(state["schedules"])

    def schedule_states(self) -> dict:
        return {"members": [None if s is None else s.scheduler.state_dict() for s in self.schedules]}

    def load_schedule_states(self, states: dict) -> None:
        for s, state in zip(self.schedules, states["members"]):
            if s is not None and state is not None:
                s.scheduler.load_state_dict(state)

    def _diverge(self, i: int, err: Exception) -> None:
        why = str(err).split(";")[0]
        self.diverged[i] = why
        log.warning("ensemble member seed=%d %s; the other members go on", self.seeds[i], why)

    def member_losses(self, batch: dict, batch_idx: int) -> dict[int, torch.Tensor]:
        """Each active member's training loss (its ``training_step``, which logs and checks it), by index."""
        losses = {}
        for i in self.active:
            try:
                losses[i] = self._swap_rng(i, lambda i=i: self.members[i].training_step(batch, batch_idx))
            except DivergenceError as err:
                self._diverge(i, err)
        return losses

    def training_step(self, batch: dict, batch_idx: int) -> None:
        opt = self.optimizers()
        losses = self.member_losses(batch, batch_idx)
        if losses:
            self.log("train/loss", torch.stack([v.detach() for v in losses.values()]).mean(), prog_bar=True,
                     batch_size=len(batch["states"]))
        opt.optimizer.active = list(losses)
        if not losses:
            return
        opt.zero_grad()
        self.manual_backward(sum(losses.values()))
        self._clip(list(losses))
        opt.step()
        for i in losses:
            if self.schedules[i] is not None and self.schedules[i].interval == "step":
                self.schedules[i].scheduler.step()

    def _clip(self, members: list[int]) -> None:
        """The trainer's gradient clipping, per member (a norm over one member's parameters only)."""
        value, algorithm = self.clip
        if not value:
            return
        for i in members:
            params = [p for p in self.members[i].parameters() if p.grad is not None]
            if algorithm == "value":
                torch.nn.utils.clip_grad_value_(params, value)
            else:
                torch.nn.utils.clip_grad_norm_(params, value)

    def on_train_epoch_end(self) -> None:
        """Epoch schedulers, after validation (as Lightning orders them); a plateau on the member's own metric,
        in the epochs that validate (``validation.every``)."""
        metrics = self.trainer.callback_metrics
        validated = (self.current_epoch + 1) % (self.trainer.check_val_every_n_epoch or 1) == 0
        for i in self.active:
            s = self.schedules[i]
            if s is None or s.interval != "epoch":
                continue
            if s.monitor is None:
                s.scheduler.step()
            elif validated and (key := f"seed{self.seeds[i]}/{s.monitor}") in metrics:
                s.scheduler.step(metrics[key])

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        for i in self.active:
            self._swap_rng(i, lambda i=i: self.members[i].validation_step(batch, batch_idx))


class MemberCheckpoints(pl.Callback):
    """Each member's best checkpoint by its own ``seed<k>/<monitor>``, as ``ModelCheckpoint`` (save_top_k 1)
    keeps a separate run's: written after each validation where the member improved (strictly; NaN never),
    the previous one removed. The file is a normal single-seed checkpoint: the member's ``state_dict``, its
    epoch and step, and its run config (``encons.checkpoints.CONFIG_KEY``)."""

    def __init__(self, dirs: Sequence[Path], configs: Sequence[dict], monitor: str, mode: str = "min"):
        self.dirs, self.configs, self.monitor, self.mode = list(dirs), list(configs), monitor, mode
        self.best: dict[int, tuple[float, Path]] = {}

    def _better(self, value: float, best: float) -> bool:
        return not math.isnan(value) and (value < best if self.mode == "min" else value > best)

    def _save(self, trainer: pl.Trainer, module: EnsembleModule) -> None:
        from encons.io import save_checkpoint

        for i in module.active:
            key = f"seed{module.seeds[i]}/{self.monitor}"
            if key not in trainer.callback_metrics:
                continue
            value = float(trainer.callback_metrics[key])
            old = self.best.get(i)
            if old is not None and not self._better(value, old[0]):
                continue
            if old is None and math.isnan(value):
                continue
            path = self.dirs[i] / "checkpoints" / f"best-epoch{trainer.current_epoch + 1:04d}.ckpt"  # from 1, as the log
            save_checkpoint({"epoch": trainer.current_epoch, "global_step": trainer.global_step,
                             "pytorch-lightning_version": pl.__version__,
                             "state_dict": module.members[i].state_dict(),
                             checkpoints.CONFIG_KEY: self.configs[i]}, path)
            if old is not None and old[1] != path:
                old[1].unlink(missing_ok=True)
            self.best[i] = (value, path)

    def state_dict(self) -> dict:  # in the ensemble's last.ckpt: a resumed ensemble keeps its members' bests
        return {"best": {i: [value, str(path)] for i, (value, path) in self.best.items()}}

    def load_state_dict(self, state_dict: dict) -> None:
        self.best = {int(i): (float(value), Path(path)) for i, (value, path) in state_dict["best"].items()}

    def on_validation_end(self, trainer: pl.Trainer, module: EnsembleModule) -> None:
        if not trainer.sanity_checking:
            self._save(trainer, module)

    def on_train_epoch_end(self, trainer: pl.Trainer, module: EnsembleModule) -> None:
        if not self.monitor.startswith("val/"):
            self._save(trainer, module)


class StackedEnsemble(EnsembleModule):
    """``EnsembleModule`` whose members train as one ``StackedTraining`` (one forward and backward for all)."""

    def __init__(self, members: Sequence[TrainingModule], seeds: Sequence[int], clip=(None, None),
                 dimension: bool = True):
        super().__init__(members, seeds, clip)
        m = members[0]
        model = stacking.StackedModel([x.model for x in members],
                                      dimension=dimension and stacking.dimension_penalty(m.model, m.regulariser))
        self.path = f"stacked ({'ensemble dimension' if model.dimension is not None else 'vmap'})"
        self.stacked = stacking.StackedTraining(model, m.system, m.dt, m.integrator, m.optimizer, m.scheduler,
                                                objective=m.objective, regulariser=m.regulariser, horizon=m.horizon,
                                                model_name=m.model_name)
        self.factors: list[Any] = []  # per member: a one-parameter optimiser whose lr its plateau scheduler moves

    def configure_optimizers(self):
        member = self.members[0]
        opt = stacking.optimizer(member.optimizer, list(self.stacked.parameters()))
        self.base_lr = [g["lr"] for g in opt.param_groups]
        self.schedules = [None] * len(self.members)
        if member.scheduler is None:
            return opt
        if takes_total_steps(member.scheduler):
            sched = member.scheduler(opt, total_steps=max(1, int(self.trainer.estimated_stepping_batches)))
            self.shared = Schedule(sched, "step")
            return opt
        probe_sched = member.scheduler(torch.optim.SGD([torch.zeros(1, requires_grad=True)], lr=1.0))
        if isinstance(probe_sched, torch.optim.lr_scheduler.ReduceLROnPlateau):  # per member, on its own metric
            for i in range(len(self.members)):
                shadow = torch.optim.SGD([torch.zeros(1, requires_grad=True)], lr=self.base_lr[0])
                self.factors.append(shadow)
                self.schedules[i] = Schedule(member.scheduler(shadow), "epoch", "val/loss")
        else:
            self.shared = Schedule(member.scheduler(opt), "epoch")
        return opt

    def schedule_states(self) -> dict:
        shared = getattr(self, "shared", None)
        return {**super().schedule_states(), "shared": None if shared is None else shared.scheduler.state_dict(),
                "factors": [shadow.state_dict() for shadow in self.factors]}

    def load_schedule_states(self, states: dict) -> None:
        super().load_schedule_states(states)
        if states["shared"] is not None:
            self.shared.scheduler.load_state_dict(states["shared"])
        for shadow, state in zip(self.factors, states["factors"]):
            shadow.load_state_dict(state)

    def training_step(self, batch: dict, batch_idx: int) -> None:
        opt = self.optimizers()
        objective, penalty = self.stacked.member_losses(batch)
        losses = objective if penalty is None else objective + penalty
        size = len(batch["states"])
        finite = torch.isfinite(losses.detach())
        for i in self.active:  # as each member's own training_step logs them
            self.log(f"seed{self.seeds[i]}/train/loss", objective[i].detach(), batch_size=size)
            if penalty is not None:
                self.log(f"seed{self.seeds[i]}/train/regulariser", penalty[i].detach(), batch_size=size)
            if not bool(finite[i]):
                self.diverged[i] = (f"training diverged: loss is {float(losses[i])} at epoch {self.current_epoch}, "
                                    f"step {self.global_step}")
                self._diverge(i, Exception(self.diverged[i]))
        active = self.active
        if not active:
            return
        mask = torch.zeros(len(self.members), dtype=torch.bool, device=losses.device)
        mask[active] = True
        self.log("train/loss", losses.detach()[mask].mean(), prog_bar=True, batch_size=size)
        opt.zero_grad()
        self.manual_backward(torch.where(mask, losses, torch.zeros_like(losses)).sum())
        weights = list(self.stacked.model.weights)
        with torch.no_grad():
            for w in weights:
                if w.grad is not None:
                    w.grad[~mask] = 0
            self._clip_stacked(weights)
            before = [w.detach().clone() for w in weights] if self.factors else None
        opt.step()
        if before is not None:
            self._scale_steps(weights, before)
        shared = getattr(self, "shared", None)
        if shared is not None and shared.interval == "step":
            shared.scheduler.step()

    def _clip_stacked(self, weights: list[Tensor]) -> None:
        """``clip_grad_norm_`` / ``clip_grad_value_`` of the trainer's clipping, per member's slices."""
        value, algorithm = self.clip
        grads = [w.grad for w in weights if w.grad is not None]
        if not value or not grads:
            return
        if algorithm == "value":
            for g in grads:
                g.clamp_(-value, value)
            return
        norms = torch.stack([g.flatten(1).norm(dim=1) for g in grads], 1).norm(dim=1)  # (K,)
        coef = (value / (norms + 1e-6)).clamp(max=1.0)
        for g in grads:
            g.mul_(coef.reshape(-1, *[1] * (g.dim() - 1)))

    @torch.no_grad()
    def _scale_steps(self, weights: list[Tensor], before: list[Tensor]) -> None:
        """Member k's step times its plateau factor (its lr over the optimiser's): exact for Adam/AdamW/SGD,
        whose step (decoupled weight decay included) is linear in the learning rate."""
        factors = torch.tensor([shadow.param_groups[0]["lr"] / self.base_lr[0] for shadow in self.factors])
        if bool((factors == 1).all()):
            return
        for w, old in zip(weights, before):
            f = factors.to(w).reshape(-1, *[1] * (w.dim() - 1))
            w.copy_(torch.where(f == 1, w, old + f * (w - old)))

    def on_train_epoch_end(self) -> None:
        metrics = self.trainer.callback_metrics
        shared = getattr(self, "shared", None)
        if shared is not None and shared.interval == "epoch":
            shared.scheduler.step()
        for i in self.active:
            s = self.schedules[i]
            if s is not None and (key := f"seed{self.seeds[i]}/{s.monitor}") in metrics:
                s.scheduler.step(metrics[key])

    def on_validation_epoch_start(self) -> None:
        self.stacked.model.copy_to([m.model for m in self.members])

    def on_train_end(self) -> None:
        self.stacked.model.copy_to([m.model for m in self.members])


@dataclass
class Ensemble:
    """A trained ensemble: one :class:`encons.runs.Run` per member (in ``seeds`` order; a diverged member's
    ``checkpoint`` is None and its ``metrics`` empty), the seeds that ``diverged`` (seed -> why), the
    ``metrics`` over members (mean, ``_sd``, ``_min``, ``_max``) and the run folder; ``path`` says how the
    members were stepped (``stacked`` or ``loop``, and why not stacked)."""

    members: list  # encons.runs.Run
    seeds: list[int]
    diverged: dict[int, str]
    metrics: dict[str, float]
    run_dir: Path
    path: str = "loop"
    member_metrics: dict[int, dict[str, float]] = field(default_factory=dict)


def member_folders(path: Path) -> tuple[list[int], list[Path]] | None:
    """The seeds and member folders of the ensemble folder ``path`` (its ``members.json``); None: not one."""
    file = path / MEMBERS_FILE
    if not file.is_file():
        return None
    listed = json.loads(file.read_text())
    return [int(s) for s in listed["seeds"]], [path / p for p in listed["members"]]


#: The headline metrics of an ensemble's spread line, the first present
HEADLINE = ("test/traj_rel_err", "test/geom_rel_err", "test/accel_mse", "test/state_mse", "val/loss")


def spread_line(metrics: dict[str, float], members: int) -> str:
    """The headline metric as mean ± sample std over the members (mean alone where one member remains or the
    spread is below float rounding of the mean)."""
    key = next((k for k in HEADLINE if k in metrics), None)
    if key is None:
        return f"mean over {members} members"
    mean, sd = metrics[key], metrics.get(f"{key}_sd", 0.0)
    if members < 2 or sd <= 1e-12 * abs(mean):
        return f"{key.removeprefix('test/')} {mean:.4g} (mean over {members} member{'s' * (members != 1)}, no spread)"
    return (f"{key.removeprefix('test/')} {mean:.4g} ± {sd:.2g} (mean ± sample std over {members} members, "
            f"min {metrics[key + '_min']:.4g}, max {metrics[key + '_max']:.4g})")


def summarise(per_member: dict[int, dict[str, float]]) -> dict[str, float]:
    """Mean, sample std (``_sd``), ``_min`` and ``_max`` over members of every metric they share."""
    out: dict[str, float] = {}
    keys = dict.fromkeys(k for m in per_member.values() for k in m)
    for key in keys:
        values = [m[key] for m in per_member.values() if key in m]
        if not values:
            continue
        mean = sum(values) / len(values)
        out[key] = mean
        out[f"{key}_sd"] = math.sqrt(sum((v - mean) ** 2 for v in values) / max(1, len(values) - 1))
        out[f"{key}_min"], out[f"{key}_max"] = min(values), max(values)
    return out


def train(cfg: DictConfig, summary: bool, request: Request, run_type: type,
          member_dir: Callable[[int], Path] | None = None, stacked: bool | None = None) -> Ensemble:
    """Train the ensemble ``cfg.seeds`` of ``cfg`` (see the module docstring); member ``k`` writes to
    ``member_dir(k)`` (default ``<run>/seed<k>``) and is returned as a ``run_type`` (``encons.runs.Run``).
    ``stacked``: None picks the stacked path where ``encons.stacked.why_not`` and the first batch allow it;
    False forces the loop."""
    from encons.build import build, build_trainer
    from encons.config import run_config, validate
    from encons.fitting import fit
    from encons.io import write_json, write_yaml

    started = time.perf_counter()
    seeds = check_seeds(cfg.seeds)
    refuse(cfg, request)
    checked = validate(cfg, request)  # the one validation pass: the members differ from it in seed and folders only
    if cfg.get("plain_solve") and attempts.has_guard(checked.model):
        raise ConfigError("plain_solve=true retrains a run from scratch when the plain inverse diverges, which "
                          "one member of an ensemble cannot do alone; allowed: plain_solve=false with seeds")
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
        saved_state = checkpoints.read(resume, "ckpt_path").get(ENSEMBLE_KEY)
        if saved_state is None:
            raise ConfigError(f"ckpt_path={resume} is not a seed ensemble's checkpoint (a single run's, or a member's "
                              f"best weights); allowed: ckpt_path=last, or the ensemble's checkpoints/last.ckpt")
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
    monitor = _monitor(cfg, checked.targets)
    if monitor is not None:
        trainer.callbacks.append(MemberCheckpoints(dirs, [OmegaConf.to_container(c) for c in saved], *monitor))
        keeper = trainer.callbacks[-1]
    else:
        keeper = None
    if resume is not None:  # resuming writes into the run's own checkpoints/ on purpose
        warnings.filterwarnings("ignore", message=r"Checkpoint directory .* exists and is not empty")
    log.info("ensemble of %d members (seeds %s), path: %s%s", len(seeds), seeds, module.path,
             f"; resumed from {resume}" if resume else "")
    try:
        fit(cfg, trainer, module, data, resume, request)
    finally:
        if any(type(lg).__name__ == "WandbLogger" for lg in loggers):
            import wandb

            wandb.finish()
    module.release()
    return _test_members(cfg, checked, module, data, configs, saved, dirs, keeper, trainer, started, summary,
                         run_type)


def _module(cfg: DictConfig, members: list, seeds: list[int], data, stacked: bool | str | None) -> EnsembleModule:
    """The stacked ensemble where ``encons.stacked`` accepts the run (its settings, then its first batch) and
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
            why = "a parameter outside nn.Linear layers or a per-rollout cache (no ensemble dimension)"
            continue
        why = stacking.probe(module.stacked, members, batch)
        if why is None:
            break
    if why is not None:
        return _loop(cfg, members, seeds, f"loop: {why}")
    if stacked is None:
        fast, slow = stacking.step_times(module.stacked, members, batch)
        if fast >= slow:
            return _loop(cfg, members, seeds, f"loop: measured faster on the first batch ({module.path}: "
                                              f"{1e3 * fast:.3g} ms per step, loop: {1e3 * slow:.3g} ms)")
    return module


def _loop(cfg: DictConfig, members: list, seeds: list[int], why: str) -> EnsembleModule:
    module = EnsembleModule(members, seeds, _clip(cfg))
    module.path = why
    return module


def _ensemble_figures(members: list, seeds: list[int], folder: Path) -> None:
    """Each evaluator's figures of the members' spread (``Evaluator.ensemble_figures``), in the ensemble's
    ``figures/``."""
    from encons.plots import save_png

    first = members[0]
    for name, evaluator in first.evaluators.items():
        figures = evaluator.ensemble_figures(first, [m.evaluators[name] for m in members], seeds)
        for stem, fig in figures.items():
            save_png(fig, folder / f"{stem}.png", layout=False)


def _clip(cfg: DictConfig) -> tuple[float | None, str | None]:
    return cfg.trainer.get("gradient_clip_val"), cfg.trainer.get("gradient_clip_algorithm")


def _test_members(cfg, checked, module, data, configs, saved, dirs, keeper, trainer, started, summary,
                  run_type) -> Ensemble:
    """Test each member that did not diverge on its best checkpoint (else its last weights), as its separate
    run would; write the ensemble's ``test_metrics.json`` and summary."""
    from encons.build import build_trainer
    from encons.io import write_json
    from encons.report import print_summary

    seeds = module.seeds
    fit_metrics = {k: float(v) for k, v in trainer.callback_metrics.items()}
    runs, per_member, diverged = [], {}, {seeds[i]: why for i, why in module.diverged.items()}
    for i, (member, c, d) in enumerate(zip(module.members, configs, dirs)):
        prefix = f"seed{seeds[i]}/"
        results = {k.removeprefix(prefix): v for k, v in fit_metrics.items() if k.startswith(prefix)}
        if i in module.diverged:
            runs.append(run_type(member, data, saved[i], d, None, {}))
            continue
        tested = keeper.best[i][1] if keeper is not None and i in keeper.best else None
        if tested is not None:
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
        results["wall_time_s"] = time.perf_counter() - started
        results["threads"] = float(torch.get_num_threads())
        per_member[seeds[i]] = results
        runs.append(run_type(member, data, saved[i], d, tested, results))
    metrics = summarise(per_member)
    run_dir = Path(cfg.paths.output_dir)
    tested = [module.members[i] for i in range(len(seeds)) if seeds[i] in per_member]
    if cfg.test and cfg.get("figures", True) and len(tested) > 1:
        _ensemble_figures(tested, [s for s in seeds if s in per_member], run_dir / "figures")
    tests = summarise({s: {k.removeprefix("test/"): v for k, v in r.items() if k.startswith("test/")}
                       for s, r in per_member.items()})
    write_json(run_dir / "test_metrics.json", {**tests, "members": len(seeds), "diverged": len(diverged)})
    metrics["members"], metrics["diverged"] = float(len(seeds)), float(len(diverged))
    note = (f"{spread_line(metrics, len(per_member))}; ensemble of seeds {seeds} ({module.path}); _sd: sample std, "
            f"_min/_max; member folders: {', '.join(str(d) for d in dirs)}"
            + "".join(f"; seed {s} diverged: {w}" for s, w in diverged.items()))
    shown = {k: v for k, v in metrics.items() if not k.endswith(("_min", "_max"))}
    print_summary(f"{module.members[0].run_title()} × {len(seeds)} seeds", shown, run_dir, note=note, console=summary)
    return Ensemble(runs, seeds, diverged, metrics, run_dir, module.path, per_member)
