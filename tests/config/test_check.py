"""One validation pass (``encons.config.check.validate``): every check once, a frozen ``Checked`` value that
``build`` instantiates without checking or looking anything up again; checks neither write folders nor
change the config."""

from __future__ import annotations

from collections import Counter

import pytest
from omegaconf import OmegaConf
from omegaconf.errors import ReadonlyConfigError

import encons
from encons import build
from encons.config import check as config
from encons.config import trust
from encons.training import runs


@pytest.fixture
def lookups(monkeypatch) -> Counter:
    """Every ``encons.config.trust.locate`` call, by target."""
    counted: Counter = Counter()
    real = trust.locate

    def locate(target, *args, **kwargs):
        counted[target] += 1
        return real(target, *args, **kwargs)

    monkeypatch.setattr(trust, "locate", locate)
    return counted


def fast(tmp_path, *overrides):
    return encons.compose(
        "model=hnn",
        "system=pendulum1",
        "debug=fast",
        "logger=none",
        *overrides,
        output_dir=tmp_path / "run",
        cache_dir=tmp_path / "cache",
    )


@pytest.mark.parametrize("extra", [[], ["seeds=[0,1]"]])  # a run; a seed ensemble (its members derive from it)
def test_a_run_validates_once_and_looks_each_target_up_once(tmp_path, monkeypatch, lookups, extra):
    """Composing looks the model up once (its presets); the run, every target once more at most."""
    cfg = fast(tmp_path, *extra)
    assert lookups == Counter({"encons.models.hnn.HNN": 1})
    lookups.clear()
    calls = []
    real = config.validate

    def validate(*args, **kwargs):
        calls.append(args)
        return real(*args, **kwargs)

    for module in (config, build, runs):
        monkeypatch.setattr(module, "validate", validate)
    run = encons.train(cfg, summary=False)
    assert len(calls) == 1
    assert "encons.models.hnn.HNN" in lookups and max(lookups.values()) == 1, lookups
    assert run.metrics["test/traj_rel_err"] > 0


@pytest.mark.parametrize("extra", [[], ["seeds=[0,1]"]])
def test_evaluate_validates_once(tmp_path, monkeypatch, extra):
    """``encons.evaluate RUN`` (a run's folder; an ensemble's: once per member, each a run of its own)."""
    trained = encons.train(fast(tmp_path, *extra), summary=False)
    calls = []
    real = config.validate
    monkeypatch.setattr(runs, "validate", lambda *a, **k: calls.append(a) or real(*a, **k))
    monkeypatch.setattr(config, "validate", lambda *a, **k: calls.append(a) or real(*a, **k))
    metrics = encons.evaluate(trained.run_dir)
    assert len(calls) == (1 if not extra else 2)
    assert metrics["test/traj_rel_err"] == pytest.approx(trained.metrics["test/traj_rel_err"], rel=1e-12)


def test_a_second_build_of_a_checked_value_looks_nothing_up(tmp_path, lookups):
    checked = config.validate(fast(tmp_path))
    assert checked.model.__name__ == "HNN" and checked.objective == "rollout"
    lookups.clear()
    first = encons.build(checked)
    second = encons.build(checked)
    assert lookups == Counter()
    assert type(first[1].model) is type(second[1].model) is checked.model


def test_validation_writes_no_folder_changes_no_key_and_its_value_is_frozen(tmp_path):
    cfg = fast(tmp_path)
    before = OmegaConf.to_yaml(cfg)
    checked = config.validate(cfg)
    assert OmegaConf.to_yaml(cfg) == before and not (tmp_path / "run").exists() and not (tmp_path / "cache").exists()
    with pytest.raises(ReadonlyConfigError):
        checked.cfg.model.hidden = 3
    cfg.model.hidden = 3  # the user's config stays theirs
    assert checked.cfg.model.hidden == 16


def test_presets_are_applied_when_composing_not_when_checking(tmp_path, monkeypatch):
    """``preset_keys`` (``debug=fast``'s ``model.hidden``) are dropped from a node that does not take them by
    ``encons.compose`` (and the CLI's job), once; validation does not rewrite the config."""
    applied = []
    real = config.apply_presets
    monkeypatch.setattr(build, "apply_presets", lambda cfg, request: (applied.append(cfg), real(cfg, request)))
    cfg = fast(tmp_path)
    assert applied == [cfg]
    monkeypatch.setattr(config, "apply_presets", lambda *a: pytest.fail("validation applied presets"))
    config.validate(cfg)
