"""The stacked path of a seed ensemble (``encons.training.ensemble``): K members' networks as one model.

``StackedModel`` evaluates every member in one call, two ways. With the ensemble dimension (``dimension_model``:
a model whose parameters all live in ``nn.Linear`` layers or in modules that define ``ensemble``, as
``PointMasses``: ``stacker``) a copy of the model has each such part replaced by one of the members' parts with
a member axis first on its parameters (``EnsembleLinear`` for a layer), and the model's own code runs once on rows
(K, N, ...) whose leading axis is the member axis: its field, ``to_internal``/``from_internal``, a per-rollout cache
(``rollout_scope``: CHNN/CLNN's inverse masses, member-stacked), SyMo's ``residual``, a discrete model's
``rollout`` (E2E-SyMo's Newton iterations, each sample of each member converging on its own), a regulariser's
Jacobians. Otherwise ``vmap`` over the member axis of ``functional_call`` on one template of the model
(``torch.func.stack_module_state``), for the INN (its coupling scales and per-member rotations); ``vmap``
cannot pass a branch on values, so a discrete model's rollout needs the dimension.

Outside the model the member axis is folded into the batch axis (member-major: rows ``k·N … (k+1)·N − 1`` are
member ``k``'s copy of the batch), so the integrator, the objective and the rollout code run once, unchanged, on
K·N windows; each objective means its terms by ``TrainingModule.reduce``, which ``StackedTraining`` takes per
member, giving the K losses whose sum's gradient is each member's own. An observation model (the pixel models'
autoencoder, ``encons.models.observation``) is stacked as a copy whose every ``nn.Linear`` is an ``EnsembleLinear``
(``stacked_observation``), which takes the folded rows as they are: member ``k``'s frames are encoded by its own
encoder, rolled out by its own dynamics and decoded by its own decoder, one batched product per layer for all
members, and ``Observation.loss`` means its terms per member by the same ``reduce``; a regulariser acts on each
member's own encodings. One optimiser over the stacked parameters is K optimisers when it acts elementwise (Adam,
AdamW, SGD): ``why_not`` checks this by name. Gradient clipping is per member (a norm over one member's slices);
a schedule on a member's own metric (``ReduceLROnPlateau``) is one scheduler per member, whose learning-rate factor
scales that member's step.
Validation, checkpoints and tests use the members' own modules (model and observation), into which the stacked
weights are copied before each validation, at each checkpoint and at the end (``StackedTraining.copy_to``).

``why_not`` names what no stacked way takes (an observation model with a parameter outside ``stacker``'s modules,
a non-elementwise optimiser, ``compile``); ``probe`` checks on the first batch that the stacked losses equal the
members' own; ``step_times`` measures whether the stacked step is faster than the loop's
(``encons.training.ensemble`` picks by it).
"""

from __future__ import annotations

import copy
import inspect
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any, TypeVar, cast

import torch
from torch import Tensor, nn
from torch.func import functional_call, stack_module_state, vjp, vmap

from encons.models.base import DynamicsModel
from encons.models.networks import EnsembleLinear
from encons.models.observation import Observation
from encons.training.module import TrainingModule

M = TypeVar("M", bound=nn.Module)
ELEMENTWISE = ("Adam", "AdamW", "SGD", "RMSprop", "Adamax")  # optimisers whose step acts on each element alone


def stacker(module: nn.Module) -> Callable[[Sequence[Any]], nn.Module] | None:
    """How K members' copies of ``module`` become one module whose own parameters (those not inside a submodule
    that has a stacker too) carry the member axis first, member k's slice being its own parameter of the same name
    (or of the name the module's ``member_parameters()`` gives it): ``EnsembleLinear`` for an ``nn.Linear``, a
    module class's own ``ensemble`` classmethod (``PointMasses``, the INN's ``CouplingBlock``); None for any other
    module."""
    if isinstance(module, nn.Linear):
        return EnsembleLinear
    return getattr(type(module), "ensemble", None)


