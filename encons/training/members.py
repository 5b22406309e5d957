"""The LightningModules of a seed ensemble: :class:`EnsembleModule` steps each member's own ``training_step`` in
turn (the loop path), :class:`StackedEnsemble` all members as one stacked model (``encons.training.stacked``);
:class:`MemberOptimizers` steps the members' optimisers as one, :class:`Schedule` is one member's scheduler.
``encons.training.ensemble`` builds them and chooses the path."""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, cast

import lightning.pytorch as pl
import torch
from lightning.pytorch.core.optimizer import LightningOptimizer
from torch import Tensor

from encons.infra.checkpoints import ENSEMBLE_KEY
from encons.infra.compat import bare_optimizer
from encons.infra.errors import DivergenceError
from encons.models.base import DynamicsModel
from encons.training import stacked as stacking
from encons.training.module import TrainingModule, takes_total_steps

log = logging.getLogger(__name__)


class MemberOptimizers(torch.optim.Optimizer):
    """The members' optimisers stepped as one (Lightning counts one optimiser step per batch): ``step`` steps
    those of ``active`` members; ``param_groups`` are the members' own group dicts, so a member's scheduler
    acts on its own members' groups only."""

    def __init__(self, optimizers: Sequence[torch.optim.Optimizer]):  # noqa: D107 - no Optimizer.__init__: the groups are the members'
        self.optimizers = list(optimizers)
        self.active = list(range(len(self.optimizers)))
        self.defaults = dict(self.optimizers[0].defaults)
        self.param_groups = [g for opt in self.optimizers for g in opt.param_groups]
        self.state = {}  # type: ignore[assignment]  # the members' optimisers hold the state: this one's stays empty
        bare_optimizer(self)

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
    """Trains ``members`` (``encons.training.module.TrainingModule``, one per seed of ``seeds``) on the same batches,
    each as its separate run would train (see the module docstring). ``clip`` is the trainer's gradient
    clipping (value, algorithm), applied per member."""

    def __init__(
        self,
        members: Sequence[TrainingModule],
        seeds: Sequence[int],
        clip: tuple[float | None, str | None] = (None, None),
    ):
        super().__init__()
        # a ModuleList (the members registered as submodules), typed as the sequence of TrainingModules it holds
        self.members = cast("Sequence[TrainingModule]", torch.nn.ModuleList(members))
        self.seeds = list(seeds)
        self.clip = clip
        self.automatic_optimization = False
        self.diverged: dict[int, str] = {}  # member index -> why
        self.path = "loop"
        self.schedules: list[Schedule | None] = []
        self.rng = [torch.get_rng_state() for _ in members]  # each member's torch RNG, as its own run left it
        for i, member in enumerate(self.members):
            setattr(member, "log", self._member_logger(i))  # an instance attribute over LightningModule.log

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
                self.schedules.append(
                    Schedule(sched["scheduler"], sched.get("interval", "epoch"), sched.get("monitor"))
                )
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
        checkpoint[ENSEMBLE_KEY] = {
            "seeds": list(self.seeds),
            "rng": list(self.rng),
            "diverged": dict(self.diverged),
            "schedules": self.schedule_states(),
            "path": self.path,
        }

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
                losses[i] = self._swap_rng(i, lambda: self.members[i].training_step(batch, batch_idx))
            except DivergenceError as err:
                self._diverge(i, err)
        return losses

    def training_step(self, batch: dict, batch_idx: int) -> None:
        opt = cast(LightningOptimizer, self.optimizers())  # one optimiser: configure_optimizers returns one
        losses = self.member_losses(batch, batch_idx)
        if losses:
            self.log(
                "train/loss",
                torch.stack([v.detach() for v in losses.values()]).mean(),
                prog_bar=True,
                batch_size=len(batch["states"]),
            )
        cast(MemberOptimizers, opt.optimizer).active = list(losses)  # configure_optimizers returns MemberOptimizers
        if not losses:
            return
        opt.zero_grad()
        self.manual_backward(cast(Tensor, sum(losses.values())))  # a Tensor: losses is not empty
        self._clip(list(losses))
        opt.step()
        for i in losses:
            schedule = self.schedules[i]
            if schedule is not None and schedule.interval == "step":
                schedule.scheduler.step()

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
            self._swap_rng(i, lambda: self.members[i].validation_step(batch, batch_idx))


