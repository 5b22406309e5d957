"""The stacked path of a seed ensemble (``encons.ensemble``): K members' networks as one model.

``StackedModel`` holds the members' parameters stacked along a leading member axis
(``torch.func.stack_module_state``) and evaluates the field of all members in one call: ``vmap`` over the
member axis of ``functional_call`` on one template of the model. The member axis is folded into the batch
axis (member-major: rows ``k·N … (k+1)·N − 1`` are member ``k``'s copy of the batch), so the integrator, the
objective and the rollout code run once, unchanged, on K·N windows; each objective means its terms by
``TrainingModule.reduce``, which ``StackedTraining`` takes per member, giving the K losses whose sum's
gradient is each member's own. One optimiser over the stacked parameters is K optimisers when it acts
elementwise (Adam, AdamW, SGD): ``StackedEnsemble`` checks this by name. Gradient clipping is per member (a
norm over one member's slices); a schedule on a member's own metric (``ReduceLROnPlateau``) is one scheduler
per member, whose learning-rate factor scales that member's step. Validation, checkpoints and tests use the
members' own modules, into which the stacked weights are copied before each validation and at the end.

``why_not`` names why a run cannot take this path (then the loop path trains it): a discrete model
(SyMo/E2E-SyMo: Newton iterations), a regulariser (Jacobians of one sample's field), an observation model,
a learned chart map (INN), a per-rollout cache (``rollout_scope``: CHNN, CLNN), a non-elementwise
optimiser, ``compile``, or a first batch on which the stacked losses differ from the members' own or cannot
be computed under ``vmap`` (data-dependent branches: LNN/GLNN's ``guarded_solve``).
"""

from __future__ import annotations

import copy
import inspect
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

import torch
from torch import Tensor, nn
from torch.func import functional_call, stack_module_state, vmap

from encons.models.base import DynamicsModel
from encons.module import TrainingModule

ELEMENTWISE = ("Adam", "AdamW", "SGD", "RMSprop", "Adamax")  # optimisers whose step acts on each element alone


class EnsembleLinear(nn.Module):
    """K ``nn.Linear`` layers as one, on inputs whose leading axis is the member axis: (K, ..., in) -> (K, ..., out)
    by one ``baddbmm`` (the ensemble dimension written into the layer)."""

    def __init__(self, layers: Sequence[nn.Linear]):
        super().__init__()
        self.weight = nn.Parameter(torch.stack([layer.weight.detach().t() for layer in layers]).contiguous())
        self.bias = nn.Parameter(torch.stack([layer.bias.detach() for layer in layers]).unsqueeze(1).contiguous())

    def forward(self, x: Tensor) -> Tensor:
        k, lead = x.shape[0], x.shape[1:-1]
        out = torch.baddbmm(self.bias, x.reshape(k, -1, x.shape[-1]), self.weight)
        return out.reshape(k, *lead, out.shape[-1])


#: the methods of a model that act on its parameters per batch row, called per member on the folded rows
PER_MEMBER = ("to_internal", "from_internal", "residual")


def dimension_model(models: Sequence[DynamicsModel]) -> nn.Module | None:
    """A copy of ``models[0]`` whose every ``nn.Linear`` is an ``EnsembleLinear`` of the members' layers; None
    where a parameter or buffer lives outside ``nn.Linear`` layers (with bias), the members differ in layout, or
    the model does parameter-dependent work outside its ``forward`` (``PER_MEMBER``, ``rollout_scope``)."""
    if any(getattr(type(models[0]), m) is not getattr(DynamicsModel, m) for m in ("to_internal", "from_internal",
                                                                                    "rollout_scope")):
        return None
    linears = [name for name, mod in models[0].named_modules() if isinstance(mod, nn.Linear)]
    owned = {f"{n}.{p}" for n in linears for p in ("weight", "bias")}
    names = {n for n, _ in models[0].named_parameters()} | {n for n, _ in models[0].named_buffers()}
    if not linears or names != owned:
        return None
    stacked = copy.deepcopy(models[0])
    for name in linears:
        parent, _, leaf = name.rpartition(".")
        setattr(stacked.get_submodule(parent) if parent else stacked, leaf,
                EnsembleLinear([m.get_submodule(name) for m in models]))
    return stacked


class _Call(nn.Module):
    """``model.<fn>(*args)`` (a method's name) or ``fn(model, *args)`` as a module's forward, so that
    ``functional_call`` can run it on a member's weights."""

    def __init__(self, model: nn.Module, fn: str | Callable[..., Any]):
        super().__init__()
        self.model, self.fn = model, fn

    def forward(self, *args: Any) -> Any:
        return getattr(self.model, self.fn)(*args) if isinstance(self.fn, str) else self.fn(self.model, *args)