def stacked_names(modules: Sequence[nn.Module]) -> list[str] | None:
    """The names of ``modules[0]``'s submodules that ``stacker`` takes, outer before inner, where every parameter
    lives inside one of them, the modules share their layout (parameter names) and their buffers outside them are
    equal (a constant shared by all members); else None (also where there is none)."""
    names = [name for name, mod in modules[0].named_modules() if name and stacker(mod) is not None]
    inside = tuple(f"{n}." for n in names)
    if not names or not all(p.startswith(inside) for p, _ in modules[0].named_parameters()):
        return None
    if any([n for n, _ in m.named_parameters()] != [n for n, _ in modules[0].named_parameters()] for m in modules):
        return None
    buffers = [{n: b for n, b in m.named_buffers() if not n.startswith(inside)} for m in modules]
    if any(b.keys() != buffers[0].keys() or not all(torch.equal(b[n], buffers[0][n]) for n in b) for b in buffers):
        return None
    return names


def ensemble_copy(modules: Sequence[M], names: Sequence[str]) -> M:
    """A copy of ``modules[0]`` whose submodules ``names`` (``stacked_names``, outer first) are each the
    ``stacker`` of the modules' submodules of that name (an inner one then replaces what its outer one copied):
    every parameter carries the member axis first, and the copy's own code runs once for all members, on rows
    whose leading axis is the member axis or folded member-major into it."""
    stacked = copy.deepcopy(modules[0])
    for name in names:
        parent, _, leaf = name.rpartition(".")
        parts = [m.get_submodule(name) for m in modules]
        setattr(
            stacked.get_submodule(parent) if parent else stacked,
            leaf,
            cast(Callable[[Sequence[Any]], nn.Module], stacker(parts[0]))(parts),  # stacked_names: a stacker's
        )
    return stacked


@torch.no_grad()
def copy_members(stacked: nn.Module, modules: Sequence[nn.Module]) -> None:
    """Write member ``k``'s slice of every parameter of ``stacked`` (an ``ensemble_copy`` of ``modules``) into
    the parameter of the same name in ``modules[k]``: a submodule's own parameters, or what its
    ``member_parameters()`` names (a stacked tensor held in another layout: ``EnsembleLinear``'s)."""
    stacks: dict[str, Tensor] = {}
    for prefix, part in stacked.named_modules():
        own = getattr(part, "member_parameters", lambda: dict(part.named_parameters(recurse=False)))()
        stacks |= {f"{prefix}.{name}" if prefix else name: value for name, value in own.items()}
    write_slices(stacks, modules)


@torch.no_grad()
def write_slices(stacks: dict[str, Tensor], modules: Sequence[nn.Module]) -> None:
    """``modules[k]``'s parameter or buffer of each name in ``stacks`` := slice k of that stacked tensor."""
    for k, module in enumerate(modules):
        own = dict(module.named_parameters()) | dict(module.named_buffers())
        for name, value in stacks.items():
            own[name].copy_(value[k])


def dimension_model(models: Sequence[DynamicsModel]) -> nn.Module | None:
    """``ensemble_copy`` of the models; None where ``stacked_names`` finds no way to stack them."""
    names = stacked_names(models)
    return None if names is None else ensemble_copy(models, names)


