"""Extending encons without touching it, end to end: a user's optimiser, scheduler and evaluator from their
own config folder, the evaluators' one writer and their refusals, the objectives' registry."""

from __future__ import annotations

from pathlib import Path

import pytest

import encons
from encons.infra.errors import ConfigError
from encons.training.build import compose


def test_a_users_optimizer_and_scheduler_from_a_searchpath_yaml_train(tmp_path):
    """``optimizer`` and ``scheduler`` are ``_partial_`` configs: a user's YAML swaps them, no code."""
    import torch

    for group, name, text in [
        ("optimizer", "sgd", "_target_: torch.optim.SGD\n_partial_: true\nlr: 0.01\nmomentum: 0.9\n"),
        (
            "scheduler",
            "halving",
            "_target_: torch.optim.lr_scheduler.StepLR\n_partial_: true\nstep_size: 1\ngamma: 0.5\n",
        ),
    ]:
        (tmp_path / "myconf" / group).mkdir(parents=True)
        (tmp_path / "myconf" / group / f"{name}.yaml").write_text(text)
    cfg = encons.compose(
        "debug=fast",
        "logger=none",
        "model=node",
        "system=pendulum1",
        f"hydra.searchpath=[file://{tmp_path / 'myconf'}]",
        "optimizer=sgd",
        "scheduler=halving",
        output_dir=tmp_path / "run",
        cache_dir=tmp_path / "cache",
    )
    run = encons.train(cfg)
    optimizer = run.module.trainer.optimizers[0]
    assert type(optimizer) is torch.optim.SGD and optimizer.defaults["momentum"] == 0.9
    epochs = cfg.trainer.max_epochs
    assert optimizer.param_groups[0]["lr"] == pytest.approx(0.01 * 0.5**epochs)  # stepped once an epoch
    assert run.metrics["test/traj_rel_err"] > 0


@pytest.mark.parametrize("history, targets", [(1, [2, 3, 4, 5]), (2, [2, 3, 4, 5]), (3, [3, 4, 5]), (4, [4, 5])])
def test_santos_one_step_targets_are_every_state_from_two_on_for_any_history(history, targets):
    """The windows' last steps are the targets k ≥ max(2, history), each once (history 3 once kept only k = 5)."""
    import torch

    from encons.evaluators.santos import one_step_windows

    states = torch.arange(6.0).reshape(1, 6, 1)  # state k holds the value k
    windows = one_step_windows(states, history)
    assert windows.shape == (len(targets), history + 1, 1)
    assert windows[:, -1, 0].tolist() == targets
    assert torch.equal(windows[:, 0, 0], torch.tensor(targets, dtype=torch.float32) - history)


def test_every_objective_a_model_declares_is_registered():
    from encons.config.trust import locate
    from encons.training.build import catalogue
    from encons.training.objectives import OBJECTIVES

    declared = {
        o for name in catalogue("model") for o in locate(compose([f"model={name}"], ".").model._target_).objectives
    }
    assert declared == set(OBJECTIVES)


@pytest.fixture
def written(monkeypatch):
    """Every path encons writes through ``encons.infra.io`` (every writer does), in order."""
    from encons.infra import io

    paths = []
    real = io.atomic_open
    monkeypatch.setattr(io, "atomic_open", lambda path, *a, **k: (paths.append(Path(path)), real(path, *a, **k))[1])
    return paths


def test_one_writer_saves_the_test_metrics_once_with_every_evaluators_results(tmp_path, written):
    """The states and the controlled-system (Santos) evaluators both reach test_metrics.json, written once
    per test, by one writer; so are test_curves.npz and each evaluator's figures."""
    import json

    cfg = encons.compose(
        "debug=fast",
        "model=lnode",
        "system=pendulum_control",
        "evaluators.santos.steps=10",
        "evaluators.santos.n_trajectories=2",
        output_dir=tmp_path / "run",
        cache_dir=tmp_path / "c",
    )
    assert list(cfg.evaluators) == ["states", "santos"]
    run = encons.train(cfg)
    results = [
        p.relative_to(tmp_path / "run")
        for p in written
        if p.suffix in (".json", ".npz", ".png") and tmp_path / "run" in p.parents
    ]
    assert sorted(map(str, results)) == sorted(map(str, set(results)))  # each file once
    assert {
        Path("test_metrics.json"),
        Path("test_curves.npz"),
        Path("figures/integration.png"),
        Path("figures/rollout.png"),
    } <= set(results)
    saved = json.loads((tmp_path / "run" / "test_metrics.json").read_text())
    assert {"traj_rel_err", "oracle/geom_rel_err", "mse_integration", "mse_test"} <= set(saved)
    assert saved == {k.removeprefix("test/"): v for k, v in run.metrics.items() if k.startswith("test/")}


