"""Types and ranges of config values, declared beside each parameter and read by one checker.

A constructor that Hydra instantiates declares a parameter's range on its annotation,
``hidden: Count = 64`` or ``g: Annotated[float, Range(ge=0)]`` (a range on a list holds for every
entry); a class built from a config node derives from :class:`Declared`, which checks the ranges of
the arguments it is constructed with too. Keys that no encons constructor takes (``seed``,
``trainer.max_epochs``, a torch optimiser's ``lr``) are declared by the function that reads them,
with :func:`declare`. :func:`check` is the one checker: ``<key>=<value>; allowed: ...``, key being
the config path (``model.hidden``).
"""

from __future__ import annotations

import functools
import inspect
import math
import types
import typing
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Annotated, Any, ClassVar

from encons.infra.errors import ConfigError


@dataclass(frozen=True)
class Range:
    """Bounds of a number (``gt`` < v, ``ge`` <= v, v < ``lt``, v <= ``le``; none: any finite number);
    ``says`` words the allowed values where the inequality is not what a user reads."""

    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    says: str | None = None

    def __contains__(self, value: float) -> bool:
        return (
            math.isfinite(value)
            and (self.gt is None or value > self.gt)
            and (self.ge is None or value >= self.ge)
            and (self.lt is None or value < self.lt)
            and (self.le is None or value <= self.le)
        )

    def __str__(self) -> str:
        if self.says:
            return self.says
        low = f"({self.gt}" if self.gt is not None else f"[{self.ge}" if self.ge is not None else None
        high = f"{self.lt})" if self.lt is not None else f"{self.le}]" if self.le is not None else None
        if low and high:
            return f"in {low}, {high}"
        if low:
            return f"{'>' if low[0] == '(' else '>='} {low[1:]}"
        if high:
            return f"{'<' if high[-1] == ')' else '<='} {high[:-1]}"
        return "a finite number"


Count = Annotated[int, Range(ge=1, says="a positive integer")]
Positive = Annotated[float, Range(gt=0)]
NonNegative = Annotated[float, Range(ge=0)]
Finite = Annotated[float, Range()]
Fraction = Annotated[float, Range(gt=0, lt=1)]
Seed = Annotated[int, Range(ge=0, lt=2**32, says="0..2**32-1 (numpy's seed range)")]

#: Declarations of keys read outside any encons constructor, by config node ("" the top level):
#: filled by :func:`declare` where the reading function is defined.
DECLARED: dict[str, dict[str, Any]] = {}


def declare(node: str, **hints: Any) -> Callable[[Callable], Callable]:
    """Decorate the function that reads keys of ``node`` with their types and ranges (``Annotated`` hints)."""

    def record(fn: Callable) -> Callable:
        DECLARED.setdefault(node, {}).update(hints)
        return fn

    return record


def split(hint: Any) -> tuple[Any, Range | None]:
    """A hint without its ``Annotated`` layers, and the range declared on it (or on its list entries)."""
    origin = typing.get_origin(hint)
    if origin is Annotated:
        bare, inner = split(hint.__origin__)
        return bare, next((m for m in hint.__metadata__ if isinstance(m, Range)), inner)
    if origin in (typing.Union, types.UnionType):
        parts = [split(h) for h in typing.get_args(hint)]
        union: Any = typing.Union  # subscripted below by types computed at run time, which mypy cannot read
        return union[tuple(b for b, _ in parts)], next((r for _, r in parts if r is not None), None)
    if origin in (list, tuple, Sequence):
        args = [split(a) for a in typing.get_args(hint) if a is not Ellipsis]
        generic: Any = origin if origin is not tuple else list  # subscripted by a type computed at run time
        return generic[args[0][0]] if args else hint, (args[0][1] if args else None)
    return hint, None


def hints(target: Any) -> dict[str, Any]:
    """The annotations of ``target``'s constructor (of a function: its parameters), with their ranges;
    empty where they cannot be resolved (they cannot be judged)."""
    return dict(_hints(target))


@functools.cache
def _hints(target: Any) -> tuple[tuple[str, Any], ...]:
    fn = (
        target
        if not inspect.isclass(target)
        else target
        if hasattr(target, "__dataclass_fields__")
        else target.__init__
    )
    try:
        found = typing.get_type_hints(fn, include_extras=True)
    except Exception:  # noqa: BLE001 - an annotation that cannot be resolved cannot be judged
        return ()
    return tuple((k, v) for k, v in found.items() if k != "return")


