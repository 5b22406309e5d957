"""One validation pass (``encons.config.check.validate``): every check once, a frozen ``Checked`` value that
``build`` instantiates without checking or looking anything up again; checks neither write folders nor
change the config."""

from __future__ import annotations

import sys
from collections import Counter
from dataclasses import dataclass, field

import pytest
from omegaconf import OmegaConf
from omegaconf.errors import ReadonlyConfigError

import encons
from encons.config import check as config
from encons.config import trust
from encons.training import build


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


@dataclass
class Counted:
    """The ``validate`` calls and ``locate`` lookups (by target) made since the last :meth:`clear`."""

    validations: list = field(default_factory=list)
    lookups: Counter = field(default_factory=Counter)

    def clear(self) -> None:
        self.validations.clear()
        self.lookups.clear()

    def once(self, validations: int = 1) -> None:
        """``validations`` validations, and no ``_target_`` looked up twice."""
        assert len(self.validations) == validations, self.validations
        assert self.lookups and max(self.lookups.values()) == 1, self.lookups


@pytest.fixture
def counted(monkeypatch) -> Counted:
    """``encons.config.check.validate`` and ``encons.config.trust.locate`` counted under every name an encons
    module holds them by (``from encons.config.check import validate`` included)."""
    import encons.tools.benchmark  # noqa: F401 - the paths below, imported before their names are replaced
    import encons.tools.sweep  # noqa: F401
    from encons.entry import cli  # noqa: F401
    from encons.training import ensemble, runs  # noqa: F401

    seen = Counted()
    real_validate, real_locate = config.validate, trust.locate

    def validate(*args, **kwargs):
        seen.validations.append(args[0])
        return real_validate(*args, **kwargs)

    def locate(target, *args, **kwargs):
        seen.lookups[target] += 1
        return real_locate(target, *args, **kwargs)

    for module in [m for name, m in sys.modules.items() if name.startswith("encons") and m is not None]:
        for name, value in list(vars(module).items()):
            if value is real_validate:
                monkeypatch.setattr(module, name, validate)
            elif value is real_locate:
                monkeypatch.setattr(module, name, locate)
    return seen


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
def test_a_run_validates_once_and_looks_each_target_up_once(tmp_path, counted, extra):
    """From compose to the test: one validation; composing looks the model up (its presets), the run
    every other target, each once."""
    run = encons.train(fast(tmp_path, *extra), summary=False)
    counted.once()
    assert "encons.models.hnn.HNN" in counted.lookups and "lightning.pytorch.Trainer" in counted.lookups
    assert run.metrics["test/traj_rel_err"] > 0


@pytest.mark.parametrize("extra", [[], ["seeds=[0,1]"]])
def test_evaluate_validates_once(tmp_path, counted, extra):
    """``encons.evaluate RUN`` (a run's folder; an ensemble's: once per member, each a run of its own),
    each target looked up once per validation; a run in memory carries its checked config: none."""
    trained = encons.train(fast(tmp_path, *extra), summary=False)
    counted.clear()
    metrics = encons.evaluate(trained.run_dir)
    assert metrics["test/traj_rel_err"] == pytest.approx(trained.metrics["test/traj_rel_err"], rel=1e-12)
    if extra:
        assert len(counted.validations) == 2 and set(counted.lookups.values()) == {2}
        return
    counted.once()
    counted.clear()
    encons.evaluate(trained)
    assert counted.validations == [] and counted.lookups == Counter()


@pytest.mark.parametrize("seeds", [[0], [0, 1]])  # a cell of one run (run_one); of a seed ensemble (run_ensemble)
def test_a_benchmark_cell_validates_once_and_looks_each_target_up_once(tmp_path, counted, seeds):
    from encons.tools import benchmark
    from encons.training.build import compose

    profile = compose(
        ["profile=smoke", "models=[hnn]", "n_train=[]", f"seeds={seeds}", f"out={tmp_path / 'out'}"],
        config_name="benchmark",
    )
    planned = benchmark.expand(profile)
    assert len(planned) == len(seeds)
    counted.clear()
    rows = (
        [benchmark.run_one(planned[0], tmp_path / "out", str(tmp_path / "cache"))]
        if len(seeds) == 1
        else benchmark.run_ensemble(planned, tmp_path / "out", str(tmp_path / "cache"))
    )
    assert [r["error"] for r in rows] == [""] * len(seeds)
    counted.once()


def test_a_sweep_trial_validates_once_and_looks_each_target_up_once(tmp_path, counted, cli, monkeypatch):
    monkeypatch.setenv("ENCONS_ROOT", str(tmp_path))
    args = ["model=node", "system=pendulum1", "debug=fast", "test=false", "sweeps=chnn_tuning"]
    proc = cli("-m", *args, "hydra.sweeper.n_trials=1", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    counted.once()
    assert "encons.models.node.NODE" in counted.lookups and "optuna.pruners.MedianPruner" in counted.lookups


def test_a_builder_takes_a_checked_config_only(tmp_path):
    from encons.training.build import build_system

    cfg = fast(tmp_path)
    with pytest.raises(TypeError, match=r"^build_system takes a Checked config"):
        build_system(cfg)
    assert type(build_system(config.validate(cfg))).__name__ == "NPendulum"


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
