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


# -- declared extension points (issue 49): each added from a folder outside the package --------------------------

USER_SYSTEM = '''
"""A user's controlled system: a point mass on a massless rod, torque at the pivot, θ from upright."""
import math

import torch

from encons.systems.controlled import ControlledMechanical, ControllerSettings


class PointPendulum(ControlledMechanical):
    angles = (True,)
    input_unit = "user N m"
    controller = ControllerSettings(
        gain_energy=1.0,
        q_weights=(10.0, 1.0),
        r_weight=1.0,
        switch=20.0,
        tolerance=(0.1, 0.5),
        duration=3.0,
        hold=1.0,
        start_range=(0.05, 0.05),  # near upright: the LQR's basin
    )

    def __init__(self, mass=1.0, length=1.0, g=9.81, init_range=(math.pi, 2.0), u_max=5.0):
        super().__init__(init_range, u_max)
        self.name = "point_pendulum"
        self.m, self.l, self.g = float(mass), float(length), float(g)

    def mass_matrix(self, q):
        return torch.full((*q.shape, 1), self.m * self.l**2, dtype=q.dtype, device=q.device)

    def potential(self, q):
        return self.m * self.g * self.l * (1 + torch.cos(q[..., 0]))

    def bias(self, q, qd):
        return -self.m * self.g * self.l * torch.sin(q)

    def input_matrix(self):
        return torch.ones(1, 1, dtype=torch.float64)
'''

USER_MODEL = '''
"""A user's model with an energy: M(q) = a, V(q) = b (1 + cos q), the input through the system's B."""
import torch
from torch import nn

from encons.models.base import DynamicsModel, EnergyStructure
from encons.models.lnode import forced_euler_lagrange


class EnergyPendulum(DynamicsModel):
    default_chart = "angle"
    supports_controls = True
    family = "user_energy"

    def __init__(self, system, chart=None, mass: float = 0.3, weight: float = 5.0):
        super().__init__(system, chart)
        self.a, self.b = nn.Parameter(torch.tensor(mass)), nn.Parameter(torch.tensor(weight))
        self.register_buffer("b_matrix", system.input_matrix().float())

    def mass(self, q):
        return self.a * torch.ones(*q.shape, 1, dtype=q.dtype, device=q.device)

    def potential(self, q):
        return self.b * (1 + torch.cos(q[..., 0]))

    def energy_structure(self):
        return EnergyStructure(self.mass, self.potential, self.b_matrix)

    def forward(self, t, s, u=None):
        return forced_euler_lagrange(self.mass, self.potential, self.b_matrix, s, u)
'''

USER_HEADLINE_EVALUATOR = (
    USER_EVALUATOR
    + """

class DeclaredLargestState(LargestState):
    headline = ("declared_largest_state",)

    def compute(self, module):
        return Result({"declared_largest_state": self.scale * self.largest})
"""
)


@pytest.fixture
def outside(tmp_path, monkeypatch):
    """A user's package ``mypkg`` and config folder ``myconf`` outside encons (``docs/extending.md``): a controlled
    system, a model with an energy and two evaluators (one declaring its headline), trusted by
    ``ENCONS_TRUSTED_TARGETS``; returns the ``hydra.searchpath`` override."""
    import sys

    files = {
        "mypkg/__init__.py": "",
        "mypkg/swing.py": USER_SYSTEM,
        "mypkg/energy.py": USER_MODEL,
        "mypkg/largest.py": USER_HEADLINE_EVALUATOR,
        "myconf/system/point_pendulum.yaml": "# @package _global_\nsystem:\n  _target_: mypkg.swing.PointPendulum\n"
        "  u_max: 5.0\ndata:\n  dt: 0.1\n  chunk_len: 3\n",
        "myconf/model/energy_pendulum.yaml": "_target_: mypkg.energy.EnergyPendulum\nchart: null\nmass: 0.3\n",
        "myconf/evaluators/largest.yaml": "# @package evaluators.largest\n_target_: mypkg.largest.LargestState\n",
        "myconf/evaluators/declared.yaml": "# @package evaluators.declared\n"
        "_target_: mypkg.largest.DeclaredLargestState\n",
    }
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("ENCONS_TRUSTED_TARGETS", "mypkg.*")
    for module in [m for m in sys.modules if m == "mypkg" or m.startswith("mypkg.")]:
        monkeypatch.delitem(sys.modules, module)
    return f"hydra.searchpath=[file://{tmp_path / 'myconf'}]"


CONTROL_TINY = [
    "debug=fast",
    "logger=none",
    "figures=false",
    "trainer.max_epochs=1",
    "trainer.enable_progress_bar=false",
]