def check(values: Mapping[str, Any], declared: Mapping[str, Any], key: str, types: bool = True) -> None:
    """Refuse a value of ``values`` whose type does not fit its ``declared`` hint (unless not ``types``; a
    boolean's type is checked always: ``maybe`` or 1 is not true) or
    that lies outside its range (for a list, any entry), naming ``key.name``, the value and what is allowed."""
    for name, value in values.items():
        if name not in declared:
            continue
        bare, bounds = split(declared[name])
        full = f"{key}.{name}" if key else name
        if (types or _boolean(bare)) and not _matches(value, bare):  # a word is never a boolean
            allowed = _type_name(bare) + (
                "" if bounds is None else f", {bounds}" if bounds.says else f", a number {bounds}"
            )
            raise ConfigError(f"{full}={value!r} has type {type(value).__name__}; allowed: {allowed}")
        entries = list(value) if isinstance(value, (list, tuple)) else [value]
        numbers = [v for v in entries if isinstance(v, (int, float)) and not isinstance(v, bool)]
        if bounds is not None and not all(v in bounds for v in numbers):
            every = " (every entry)" if isinstance(value, (list, tuple)) else ""
            raise ConfigError(f"{full}={list(value) if every else value}; allowed: {bounds}{every}")


class Declared:
    """Base of a class built from config node ``config_key``: its constructor's arguments are checked
    against its annotations' ranges (:func:`check`, types left to the config) and its ``rules``
    (:func:`check_rules`) however it is constructed."""

    config_key: ClassVar[str]
    #: Checks between the values of the node that a range cannot say (``chunk_len <= n_steps + 1``): each
    #: ``rule(values, key)`` raises one ``ConfigError`` line; ``values`` hold the constructor's defaults
    #: for what the node leaves out. Run where the node is checked (``encons.config.check``) and on construction.
    rules: ClassVar[tuple[Callable[[Mapping[str, Any], str], None], ...]] = ()

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        init = cls.__dict__.get("__init__")
        if init is None or getattr(init, "_checked", False):
            return

        @functools.wraps(init)
        def checked(self, *args: Any, **kw: Any) -> None:
            bound = inspect.signature(init).bind(self, *args, **kw)
            check({k: v for k, v in bound.arguments.items() if k != "self"}, hints(cls), cls.config_key, types=False)
            check_rules(cls, {k: v for k, v in bound.arguments.items() if k != "self"}, cls.config_key)
            init(self, *args, **kw)

        setattr(checked, "_checked", True)  # a mark on the function, read above by a subclass's subclass
        setattr(cls, "__init__", checked)  # the class's own constructor, replaced by its checked wrapper


def check_rules(target: Any, values: Mapping[str, Any], key: str) -> None:
    """Run the ``rules`` a :class:`Declared` ``target`` declares on the values of its node ``key`` (the
    constructor's defaults filled in for keys the node leaves out); nothing for any other target."""
    rules = getattr(target, "rules", ()) if inspect.isclass(target) and issubclass(target, Declared) else ()
    if not rules:
        return
    params = inspect.signature(target.__init__).parameters.values()
    full = {p.name: p.default for p in params if p.default is not inspect.Parameter.empty}
    full.update(values)
    for rule in rules:
        rule(full, key)


def _boolean(hint: Any) -> bool:
    """Whether a hint is ``bool`` or ``bool | None``: checked for its type even where types are left to the config."""
    return hint is bool or set(typing.get_args(hint)) == {bool, type(None)}


def _type_name(hint: Any) -> str:
    if hint is type(None):
        return "null"
    if hint is bool:
        return "true or false (a bool)"
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return " or ".join(_type_name(h) for h in typing.get_args(hint))
    if typing.get_origin(hint) in (list, tuple, Sequence):
        args = typing.get_args(hint)
        return f"a list of {_type_name(args[0])}" if args else "a list"
    return getattr(hint, "__name__", str(hint))


def _matches(value: Any, hint: Any) -> bool:
    """Whether a config value fits an annotation (without ``Annotated``); annotations it cannot judge pass."""
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        return any(_matches(value, h) for h in typing.get_args(hint))
    if origin in (list, tuple, Sequence):
        args = [a for a in typing.get_args(hint) if a is not Ellipsis]
        return isinstance(value, (list, tuple)) and all(_matches(v, args[0]) for v in value[: len(value) * bool(args)])
    if hint is type(None):
        return value is None
    if hint is bool:
        return isinstance(value, bool)
    if hint is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if hint is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if hint is str:
        return isinstance(value, str)
    return True
