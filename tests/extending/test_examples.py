"""The repository's example of a user's own system and model (``examples/``): one class and one YAML
each, outside encons, trained through the CLI with ``hydra.searchpath`` and ``debug=fast``; and the
errors a user meets when the contract is broken."""

from __future__ import annotations

import json
import re
import shutil
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).parents[2] / "examples"


@pytest.fixture
def example_project(tmp_path, monkeypatch):
    """A copy of ``examples/`` importable and trusted, as its README's command sets up."""
    root = tmp_path / "examples"
    shutil.copytree(EXAMPLES, root, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.syspath_prepend(str(root))
    for name in [m for m in sys.modules if m.split(".")[0] == "encons_examples"]:  # another test's copy
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setenv("ENCONS_TRUSTED_TARGETS", "encons_examples.*")
    return root


def readme_command(root: Path) -> list[str]:
    """The overrides of the command in ``examples/README.md``."""
    text = (root / "README.md").read_text().replace("\\\n", " ")
    command = re.search(r"encons-train (.*)", text)
    assert command, "examples/README.md lost its command"
    return [a.strip("'") for a in command.group(1).split()]


def test_the_example_system_and_model_train_through_the_cli_with_debug_fast(example_project, cli):
    args = readme_command(example_project)
    assert "debug=fast" in args and "model=linear_newton" in args and "system=duffing" in args
    proc = cli(*args, f"hydra.run.dir={example_project / 'run'}", cwd=example_project)
    assert proc.returncode == 0, proc.stderr[-2000:]
    metrics = json.loads((example_project / "run" / "test_metrics.json").read_text())
    assert metrics["traj_rel_err"] > 0 and "energy_abs_err" in metrics  # the system's own energy is scored
    assert "linear_newton on duffing" in proc.stdout


def test_a_preset_key_set_on_the_command_line_is_still_refused(example_project, cli):
    proc = cli(
        *readme_command(example_project),
        "model.hidden=8",
        f"hydra.run.dir={example_project / 'run'}",
        cwd=example_project,
    )
    assert proc.returncode == 2 and "unexpected keyword argument 'hidden'" in proc.stderr, proc.stderr


def test_super_init_without_the_system_names_the_real_cause(example_project, cli):
    model = example_project / "encons_examples" / "linear_newton.py"
    model.write_text(model.read_text().replace("super().__init__(system, chart)", "super().__init__()"))
    proc = cli(*readme_command(example_project), f"hydra.run.dir={example_project / 'run'}", cwd=example_project)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert proc.stderr.startswith(
        "encons: error: model._target_=encons_examples.linear_newton.LinearNewton: its __init__ calls "
        "super().__init__() with system=None; allowed: super().__init__(system, chart)"
    ), proc.stderr
    assert "model.stiffness" not in proc.stderr