def stacked_observation(observations: Sequence[Observation]) -> Observation | None:
    """The members' observation models as one: None for the identity (the stacked training's default), else
    ``ensemble_copy`` of them (an autoencoder's encoder and decoder: one batched product per layer for all
    members, on the member-major folded rows the stacked training passes; ``why_not`` refuses an observation
    with a parameter outside ``nn.Linear`` layers and modules that define ``ensemble``)."""
    if observations[0].identity:
        return None
    names = stacked_names(observations)
    assert names is not None  # why_not refused the run otherwise
    return ensemble_copy(observations, names)


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

    Its ``forward(t, z, u)``, ``to_internal``, ``from_internal``, ``residual`` and ``rollout`` take tensors whose
    leading axis is the member axis folded into the batch (member-major: rows ``k·N … (k+1)·N − 1`` are member
    ``k``'s) and return the same layout: each member's own call on its rows, by the ensemble dimension in the
    layers (``dimension``, where ``dimension_model`` allows it: measured faster than ``vmap``), else by ``vmap``
    over the member axis of ``functional_call`` on one template. ``rollout_scope`` is the dimension's own (a
    per-rollout cache holds every member's), empty under ``vmap`` (the template's cache would be one member's, so
    each field evaluation computes it from the member's weights instead). ``penalty`` gives a regulariser per
    member.
    """

    def __init__(self, models: Sequence[DynamicsModel], dimension: bool = True):
        super().__init__()
        self.k = len(models)
        self.dimension = dimension_model(models) if dimension else None
        if self.dimension is not None:
            self.names, self.buffer_names = [], []
            self.weights = nn.ParameterList(list(self.dimension.parameters()))  # each member-stacked
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
        others (times, None) are shared by all members. The result is folded the same way where an argument was
        (one number per member stays (K,)), else it gets a leading member axis."""
        template = _Call(self.__dict__["template"], fn)
        params, buffers = self.member_weights()
        params = {f"model.{n}": v for n, v in params.items()}
        buffers = {f"model.{n}": v for n, v in buffers.items()}
        dims = tuple(0 if f else None for f in folded)
        args = tuple(self.fold(a) if f else a for a, f in zip(args, folded))
        out = vmap(lambda p, b, *xs: functional_call(template, (p, b), xs), in_dims=(0, 0, *dims))(
            params, buffers, *args
        )
        return out.reshape(-1, *out.shape[2:]) if any(folded) else out

    def call(self, name: str, args: tuple, folded: tuple[bool, ...]) -> Any:
        """The template's method ``name`` for all members: with the ensemble dimension in its layers, one call on
        the ``folded`` arguments unfolded to (K, N, ...) (the model's code broadcasts over the extra leading
        axis); else ``per_member``."""
        if self.dimension is None:
            return self.per_member(name, args, folded)
        out = getattr(self.dimension, name)(*(self.fold(a) if f else a for a, f in zip(args, folded)))
        return out.reshape(-1, *out.shape[2:])

    def forward(self, t: Tensor, z: Tensor, u: Tensor | None = None) -> Tensor:
        return (
            self.call("forward", (t, z), (False, True))
            if u is None
            else self.call("forward", (t, z, u), (False, True, True))
        )

    def to_internal(self, s: Tensor) -> Tensor:
        return self.call("to_internal", (s,), (True,))

    def from_internal(self, z: Tensor) -> Tensor:
        return self.call("from_internal", (z,), (True,))

    def residual(self, states: Tensor, t: Tensor, u: Tensor | None = None) -> Tensor:
        return (
            self.call("residual", (states, t), (True, False))
            if u is None
            else self.call("residual", (states, t, u), (True, False, True))
        )

    def rollout(self, start: Tensor, t: Tensor, u: Tensor | None = None) -> Tensor:
        """A discrete model's rollout (SyMo/E2E-SyMo: Newton iterations, each sample of each member converging on
        its own), with the ensemble dimension only: ``vmap`` cannot pass its stopping test."""
        return (
            self.call("rollout", (start, t), (True, False))
            if u is None
            else self.call("rollout", (start, t, u), (True, False, True))
        )

    @contextmanager
    def rollout_scope(self) -> Iterator[None]:
        """The ensemble dimension's own (a per-rollout cache, e.g. CHNN/CLNN's inverse masses, holds every
        member's); none under ``vmap`` (each field evaluation computes it from the member's weights)."""
        if self.dimension is None:
            yield
            return
        with cast(DynamicsModel, self.dimension).rollout_scope():
            yield

    def penalty(self, regulariser: Any, points: Tensor, u: Tensor | None) -> Tensor:
        """``regulariser(member, points, u)`` of every member (K,), each at its own rows of ``points`` and ``u``
        (folded member-major: the batch's states, or each member's own encodings of its frames). With the
        ensemble dimension (``dimension_penalty``: a Jacobian penalty on the default constrained field), every
        member's per-sample Jacobians come from one reverse pass through the whole stacked field on its rows
        repeated once per field dimension j, each copy's cotangent e_j (the rows are independent, so copy j of
        row b gives row j of row b's Jacobian). Not ``vmap`` of the pullback over the e_j: its batching rule for
        ``bmm`` broadcasts every (K, in, out) weight to (d, K, in, out) and copies it, per layer and step
        (``benchmarks/reports/ensemble_speed/cells.md``); the stacked rows stay member-major. Else ``per_member``
        (one number per member: (K,))."""
        if self.dimension is None:
            return self.per_member(regulariser, (points, u), (True, u is not None))
        z = self.to_internal(points)
        d = z.shape[-1]

        def repeated(x: Tensor) -> Tensor:  # (K·N, m) -> (K·d·N, m): member k's N rows, d times, member-major
            return x.reshape(self.k, 1, -1, x.shape[-1]).expand(-1, d, -1, -1).reshape(-1, x.shape[-1])

        rows, controls = repeated(z), None if u is None else repeated(u)
        t = torch.zeros((), dtype=points.dtype, device=points.device)
        _, pullback = cast(
            "tuple[Tensor, Callable]", vjp(lambda r: self(t, r) if u is None else self(t, r, controls), rows)
        )
        basis = (
            torch.eye(d, dtype=z.dtype, device=z.device)
            .reshape(1, d, 1, d)
            .expand(self.k, -1, z.shape[0] // self.k, -1)
        )
        (grad,) = pullback(basis.reshape(-1, d))
        jac = grad.reshape(self.k, d, -1, d).transpose(1, 2).reshape(-1, d, d)  # (K·N, d out, d in)
        return regulariser.weight * regulariser.violation(jac).reshape(self.k, -1).mean(1)

    @torch.no_grad()
    def copy_to(self, models: Sequence[nn.Module]) -> None:
        """Write member ``k``'s slices into ``models[k]``'s own parameters and buffers."""
        if self.dimension is not None:
            copy_members(self.dimension, models)
            return
        params, buffers = self.member_weights()
        write_slices(params | buffers, models)


def dimension_penalty(model: DynamicsModel, regulariser: Any) -> bool:
    """Whether ``StackedModel.penalty`` takes ``regulariser`` with the ensemble dimension: a Jacobian penalty
    (``encons.numerics.regularisers.JacobianPenalty``: a weight and a violation per Jacobian) of the default constrained
    field (the internal field at ``to_internal(s)``; an INN's latent field is another)."""
    return (regulariser is None or callable(getattr(regulariser, "violation", None))) and type(
        model
    ).constrained_field is DynamicsModel.constrained_field


class StackedTraining(TrainingModule):
    """The training objective of all members at once: a ``TrainingModule`` on a ``StackedModel`` (and, under an
    observation model, on its ``stacked_observation``) whose ``reduce`` means each member's rows, so ``loss``
    returns the K members' losses."""

    model: StackedModel  # type: ignore[assignment]  # stands in for the DynamicsModel: forwards what it lacks to one

    def reduce(self, terms: Tensor) -> Tensor:
        return terms.reshape(self.model.k, -1).mean(1)

    def regularise(self, points: Tensor, u: Tensor | None) -> Tensor:
        return self.model.penalty(self.regulariser, points, u)

    def member_losses(self, batch: dict) -> tuple[Tensor, Tensor | None]:
        """The K members' objectives on ``batch`` and their regulariser's penalties (None: no regulariser);
        a member's training loss is their sum."""
        k = self.model.k
        folded = {key: v.repeat(k, *[1] * (v.dim() - 1)) for key, v in batch.items() if isinstance(v, Tensor)}
        return self.loss(folded), self.penalty(folded)

    def training_loss(self, batch: dict) -> Tensor:
        """The K members' training losses (K,): each objective plus its penalty."""
        objective, penalty = self.member_losses(batch)
        return objective if penalty is None else objective + penalty

    def copy_to(self, members: Sequence[TrainingModule]) -> None:
        """Write member ``k``'s slices of the stacked weights into ``members[k]``'s model and observation."""
        self.model.copy_to([m.model for m in members])
        if not self.observation.identity:
            copy_members(self.observation, [m.observation for m in members])


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
    """Why the members cannot train stacked (None: they can), from the model, observation and settings alone."""
    member = members[0]
    if not member.observation.identity and stacked_names([m.observation for m in members]) is None:
        return (
            f"observation={type(member.observation).__name__} has a parameter outside nn.Linear layers and modules "
            "that define ensemble"
        )
    if cfg.get("compile"):
        return "compile=true compiles one model's field"
    opt = member.optimizer.func if hasattr(member.optimizer, "func") else member.optimizer
    if getattr(opt, "__name__", "") not in ELEMENTWISE:
        return (
            f"optimizer {getattr(opt, '__name__', opt)} may mix elements across members; allowed stacked: "
            f"{', '.join(ELEMENTWISE)}"
        )
    return None


def step_times(
    stacked: StackedTraining, members: Sequence[TrainingModule], batch: dict, repeats: int = 2
) -> tuple[float, float]:
    """Seconds of one forward and backward of the members' training losses on ``batch``: stacked, and member by
    member (the loop path), the faster of ``repeats`` after a warm-up; the gradients are cleared after."""

    def step_stacked() -> None:
        stacked.training_loss(batch).sum().backward()

    def step_loop() -> None:
        for m in members:
            m.training_loss(batch).backward()

    best = []
    for step, modules in ((step_stacked, [stacked]), (step_loop, members)):
        times = []
        for _ in range(repeats + 1):
            started = time.perf_counter()
            step()
            times.append(time.perf_counter() - started)
        for module in modules:
            module.zero_grad(set_to_none=True)
        best.append(min(times[1:]))
    return best[0], best[1]


def float64_batch(batch: dict) -> dict:
    """``batch`` with its floating tensors in float64 (what ``probe`` compares its float64 copies on)."""
    return {k: v.double() if isinstance(v, Tensor) and v.is_floating_point() else v for k, v in batch.items()}


def probe(stacked: StackedTraining, members: Sequence[TrainingModule], batch: dict, rtol: float = 1e-4) -> str | None:
    """None when the stacked losses on ``batch`` equal each member's own (relative ``rtol``), else why not
    (the first line of the error the stacked forward raised, e.g. ``vmap``'s at a data-dependent branch).

    Compared in float64, on copies: what the probe asks is whether the stacked code computes each member's loss,
    and a float32 loss can be good to less than ``rtol`` whichever way it is computed. Lim & Kasim's NSF at its
    own sizes (a 2-form made of differences of derivatives, inverted) gave a member's separate float32 loss 8.6e-5
    from its float64 value and the stacked one 1.2e-4, 2e-4 apart, and a float32 probe sent that ensemble down
    the slower ``vmap`` path (``benchmarks/reports/ensemble_speed/cells.md``, "The probe in float64"). A model
    that does not run in float64 (a user's that makes float32 tensors of its own) is compared as it trains."""
    wide = (copy.deepcopy(stacked).double(), [copy.deepcopy(m).double() for m in members])
    batch64 = float64_batch(batch)
    try:
        want = torch.stack([m.training_loss(batch64).detach() for m in wide[1]])
        stacked, batch = wide[0], batch64
    except Exception:  # noqa: BLE001 - any failure in float64: the members' own losses as they train
        want = torch.stack([m.training_loss(batch).detach() for m in members])
    try:
        got = stacked.training_loss(batch).detach()
    except Exception as err:  # noqa: BLE001 - any failure of the stacked forward sends the run down the loop path
        return f"the stacked field failed ({type(err).__name__}: {str(err).splitlines()[0]})"
    diff = ((got - want).abs() / want.abs().clamp_min(1e-12)).max()
    if not bool(diff <= rtol):
        return f"the stacked losses differ from the members' own by {float(diff):.2g} (relative) on the first batch"
    return None
