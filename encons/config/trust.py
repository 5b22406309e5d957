"""Which ``_target_`` a config may name, checked on the string before anything is imported.

A target is trusted when it matches :func:`trusted_targets` (Hydra's rule: an exact name, or a
package prefix ending in ``.*``), and it resolves to an object defined in the package it names: an
alias such as ``encons.config.trust.os.system`` (a module reached by attribute) is refused. The list is
encons, Lightning, torch's optimisers and schedulers, Optuna's pruners and samplers, and ``ENCONS_TRUSTED_TARGETS`` as
the process environment holds it; a config file cannot widen it (see ``encons.entry.cli``).
"""

from __future__ import annotations

import importlib
import os
import types
from collections.abc import Mapping
from typing import Any, Iterator

from encons.infra.errors import ConfigError

TRUSTED_TARGETS = ("encons.*", "lightning.pytorch.*", "torch.optim.*", "optuna.pruners.*", "optuna.samplers.*")
TRUST_VARIABLE = "ENCONS_TRUSTED_TARGETS"


def trusted_targets() -> tuple[str, ...]:
    """encons' own prefixes and the comma-separated ``ENCONS_TRUSTED_TARGETS`` of the environment."""
    extra = [t.strip() for t in os.environ.get(TRUST_VARIABLE, "").split(",") if t.strip()]
    return (*TRUSTED_TARGETS, *extra)


def is_trusted(target: str, trusted: tuple[str, ...]) -> bool:
    """Hydra's rule: an exact name, or a package prefix ending in ``.*``."""
    return any(target.startswith(p[:-1]) if p.endswith(".*") else target == p for p in trusted)


def _refuse_untrusted(target: str, key: str, trusted: tuple[str, ...]) -> None:
    if not is_trusted(target, trusted):
        raise ConfigError(
            f"{key}._target_={target!r} is not a trusted target; allowed: {', '.join(trusted)} "
            f"(trust your package with {TRUST_VARIABLE}=yourpkg.*)".removeprefix(".")
        )


def locate(target: str, key: str = "", trusted: tuple[str, ...] | None = None) -> Any:
    """The object a trusted ``package.module.Name[.attr]`` names, or None when it does not exist.

    The trust check runs on the string first, so an untrusted module is never imported. A module
    reached by attribute, or an object defined outside the target's top-level package, is an alias
    and refused. A module that exists but fails on one of its own imports raises its own error.
    """
    trusted = trusted_targets() if trusted is None else trusted
    _refuse_untrusted(target, key, trusted)
    parts = target.split(".")
    for split in range(len(parts) - 1, 0, -1):
        module = ".".join(parts[:split])
        try:
            obj: Any = importlib.import_module(module)
        except ModuleNotFoundError as err:
            if err.name is None or not (module == err.name or module.startswith(f"{err.name}.")):
                raise
            continue
        for name in parts[split:]:
            obj = getattr(obj, name, None)
            if obj is None:
                return None
            if isinstance(obj, types.ModuleType):
                _refuse_alias(target, key, f"{name} is a module reached by attribute")
        defined = getattr(obj, "__module__", None) or ""
        if defined.split(".")[0] != parts[0]:
            _refuse_alias(target, key, f"it is {defined or 'an object'}'s, not {parts[0]}'s")
        return obj
    return None


def _refuse_alias(target: str, key: str, why: str) -> None:
    raise ConfigError(
        f"{key}._target_={target!r} is an alias ({why}); allowed: the name where the object is "
        f"defined, in a trusted package".removeprefix(".")
    )


def targets(node: Any, key: str = "") -> Iterator[tuple[str, str]]:
    """Every ``(key, _target_)`` of a plain config (nested dicts and lists), depth first."""
    if isinstance(node, Mapping):
        if isinstance(node.get("_target_"), str):
            yield key, node["_target_"]
        for k, v in node.items():
            yield from targets(v, f"{key}.{k}" if key else str(k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from targets(v, f"{key}[{i}]")


def check_targets(
    cfg: Mapping, trusted: tuple[str, ...] | None = None, located: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """Refuse every ``_target_`` of a plain config that is untrusted, an alias or not importable,
    naming its key; every string is checked before any import. Returns each target string's object,
    each looked up once: ``located`` holds the objects of strings looked up before (by :func:`locate`;
    they are still checked against ``trusted``)."""
    trusted = trusted_targets() if trusted is None else trusted
    found = list(targets(cfg))
    for key, target in found:
        _refuse_untrusted(target, key, trusted)
    located = {t: obj for t, obj in (located or {}).items() if obj is not None and any(t == f for _, f in found)}
    for key, target in found:
        if target in located:
            continue
        located[target] = locate(target, key, trusted)
        if located[target] is None:
            raise ConfigError(
                f"{key}._target_={target!r} cannot be imported; allowed: an importable "
                f"module.Class (your own package on PYTHONPATH)".removeprefix(".")
            )
    return located
