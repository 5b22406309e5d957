"""Every key a sweep (``sweeps/``), a benchmark profile (``conf/profile/``) or an experiment
(``conf/experiment/``) sets is one the run it configures reads: a key of the composed training config, or a
constructor parameter of some option of its group (``model.guard`` is read by LNN and GLNN only). A key
nothing reads — ``optim.weight_decay`` for ``optimizer.weight_decay`` — would silently leave the default."""

from __future__ import annotations

import importlib
import inspect
from functools import cache
from pathlib import Path

import pytest
import yaml
from omegaconf import OmegaConf

ROOT = Path(__file__).parents[2]
CONF = ROOT / "conf"


@cache
def base():
    from encons.entry import api

    return OmegaConf.to_container(api.compose(), resolve=False)


def _has(tree, key: str) -> bool:
    for part in key.split("."):
        if not isinstance(tree, dict) or part not in tree:
            return False
        tree = tree[part]
    return True


@cache
def group_parameters(group: str) -> frozenset[str]:
    """Constructor parameters of every option of ``conf/<group>/`` (its ``_target_``s), and their YAML keys."""
    names: set[str] = set()
    for option in (CONF / group).glob("*.yaml"):
        node = yaml.safe_load(option.read_text()) or {}
        node = node.get(group, node) if isinstance(node.get(group), dict) else node  # a @package _global_ option
        names |= set(node)
        target = node.get("_target_")
        if target:
            module, _, attr = target.rpartition(".")
            obj = getattr(importlib.import_module(module), attr)
            for cls in obj.__mro__ if inspect.isclass(obj) else [obj]:
                try:
                    names |= set(inspect.signature(cls).parameters)
                except (TypeError, ValueError):
                    pass
    return frozenset(names)


def _signature(target: str) -> set[str]:
    module, _, attr = target.rpartition(".")
    return set(inspect.signature(getattr(importlib.import_module(module), attr)).parameters)


def unread(key: str, tree: dict | None = None) -> bool:
    """Whether no run reads the training-config ``key`` (``tree``: the file that sets it, whose own
    ``_target_`` nodes declare what their keys feed)."""
    key = key.lstrip("+~")
    if "/" in key or (CONF / key).is_dir() or key.startswith("preset_keys.") or _has(base(), key):
        return False  # a group choice (model, hydra/launcher), a preset's key list, a key of the config
    parts = key.split(".")
    node = tree or {}
    for i, part in enumerate(parts[:-1]):
        node = node.get(part) if isinstance(node, dict) else None
        if isinstance(node, dict) and "_target_" in node:  # a node this file instantiates itself
            return parts[i + 1] not in {"_target_", "_partial_", *_signature(node["_target_"])}
    head, _, param = key.partition(".")
    if head == "trainer":
        import lightning

        return param.split(".")[0] not in inspect.signature(lightning.Trainer).parameters
    return not ((CONF / head).is_dir() and param.split(".")[0] in group_parameters(head))


def flat(tree: dict, prefix: str = "") -> list[str]:
    """Dotted keys of the leaves of a nested mapping (a list or an empty mapping is a leaf)."""
    return [
        k
        for key, value in tree.items()
        for k in (flat(value, f"{prefix}{key}.") if isinstance(value, dict) and value else [f"{prefix}{key}"])
    ]


def run_config_keys(path: Path) -> list[str]:
    """The training-config keys an experiment or sweep file sets (its swept parameters included)."""
    node = yaml.safe_load(path.read_text()) or {}
    node.pop("defaults", None)
    hydra = node.pop("hydra", {}) or {}
    keys = flat(node)
    keys += list(((hydra.get("sweeper") or {}).get("params") or {}))
    return keys


def override_keys(overrides: list) -> list[str]:
    return [o.split("=", 1)[0] for o in overrides if isinstance(o, str) and "=" in o]


def profile_keys(path: Path) -> tuple[list[str], list[str]]:
    """(keys of the profile itself, training-config keys of every override it gives its runs)."""
    node = yaml.safe_load(path.read_text()) or {}
    train = override_keys(node.get("common", []))
    for section in ("per_system", "per_model", "per_family", "per_n_train"):
        for overrides in (node.get(section) or {}).values():
            train += override_keys(overrides)
    for run in node.get("runs", []):
        train += override_keys(run.get("overrides", []))
    for model in node.get("n_train_models", []):
        if isinstance(model, dict):
            train += override_keys(model.get("overrides", []))
    return list(node), train


FILES = sorted([*(ROOT / "sweeps").glob("*.yaml"), *(CONF / "experiment").glob("*.yaml")])


@pytest.mark.parametrize("path", FILES, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_every_key_of_a_sweep_or_experiment_is_read(path):
    tree = yaml.safe_load(path.read_text())
    bad = [k for k in run_config_keys(path) if not k.startswith("sweeps.") and unread(k, tree)]
    assert not bad, f"{path.relative_to(ROOT)} sets keys no run reads: {bad}"


@pytest.mark.parametrize("path", sorted((CONF / "profile").glob("*.yaml")), ids=lambda p: p.name)
def test_every_key_of_a_profile_is_read(path):
    benchmark = yaml.safe_load((CONF / "benchmark.yaml").read_text())
    own, train = profile_keys(path)
    assert not [k for k in own if k not in benchmark], f"{path.name}: keys conf/benchmark.yaml does not have"
    bad = [k for k in train if unread(k)]
    assert not bad, f"{path.relative_to(ROOT)} gives its runs keys no run reads: {bad}"


def test_a_planted_unread_key_fails(tmp_path):
    planted = tmp_path / "planted.yaml"
    planted.write_text("optim:\n  weight_decay: 0.0\noptimizer:\n  weight_decay: 0.0\n")
    assert [k for k in run_config_keys(planted) if unread(k)] == ["optim.weight_decay"]
    assert unread("model.no_such_width") and not unread("model.guard") and not unread("trainer.max_epochs")