USER_EVALUATOR = '''
"""A user's evaluator: the largest absolute state of the test rollouts."""
from encons.evaluators import Evaluator, Result


class LargestState(Evaluator):
    def __init__(self, scale: float = 1.0):
        self.scale = scale

    def reset(self):
        self.largest = 0.0

    def update(self, module, batch):
        self.largest = max(self.largest, batch.pred.abs().max().item())

    def compute(self, module):
        return Result({"largest_state": self.scale * self.largest})
'''


def test_a_users_evaluator_from_a_searchpath_yaml_adds_its_metric(tmp_path, monkeypatch, written):
    """One class and one YAML in the user's config folder: its metric joins test_metrics.json beside the
    states evaluator's, from the same rollouts, in the one write of the file."""
    import json

    import torch

    (tmp_path / "mypkg").mkdir()
    (tmp_path / "mypkg" / "__init__.py").write_text("")
    (tmp_path / "mypkg" / "largest.py").write_text(USER_EVALUATOR)
    (tmp_path / "myconf" / "evaluators").mkdir(parents=True)
    (tmp_path / "myconf" / "evaluators" / "largest.yaml").write_text(
        "# @package evaluators.largest\n_target_: mypkg.largest.LargestState\nscale: 2.0\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("ENCONS_TRUSTED_TARGETS", "mypkg.*")
    cfg = encons.compose(
        "debug=fast",
        "logger=none",
        "model=node",
        "system=pendulum1",
        f"hydra.searchpath=[file://{tmp_path / 'myconf'}]",
        "evaluators=[states,largest]",
        output_dir=tmp_path / "run",
        cache_dir=tmp_path / "cache",
    )
    run = encons.train(cfg)
    assert [p.name for p in written].count("test_metrics.json") == 1
    saved = json.loads((tmp_path / "run" / "test_metrics.json").read_text())
    module = run.module
    with torch.no_grad():
        pred = module.predict({"states": run.data.states["test"]}, evaluation=module.evaluation)
    assert saved["largest_state"] == pytest.approx(2.0 * pred.abs().max().item(), rel=1e-12)
    assert "traj_rel_err" in saved and "oracle/traj_rel_err" in saved


@pytest.mark.parametrize("chosen", ["states", "santos"])
def test_an_evaluator_that_does_not_apply_is_refused_in_one_line(tmp_path, chosen):
    cfg = encons.compose(
        "debug=fast",
        "logger=none",
        "system=pixel_pendulum",
        f"evaluators=[{chosen}]",
        output_dir=tmp_path / "run",
        cache_dir=tmp_path / "cache",
    )
    with pytest.raises(
        ConfigError,
        match=rf"^evaluators.{chosen} does not apply to observation=Autoencoder .*; "
        r"allowed: evaluators=\[pixels\]$",
    ):
        encons.entry.api.build(cfg)


def test_two_evaluators_giving_one_metric_name_are_refused(tmp_path):
    import lightning.pytorch as pl

    from encons.evaluators import Evaluator, Result

    class Twice(Evaluator):
        def compute(self, module):
            return Result({"traj_rel_err": 0.0})

    cfg = encons.compose(
        "debug=fast",
        "logger=none",
        "model=node",
        "system=pendulum1",
        output_dir=tmp_path / "run",
        cache_dir=tmp_path / "cache",
    )
    data, module = encons.entry.api.build(cfg)
    module.evaluators["twice"] = Twice()
    trainer = pl.Trainer(logger=False, enable_progress_bar=False, enable_checkpointing=False)
    with pytest.raises(ConfigError, match=r"^evaluators.twice gives the metric 'traj_rel_err' another evaluator"):
        trainer.test(module, datamodule=data, verbose=False)
