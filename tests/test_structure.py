"""The shape of the package: imports go one way through the layers below, and what the user asked
for is passed down, never read from Hydra's process-global state."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import encons
from encons.build import Request, build_model, build_system, compose
from encons.errors import ConfigError

#: Lowest first. A module may import from its own layer and those before it, never from a later one
#: (imports under ``if TYPE_CHECKING:`` are annotations and those under ``if __name__ == "__main__":``
#: a script's entry, not dependencies: neither is counted).
LAYERS = [
    ["errors", "bounds", "paths", "compat", "trust", "batching", "progress", "io", "checkpoints", "lightning_io", "threads",
     "help", "schedules", "docs"],
    ["systems"],
    ["integrators"],
    ["data"],
    ["models"],
    ["regularisers", "metrics", "evaluation"],
    ["plots"],
    ["evaluators"],
    ["objectives", "module", "callbacks"],
    ["config", "attempts"],
    ["build"],
    ["runs", "control", "report", "benchmark"],
    ["api", "sweep", "cli", "train", "evaluate", "__init__"],
]
PACKAGE = Path(encons.__file__).parent


def layer(module: str) -> int:
    """The layer of ``encons.<module>`` (its first dotted part names it)."""
    head = module.split(".")[0]
    found = [i for i, names in enumerate(LAYERS) if head in names]
    assert found, f"encons.{module} is in no layer of LAYERS: place it there"
    return found[0]


def encons_imports(path: Path) -> set[str]:
    """The ``encons.*`` modules ``path`` imports (at any depth, lazily too), without TYPE_CHECKING and
    ``__main__`` blocks."""
    tree = ast.parse(path.read_text())
    skipped = {id(n) for node in ast.walk(tree) if isinstance(node, ast.If)
               and ("TYPE_CHECKING" in ast.unparse(node.test) or "__main__" in ast.unparse(node.test))
               for n in ast.walk(node)}
    found = set()
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("encons"):
            names = [node.module] if node.module != "encons" else [f"encons.{a.name}" for a in node.names]
            found.update(names)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.startswith("encons."))
    return {name.removeprefix("encons.") for name in found if name != "encons"}


def test_no_module_imports_from_a_layer_above_it():
    arrows = []
    for path in sorted(PACKAGE.rglob("*.py")):
        module = ".".join(path.relative_to(PACKAGE).with_suffix("").parts)
        for imported in encons_imports(path):
            if layer(imported) > layer(module):
                arrows.append(f"encons.{module} -> encons.{imported}")
    assert arrows == []


def test_models_take_system_helpers_from_the_seam_not_from_another_model():
    imports = encons_imports(PACKAGE / "models" / "lnode.py")
    assert "models.base" in imports and "models.symo" not in imports


def test_the_layer_check_sees_a_back_arrow(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("def f():\n    from encons.report import write_report\n")
    assert layer(next(iter(encons_imports(bad)))) > layer("systems")


def test_checking_one_config_after_composing_another_gives_its_own_error(tmp_path):
    """Each config carries its own request: composing B after A does not change what A's check says."""
    symo = compose(["model=symo", "system=pendulum_control", "integrator=euler"], tmp_path / "a")
    node = compose(["model=node", "system=pendulum_control", "integrator=euler"], tmp_path / "b")
    plain = compose(["model=symo", "system=pendulum_control"], tmp_path / "c")
    with pytest.raises(ConfigError, match=r"^integrator=euler does not apply to model=symo: a discrete model"):
        build_model(symo, build_system(symo), request=Request.of(symo))
    build_model(plain, build_system(plain), request=Request.of(plain))   # no integrator override: fine
    assert node.name == "pendulum_control-node" and symo.name == "pendulum_control-symo"


def test_request_of_a_config_without_hydra_is_empty():
    from omegaconf import OmegaConf

    assert Request.of(OmegaConf.create({"model": {}})) == Request()


def test_a_users_optimizer_and_scheduler_from_a_searchpath_yaml_train(tmp_path):
    """``optimizer`` and ``scheduler`` are ``_partial_`` configs: a user's YAML swaps them, no code."""
    import torch

    for group, name, text in [("optimizer", "sgd", "_target_: torch.optim.SGD\n_partial_: true\nlr: 0.01\nmomentum: 0.9\n"),
                              ("scheduler", "halving", "_target_: torch.optim.lr_scheduler.StepLR\n_partial_: true\n"
                                                       "step_size: 1\ngamma: 0.5\n")]:
        (tmp_path / "myconf" / group).mkdir(parents=True)
        (tmp_path / "myconf" / group / f"{name}.yaml").write_text(text)
    cfg = encons.compose("debug=fast", "logger=none", "model=node", "system=pendulum1",
                         f"hydra.searchpath=[file://{tmp_path / 'myconf'}]", "optimizer=sgd", "scheduler=halving",
                         output_dir=tmp_path / "run", cache_dir=tmp_path / "cache")
    run = encons.train(cfg)
    optimizer = run.module.trainer.optimizers[0]
    assert type(optimizer) is torch.optim.SGD and optimizer.defaults["momentum"] == 0.9
    epochs = cfg.trainer.max_epochs
    assert optimizer.param_groups[0]["lr"] == pytest.approx(0.01 * 0.5 ** epochs)   # stepped once an epoch
    assert run.metrics["test/traj_rel_err"] > 0


