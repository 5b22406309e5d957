"""Every declared bound is enforced by the one checker (``encons.infra.bounds``): for every option of
``conf/`` whose target declares ranges, a value just outside each range is refused in one line
naming the user's config path, and the value on the boundary's inside passes."""

from __future__ import annotations

from pathlib import Path

import pytest
from omegaconf import OmegaConf, open_dict

from encons.config import trust
from encons.infra import bounds
from encons.infra.errors import ConfigError
from encons.infra.paths import config_dir
from encons.training.build import Request, check, compose

GROUPS = {
    "model": "model",
    "system": "system",
    "integrator": "integrator",
    "regulariser": "regulariser",
    "observation": "observation",
}


def _options() -> list[tuple[str, str]]:
    conf = Path(config_dir())
    return [
        (group, p.stem)
        for group in GROUPS
        for p in sorted((conf / group).glob("*.yaml"))
        if not p.name.startswith("_") and p.stem not in ("none", "from_file")
    ]


def _outside_inside(bare, rng: bounds.Range) -> list[tuple[float, bool]]:
    """Values just outside (False) and just inside (True) each side of ``rng`` for a value of type ``bare``."""
    step = 1 if bare is int else 1e-6
    cases = []
    if rng.gt is not None:
        cases += [(rng.gt, False), (rng.gt + step, True)]
    if rng.ge is not None:
        cases += [(rng.ge - step, False), (rng.ge, True)]
    if rng.lt is not None:
        cases += [(rng.lt, False), (rng.lt - step, True)]
    if rng.le is not None:
        cases += [(rng.le + step, False), (rng.le, True)]
    return cases + [(float("nan"), False)] * (bare is float)


def _declared(cfg, key: str) -> dict:
    node = OmegaConf.select(cfg, key)
    target = trust.locate(node._target_, key) if "_target_" in node else None
    return {**(bounds.hints(target) if target is not None else {}), **bounds.DECLARED.get(key, {})}


def _check_every_bound(cfg, key: str, declared: dict) -> int:
    """Set each bounded key of node ``key`` just outside and just inside its range; count the checks."""
    checked = 0
    for name, hint in declared.items():
        bare, rng = bounds.split(hint)
        if rng is None:
            continue
        is_list = bounds._matches([1.0], bare) and not bounds._matches(1.0, bare)
        element = int if bounds._matches(1, bare) and not bounds._matches(1.5, bare) else float
        if is_list:
            element = float
        full = f"{key}.{name}" if key else name
        for value, fits in _outside_inside(element, rng):
            value = element(value) if value == value else value
            trial = cfg.copy()
            current = OmegaConf.select(trial, full)
            given = (
                ([*OmegaConf.to_container(current)][:-1] + [value])
                if is_list and current is not None
                else ([value] if is_list else value)
            )
            with open_dict(trial):
                OmegaConf.update(trial, full, given, force_add=True)
            if fits:
                check(trial, Request())
            else:
                with pytest.raises(ConfigError) as err:
                    check(trial, Request())
                line = str(err.value)
                assert line.startswith(f"{full}=") and "; allowed: " in line and "\n" not in line, line
            checked += 1
    return checked


@pytest.mark.parametrize("group, option", _options())
def test_every_declared_bound_of_a_conf_option_is_enforced(tmp_path, group, option):
    extra = ["system=pixel_pendulum"] if group == "observation" else []
    cfg = compose(["debug=fast", f"{group}={option}", *extra], tmp_path / "run", tmp_path / "cache")
    check(cfg, Request())  # the option as shipped passes
    assert _check_every_bound(cfg, GROUPS[group], _declared(cfg, GROUPS[group])) > 0


def test_every_bound_declared_by_a_reader_and_the_data_and_evaluation_nodes_is_enforced(tmp_path):
    from encons.data.datamodule import TrajectoryDataModule

    cfg = compose(
        ["debug=fast", "scheduler=plateau", "optimized_metric=train/loss"], tmp_path / "run", tmp_path / "cache"
    )
    counts = {key: _check_every_bound(cfg, key, declared) for key, declared in bounds.DECLARED.items()}
    # the data's cross-key rules (TrajectoryDataModule.rules: chunk_len <= n_steps + 1, ...) hold at every inside
    # value of one key when the others sit at their least demanding: a window of 2 states
    data = cfg.copy()
    data.data.chunk_len = 2
    counts["data"] = _check_every_bound(data, "data", bounds.hints(TrajectoryDataModule))
    counts["evaluation"] = _check_every_bound(cfg, "evaluation", _declared(cfg, "evaluation"))
    assert set(counts) >= {"", "optimizer", "scheduler", "trainer", "data", "evaluation"}
    assert all(counts.values()), counts


@pytest.mark.parametrize("option", [o for g, o in _options() if g == "system"])
def test_a_system_constructed_directly_refuses_a_value_outside_a_declared_range(option, tmp_path):
    cfg = compose([f"system={option}"], tmp_path / "run", tmp_path / "cache")
    target = trust.locate(cfg.system._target_, "system")
    for name, hint in bounds.hints(target).items():
        bare, rng = bounds.split(hint)
        if rng is None or bounds._matches([1.0], bare) and not bounds._matches(1.0, bare):
            continue
        outside = next(v for v, fits in _outside_inside(float, rng) if not fits)
        with pytest.raises(ConfigError, match=rf"^system\.{name}="):
            target(**{name: outside})


def test_range_words():
    assert [
        str(r)
        for r in (
            bounds.Range(gt=0),
            bounds.Range(ge=1),
            bounds.Range(gt=0, lt=1),
            bounds.Range(ge=0, lt=1),
            bounds.Range(),
            bounds.Range(ge=1, says="a positive integer"),
        )
    ] == ["> 0", ">= 1", "in (0, 1)", "in [0, 1)", "a finite number", "a positive integer"]
    assert 0.5 in bounds.Range(gt=0, lt=1) and 1 not in bounds.Range(gt=0, lt=1)
    assert float("inf") not in bounds.Range() and float("nan") not in bounds.Range(ge=0)