class StackedEnsemble(EnsembleModule):
    """``EnsembleModule`` whose members train as one ``StackedTraining`` (one forward and backward for all)."""

    def __init__(
        self, members: Sequence[TrainingModule], seeds: Sequence[int], clip=(None, None), dimension: bool = True
    ):
        super().__init__(members, seeds, clip)
        m = members[0]
        model = stacking.StackedModel(
            [x.model for x in members], dimension=dimension and stacking.dimension_penalty(m.model, m.regulariser)
        )
        self.path = f"stacked ({'ensemble dimension' if model.dimension is not None else 'vmap'})"
        self.stacked = stacking.StackedTraining(
            cast(DynamicsModel, model),  # a StackedModel stands in for one: it forwards what it lacks to a member
            m.system,
            m.dt,
            m.integrator,
            m.optimizer,
            m.scheduler,
            objective=m.objective,
            regulariser=m.regulariser,
            horizon=m.horizon,
            observation=stacking.stacked_observation([x.observation for x in members]),
            model_name=m.model_name,
        )
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
        return {
            **super().schedule_states(),
            "shared": None if shared is None else shared.scheduler.state_dict(),
            "factors": [shadow.state_dict() for shadow in self.factors],
        }

    def load_schedule_states(self, states: dict) -> None:
        super().load_schedule_states(states)
        if states["shared"] is not None:
            self.shared.scheduler.load_state_dict(states["shared"])
        for shadow, state in zip(self.factors, states["factors"]):
            shadow.load_state_dict(state)

    def training_step(self, batch: dict, batch_idx: int) -> None:
        opt = cast(LightningOptimizer, self.optimizers())  # one optimiser: configure_optimizers returns one
        objective, penalty = self.stacked.member_losses(batch)
        losses = objective if penalty is None else objective + penalty
        size = len(batch["states"])
        finite = torch.isfinite(losses.detach())
        for i in self.active:  # as each member's own training_step logs them
            self.log(f"seed{self.seeds[i]}/train/loss", objective[i].detach(), batch_size=size)
            if penalty is not None:
                self.log(f"seed{self.seeds[i]}/train/regulariser", penalty[i].detach(), batch_size=size)
            if not bool(finite[i]):
                self.diverged[i] = (
                    f"training diverged: loss is {float(losses[i])} at epoch {self.current_epoch}, "
                    f"step {self.global_step}"
                )
                self._diverge(i, Exception(self.diverged[i]))
        active = self.active
        if not active:
            return
        mask = torch.zeros(len(self.members), dtype=torch.bool, device=losses.device)
        mask[active] = True
        self.log("train/loss", losses.detach()[mask].mean(), prog_bar=True, batch_size=size)
        opt.zero_grad()
        self.manual_backward(torch.where(mask, losses, torch.zeros_like(losses)).sum())
        weights: list[Tensor] = list(self.stacked.parameters())  # the model's and the observation's, member axis first
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
        self.stacked.copy_to(self.members)

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        """The members' own weights current in the file as well (its ``members.<k>.`` entries, which ``encons.load``
        and ``encons.evaluate`` read): the stacked weights copied into them, also on an epoch without validation
        (Lightning took the state dict before this hook)."""
        self.stacked.copy_to(self.members)
        checkpoint["state_dict"].update(
            {f"members.{k}.{name}": value for k, m in enumerate(self.members) for name, value in m.state_dict().items()}
        )
        super().on_save_checkpoint(checkpoint)

    def on_train_end(self) -> None:
        self.stacked.copy_to(self.members)
