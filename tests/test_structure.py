"""The shape of the package: imports go one way through the layers below, with no import cycle between
modules (every import counted: lazy ones, those under ``if TYPE_CHECKING:`` and ``if __name__ ==
"__main__":``), and what the user asked for is passed down, never read from Hydra's process-global state.
End-to-end tests of extending encons live in ``tests/extending/test_user_components.py``."""

from __future__ import annotations

import ast
import shutil
from pathlib import Path

import pytest

import encons
from encons.config.check import Request, validate
from encons.infra.errors import ConfigError
from encons.training.build import build_model, build_system, compose

#: Lowest first: one package per layer (docs/architecture.md draws them). A module may import from its own package
#: and those before it, never from a later one; every import counts.
LAYERS = [
    ["infra"],  # errors, declared bounds, paths, atomic files, checkpoints, threads, allocator, progress, compat
    ["systems"],  # the true physics
    ["models"],  # networks with physical structure
    ["numerics"],  # rollouts, the evaluation pipeline, metrics, regularisers, the Learner protocol
    ["data"],  # trajectories: simulated, recorded, from files
    ["evaluators"],  # what reads a Learner: test metrics and one run's figures
    ["config"],  # the one validation pass (Request, Checked) and target trust
    ["training"],  # the LightningModule, objectives, callbacks, builders, runs and ensembles
    ["tools"],  # the commands' libraries: benchmark, sweep, report, docs, control
    ["entry"],  # the Python API, the one room for every command's argv, --help
    ["__init__", "__main__", "train", "evaluate", "benchmark", "report", "sweep", "control"],  # encons, commands
]
PACKAGE = Path(encons.__file__).parent


def layer(module: str) -> int:
    """The layer of ``encons.<module>`` (its first dotted part names it)."""
    head = module.split(".")[0]
    found = [i for i, names in enumerate(LAYERS) if head in names]
    assert found, f"encons.{module} is in no layer of LAYERS: place it there"
    return found[0]


def modules(package: Path) -> dict[str, Path]:
    """Every module of ``package`` by its name inside it (``models.base``, ``__init__``, ``__main__``)."""
    return {
        ".".join(p.relative_to(package).with_suffix("").parts).removesuffix(".__init__"): p
        for p in sorted(package.rglob("*.py"))
    }


def encons_imports(path: Path, known: dict[str, Path] | None = None) -> set[str]:
    """The ``encons.*`` modules ``path`` imports, every import counted (at any depth, lazily, under
    TYPE_CHECKING and ``__main__`` too); ``from encons.x import y`` names ``x.y`` where that is a module."""
    known = modules(PACKAGE) if known is None else known
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if (
            isinstance(node, ast.ImportFrom)
            and node.module
            and node.level == 0
            and (node.module == "encons" or node.module.startswith("encons."))
        ):
            base = node.module.removeprefix("encons").removeprefix(".")
            for alias in node.names:
                sub = f"{base}.{alias.name}" if base else alias.name
                found.add(sub if sub in known else base)
        elif isinstance(node, ast.Import):
            found.update(a.name.removeprefix("encons.") for a in node.names if a.name.startswith("encons."))
    return {name for name in found if name}


def import_graph(package: Path) -> dict[str, set[str]]:
    """Module → the modules of the package it imports (itself left out)."""
    known = modules(package)
    return {name: {m for m in encons_imports(path, known) if m != name} for name, path in known.items()}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import cycles of ``graph``: its strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = stack[stack.index(v) :]
            del stack[stack.index(v) :]
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def assert_no_import_cycle(package: Path) -> None:
    assert cycles(import_graph(package)) == []


def test_no_import_cycle_between_modules():
    assert_no_import_cycle(PACKAGE)


def test_a_planted_import_cycle_fails_the_structure_test(tmp_path):
    """Two temporary modules importing each other, one under TYPE_CHECKING, one in a ``__main__`` block."""
    copy = tmp_path / "encons"
    shutil.copytree(PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__"))
    assert_no_import_cycle(copy)
    (copy / "planted_a.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from encons.planted_b import B\n"
    )
    (copy / "planted_b.py").write_text(
        "class B:\n    pass\n\nif __name__ == '__main__':\n    from encons import planted_a\n"
    )
    with pytest.raises(AssertionError):
        assert_no_import_cycle(copy)
    assert cycles(import_graph(copy)) == [["planted_a", "planted_b"]]


def test_no_module_imports_from_a_layer_above_it():
    arrows = [
        f"encons.{module} -> encons.{imported}"
        for module, imported_set in sorted(import_graph(PACKAGE).items())
        for imported in sorted(imported_set)
        if layer(imported) > layer(module)
    ]
    assert arrows == []


def test_the_layer_check_sees_a_back_arrow_also_under_type_checking(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from encons.tools.report import write_report\n"
    )
    assert layer(next(iter(encons_imports(bad)))) > layer("systems")


def test_objectives_and_evaluators_see_the_learner_not_the_training_module():
    graph = import_graph(PACKAGE)
    readers = ["training.objectives", *(m for m in graph if m.startswith("evaluators"))]
    assert all("training.module" not in graph[m] for m in readers)
    assert "numerics.learner" in graph["training.objectives"] and "numerics.learner" in graph["evaluators.base"]


def test_models_take_system_helpers_from_the_seam_not_from_another_model():
    imports = encons_imports(PACKAGE / "models" / "lnode.py")
    assert "models.base" in imports and "models.symo" not in imports


def test_checking_one_config_after_composing_another_gives_its_own_error(tmp_path):
    """Each config carries its own request: composing B after A does not change what A's check says."""
    symo = compose(["model=symo", "system=pendulum_control", "integrator=euler"], tmp_path / "a")
    node = compose(["model=node", "system=pendulum_control", "integrator=euler"], tmp_path / "b")
    plain = compose(["model=symo", "system=pendulum_control"], tmp_path / "c")
    with pytest.raises(ConfigError, match=r"^integrator=euler does not apply to model=symo: a discrete model"):
        validate(symo, Request.of(symo))
    checked = validate(plain, Request.of(plain))  # no integrator override: fine
    build_model(checked, build_system(checked))
    assert node.name == "pendulum_control-node" and symo.name == "pendulum_control-symo"


def test_request_of_a_config_without_hydra_is_empty():
    from omegaconf import OmegaConf

    assert Request.of(OmegaConf.create({"model": {}})) == Request()