@pytest.mark.parametrize("history, targets", [(1, [2, 3, 4, 5]), (2, [2, 3, 4, 5]), (3, [3, 4, 5]), (4, [4, 5])])
def test_santos_one_step_targets_are_every_state_from_two_on_for_any_history(history, targets):
    """The windows' last steps are the targets k ≥ max(2, history), each once (history 3 once kept only k = 5)."""
    import torch

    from encons.evaluators.santos import one_step_windows

    states = torch.arange(6.0).reshape(1, 6, 1)           # state k holds the value k
    windows = one_step_windows(states, history)
    assert windows.shape == (len(targets), history + 1, 1)
    assert windows[:, -1, 0].tolist() == targets
    assert torch.equal(windows[:, 0, 0], torch.tensor(targets, dtype=torch.float32) - history)


def test_every_objective_a_model_declares_is_registered():
    from encons.build import catalogue
    from encons.objectives import OBJECTIVES
    from encons.trust import locate

    declared = {o for name in catalogue("model")
                for o in locate(compose([f"model={name}"], ".").model._target_).objectives}
    assert declared == set(OBJECTIVES)


@pytest.fixture
def written(monkeypatch):
    """Every path encons writes through ``encons.io`` (every writer does), in order."""
    from encons import io

    paths = []
    real = io.atomic_open
    monkeypatch.setattr(io, "atomic_open", lambda path, *a, **k: (paths.append(Path(path)), real(path, *a, **k))[1])
    return paths


def test_one_writer_saves_the_test_metrics_once_with_every_evaluators_results(tmp_path, written):
    """The states and the controlled-system (Santos) evaluators both reach test_metrics.json, written once
    per test, by one writer; so are test_curves.npz and each evaluator's figures."""
    import json

    cfg = encons.compose("debug=fast", "model=lnode", "system=pendulum_control", "evaluators.santos.steps=10",
                         "evaluators.santos.n_trajectories=2", output_dir=tmp_path / "run", cache_dir=tmp_path / "c")
    assert list(cfg.evaluators) == ["states", "santos"]
    run = encons.train(cfg)
    results = [p.relative_to(tmp_path / "run") for p in written if p.suffix in (".json", ".npz", ".png")
               and tmp_path / "run" in p.parents]
    assert sorted(map(str, results)) == sorted(map(str, set(results)))      # each file once
    assert {Path("test_metrics.json"), Path("test_curves.npz"), Path("figures/integration.png"),
            Path("figures/rollout.png")} <= set(results)
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
        "# @package evaluators.largest\n_target_: mypkg.largest.LargestState\nscale: 2.0\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("ENCONS_TRUSTED_TARGETS", "mypkg.*")
    cfg = encons.compose("debug=fast", "logger=none", "model=node", "system=pendulum1",
                         f"hydra.searchpath=[file://{tmp_path / 'myconf'}]", "evaluators=[states,largest]",
                         output_dir=tmp_path / "run", cache_dir=tmp_path / "cache")
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
    cfg = encons.compose("debug=fast", "logger=none", "system=pixel_pendulum", f"evaluators=[{chosen}]",
                         output_dir=tmp_path / "run", cache_dir=tmp_path / "cache")
    with pytest.raises(ConfigError, match=rf"^evaluators.{chosen} does not apply to observation=Autoencoder .*; "
                                          r"allowed: evaluators=\[pixels\]$"):
        encons.api.build(cfg)


def test_two_evaluators_giving_one_metric_name_are_refused(tmp_path):
    import lightning.pytorch as pl

    from encons.evaluators import Evaluator, Result

    class Twice(Evaluator):
        def compute(self, module):
            return Result({"traj_rel_err": 0.0})

    cfg = encons.compose("debug=fast", "logger=none", "model=node", "system=pendulum1",
                         output_dir=tmp_path / "run", cache_dir=tmp_path / "cache")
    data, module = encons.api.build(cfg)
    module.evaluators["twice"] = Twice()
    trainer = pl.Trainer(logger=False, enable_progress_bar=False, enable_checkpointing=False)
    with pytest.raises(ConfigError, match=r"^evaluators.twice gives the metric 'traj_rel_err' another evaluator"):
        trainer.test(module, datamodule=data, verbose=False)