def test_a_users_controlled_system_is_scored_with_the_controller_settings_its_class_declares(tmp_path, outside):
    """One class (``controller``, ``input_unit`` declared on it) and one YAML: the control path scores a run on it
    with those settings (its duration, its starts near upright where the true LQR holds every one)."""
    import json

    from encons.tools.control import printed_rows, score_control, settings_record

    cfg = encons.compose(
        *CONTROL_TINY, "model=lnode", "system=point_pendulum", outside, output_dir=tmp_path / "run", cache_dir=tmp_path
    )
    run = encons.train(cfg)
    declared = type(run.module.system).controller
    metrics = score_control(run, starts=4)
    saved = json.loads((tmp_path / "run" / "control" / "control_metrics.json").read_text())
    assert saved["settings"] == json.loads(json.dumps(settings_record(declared))) and saved[
        "duration_s"
    ] == pytest.approx(3.0)
    assert metrics["oracle/success_rate"] == 1.0  # the declared starts: 0.05 rad from upright
    assert "control/success_rate" in metrics and "control/b_rel_err" in metrics
    assert "max_abs_u [user N m]" in [label for label, _ in printed_rows(metrics, run.module.system)]


def test_a_users_model_is_scored_by_the_control_path_through_the_energy_structure_it_declares(tmp_path, outside):
    """One class (``energy_structure()`` declared) and one YAML: the controller is built from the model's own
    M(q), V(q) and B, on encons' controlled pendulum."""
    import torch

    from encons.tools import control

    cfg = encons.compose(
        *CONTROL_TINY,
        "~evaluators/santos",
        "model=energy_pendulum",
        "system=pendulum_control",
        outside,
        output_dir=tmp_path / "run",
        cache_dir=tmp_path,
    )
    run = encons.train(cfg)
    metrics = control.score_control(run, starts=4, duration=3.0)
    assert {"control/success_rate", "control/a_rel_err", "oracle/success_rate"} <= set(metrics)
    plant = control.learned_plant(run.model, run.module.system, cfg.model._target_)
    q = torch.linspace(-3, 3, 7, dtype=torch.float64)[:, None]
    model = run.model.double()
    torch.testing.assert_close(plant.mass(q), model.mass(q).detach())  # the plant is the model's declared M and V
    torch.testing.assert_close(plant.potential(q), model.potential(q).detach())


def test_a_users_model_lands_in_the_family_its_class_declares(outside):
    """A profile's ``per_family`` lists families, not models: the user's model gets its declared family's
    overrides, encons' models theirs."""
    from encons.tools.benchmark import expand

    cfg = compose(
        [
            outside,
            "models=[energy_pendulum,node]",
            "systems=[pendulum_control]",
            '++per_family={user_energy: ["optimizer.lr=0.0123"], unstructured: ["optimizer.lr=0.0456"]}',
        ],
        config_name="benchmark",
    )
    lr = {r.label: compose(r.overrides).optimizer.lr for r in expand(cfg)}
    assert lr == {"energy_pendulum": 0.0123, "node": 0.0456}


def test_every_model_of_encons_declares_its_family():
    """So a profile with ``per_family`` takes any of them once their families are listed."""
    from encons.config.trust import locate
    from encons.training.build import catalogue

    undeclared = [m for m in catalogue("model") if locate(compose([f"model={m}"], ".").model._target_).family is None]
    assert undeclared == []


def test_every_headline_metric_of_the_summary_order_is_declared_by_what_reports_it():
    """``report.ORDER`` only places metrics; what shows is declared: encons' evaluators, models and control tool
    declare exactly the metrics it places (besides ``wall_time_s``, the benchmark's own)."""
    from omegaconf import OmegaConf

    from encons.config.trust import locate
    from encons.infra.paths import config_dir
    from encons.tools import control, report
    from encons.training.build import catalogue

    declared = {"wall_time_s", *(f"test/{k}" for k in control.HEADLINE)}
    for group in ("evaluators", "model"):
        for name in catalogue(group):
            target = (
                OmegaConf.load(Path(config_dir()) / group / f"{name}.yaml")._target_
                if group == "evaluators"
                else compose([f"model={name}"], ".").model._target_
            )
            declared |= {f"test/{k}" for k in locate(target).headline}
    assert declared == set(report.ORDER)


def test_a_users_evaluator_puts_the_headline_metric_it_declares_in_a_benchmark_summary(tmp_path, outside):
    """One class (``headline`` declared) and one YAML: its metric is a column of the benchmark summary's headline
    table, after encons' own; an evaluator that declares none only reaches the every-metric table."""
    import json

    from encons.entry.cli import benchmark as main

    out = tmp_path / "bench"
    main(
        [
            outside,
            "profile=smoke",
            "models=[node]",
            "n_train=[]",
            f"out={out}",
            f"cache_dir={tmp_path / 'cache'}",
            'train=["evaluators=[states,largest,declared]","trainer.max_epochs=1"]',
        ]
    )
    (row,) = [json.loads(p.read_text()) for p in (out / "runs").glob("*/result.json")]
    assert row["headline"][-1] == "test/declared_largest_state" and "test/largest_state" not in row["headline"]
    md = (out / "summary.md").read_text()
    headline_table, every_metric = md.split("## Every metric")
    head = headline_table.splitlines()[2].split(" | ")
    assert head[-2:] == ["declared_largest_state", "optimiser |"] and "traj_rel_err" in head
    assert "largest_state" not in head and " largest_state " in every_metric