class StackedModel(nn.Module):
    """K copies of one ``DynamicsModel`` with their parameters stacked (``weights``: member axis first).

    Its ``forward(t, z, u)`` and the ``PER_MEMBER`` methods take tensors whose leading axis is the member axis
    folded into the batch (member-major: rows ``k·N … (k+1)·N − 1`` are member ``k``'s) and return the same
    layout: each member's own call on its rows, as ``vmap`` over the member axis of ``functional_call`` on one
    template of the model (or, where every weight is an ``nn.Linear`` and the model does nothing outside its
    field, an ensemble dimension written into the layers: ``EnsembleLinear``, measured faster than ``vmap``).
    ``rollout_scope`` is empty: a model's per-rollout cache (CHNN/CLNN's inverse masses) is the template's, so
    each field evaluation computes it from the member's weights instead. ``penalty`` gives a regulariser per
    member."""

    def __init__(self, models: Sequence[DynamicsModel], dimension: bool = True):
        super().__init__()
        self.k = len(models)
        self.dimension = dimension_model(models) if dimension else None
        if self.dimension is not None:
            self.names, self.buffer_names = [], []
            self.weights = nn.ParameterList(self.dimension.parameters())
            self.__dict__["template"] = self.dimension
            return
        params, buffers = stack_module_state(list(models))
        self.names = list(params)
        self.weights = nn.ParameterList([nn.Parameter(params[n].detach().clone()) for n in self.names])
        self.buffer_names = list(buffers)
        for i, name in enumerate(self.buffer_names):
            self.register_buffer(f"stacked_buffer_{i}", buffers[name].clone())
        self.__dict__["template"] = copy.deepcopy(models[0])  # not a submodule: its own weights are never used

    def __getattr__(self, name: str) -> Any:  # chart, history, objectives, discrete, ...: the template's
        try:
            return super().__getattr__(name)
        except AttributeError:
            if "template" not in self.__dict__:  # still being built
                raise
            return getattr(self.__dict__["template"], name)

    def member_weights(self) -> tuple[dict[str, Tensor], dict[str, Tensor]]:
        buffers = {n: getattr(self, f"stacked_buffer_{i}") for i, n in enumerate(self.buffer_names)}
        return dict(zip(self.names, self.weights)), buffers

    def fold(self, x: Tensor) -> Tensor:
        return x.reshape(self.k, x.shape[0] // self.k, *x.shape[1:])

    def per_member(self, fn: str | Callable[..., Any], args: tuple, folded: tuple[bool, ...]) -> Any:
        """``template.<fn>(*args)`` (or ``fn(template, *args)``) for every member on its weights (vmap over the
        member axis): the ``folded`` arguments are tensors folded member-major along their leading axis, the
        others (times, points, None) are shared by all members. The result is folded the same way where an
        argument was, else it gets a leading member axis."""
        template = _Call(self.__dict__["template"], fn)
        params, buffers = self.member_weights()
        params = {f"model.{n}": v for n, v in params.items()}
        buffers = {f"model.{n}": v for n, v in buffers.items()}
        dims = tuple(0 if f else None for f in folded)
        args = tuple(self.fold(a) if f else a for a, f in zip(args, folded))
        out = vmap(lambda p, b, *xs: functional_call(template, (p, b), xs), in_dims=(0, 0, *dims))(params, buffers,
                                                                                                   *args)
        return out.reshape(-1, *out.shape[2:]) if any(folded) else out

    def forward(self, t: Tensor, z: Tensor, u: Tensor | None = None) -> Tensor:
        if self.dimension is not None:
            out = self.dimension(t, self.fold(z)) if u is None else self.dimension(t, self.fold(z), self.fold(u))
            return out.reshape(-1, *out.shape[2:])
        if u is None:
            return self.per_member("forward", (t, z), (False, True))
        return self.per_member("forward", (t, z, u), (False, True, True))

    def to_internal(self, s: Tensor) -> Tensor:
        return s if self.dimension is not None else self.per_member("to_internal", (s,), (True,))

    def from_internal(self, z: Tensor) -> Tensor:
        return z if self.dimension is not None else self.per_member("from_internal", (z,), (True,))

    def residual(self, states: Tensor, t: Tensor, u: Tensor | None = None) -> Tensor:
        if u is None:
            return self.per_member("residual", (states, t), (True, False))
        return self.per_member("residual", (states, t, u), (True, False, True))

    @contextmanager
    def rollout_scope(self) -> Iterator[None]:
        yield

    def penalty(self, regulariser: Any, points: Tensor, u: Tensor | None) -> Tensor:
        """``regulariser(member, points, u)`` of every member (K,), at the same points for all."""
        return self.per_member(regulariser, (points, u), (False, False))

    @torch.no_grad()
    def copy_to(self, models: Sequence[nn.Module]) -> None:
        """Write member ``k``'s slices into ``models[k]``'s own parameters and buffers."""
        if self.dimension is not None:
            for name, layer in self.dimension.named_modules():
                if isinstance(layer, EnsembleLinear):
                    for k, model in enumerate(models):
                        model.get_submodule(name).weight.copy_(layer.weight[k].t())
                        model.get_submodule(name).bias.copy_(layer.bias[k, 0])
            return
        params, buffers = self.member_weights()
        for k, model in enumerate(models):
            own = dict(model.named_parameters()) | dict(model.named_buffers())
            for name, value in (params | buffers).items():
                own[name].copy_(value[k])


class StackedTraining(TrainingModule):
    """The training objective of all members at once: a ``TrainingModule`` on a ``StackedModel`` whose
    ``reduce`` means each member's rows, so ``loss`` returns the K members' losses."""

    def reduce(self, terms: Tensor) -> Tensor:
        return terms.reshape(self.model.k, -1).mean(1)

    def regularise(self, points: Tensor, u: Tensor | None) -> Tensor:
        return self.model.penalty(self.regulariser, points, u)

    def member_losses(self, batch: dict) -> tuple[Tensor, Tensor | None]:
        """The K members' objectives on ``batch`` and their regulariser's penalties (None: no regulariser);
        a member's training loss is their sum."""
        k = self.model.k
        folded = {key: v.repeat(k, *[1] * (v.dim() - 1)) for key, v in batch.items() if isinstance(v, Tensor)}
        return self.loss(folded), self.penalty(batch)


def optimizer(partial: Any, params: list[Tensor]) -> torch.optim.Optimizer:
    """The members' optimiser over the stacked weights, by its fused kernel where it has one (one pass over each
    stacked tensor instead of one per operation; the same update up to rounding), else as configured."""
    cls = partial.func if hasattr(partial, "func") else partial
    if "fused" in inspect.signature(cls).parameters and "fused" not in getattr(partial, "keywords", {}):
        try:
            return partial(params, fused=True)
        except (RuntimeError, ValueError):  # a device or dtype the kernel does not take
            pass
    return partial(params)


def why_not(cfg: Any, members: Sequence[TrainingModule]) -> str | None:
    """Why the members cannot train stacked (None: they can), from the model, objective and settings alone."""
    member = members[0]
    model, name = member.model, member.model_name or type(member.model).__name__
    if model.discrete and member.objective != "residual":
        return (f"model={name} objective={member.objective} rolls out by Newton iterations whose stopping test "
                f"(any sample still unconverged) is a branch on values, which the member axis does not pass")
    if not member.observation.identity:
        return f"observation={type(member.observation).__name__} trains an encoder beside the model"
    if cfg.get("compile"):
        return "compile=true compiles one model's field"
    opt = member.optimizer.func if hasattr(member.optimizer, "func") else member.optimizer
    if getattr(opt, "__name__", "") not in ELEMENTWISE:
        return f"optimizer {getattr(opt, '__name__', opt)} may mix elements across members; allowed stacked: {', '.join(ELEMENTWISE)}"
    return None


def probe(stacked: StackedTraining, members: Sequence[TrainingModule], batch: dict, rtol: float = 1e-4) -> str | None:
    """None when the stacked losses on ``batch`` equal each member's own (relative ``rtol``), else why not
    (the first line of the error ``vmap`` raised, e.g. at a data-dependent branch)."""
    try:
        objective, penalty = stacked.member_losses(batch)
        got = (objective if penalty is None else objective + penalty).detach()
    except Exception as err:  # noqa: BLE001 - any failure of the stacked forward sends the run down the loop path
        return f"the stacked field failed ({type(err).__name__}: {str(err).splitlines()[0]})"
    want = torch.stack([(m.loss(batch) + (0 if (p := m.penalty(batch)) is None else p)).detach() for m in members])
    diff = ((got - want).abs() / want.abs().clamp_min(1e-12)).max()
    if not bool(diff <= rtol):
        return f"the stacked losses differ from the members' own by {float(diff):.2g} (relative) on the first batch"
    return None
