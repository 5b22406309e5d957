"""The one entry room and the API's names: ``python -m encons <command>`` and its ``python -m encons.<command>``
aliases, the resolvers registered before Hydra builds its launcher, and ``encons.__all__`` as the manual lists it."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import types
from pathlib import Path

import optuna
import pytest
from optuna.trial import TrialState

import encons
from encons.entry import api, cli

ROOT = Path(__file__).resolve().parents[2]


def manual_all() -> list[str]:
    """The names the manual gives for ``encons.__all__``: in the "From Python" section of README.md (else of
    the first docs/*.md that has one), the backticked names after "`encons.__all__`:" up to the sentence's
    end (a "." outside backticks); dunder names (``__version__``) are left out."""
    for path in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        text = path.read_text() if path.is_file() else ""
        section = re.search(r"^#+ From Python.*?$(.*?)(?=^#+ |\Z)", text, re.M | re.S)
        if section and "`encons.__all__`:" in section.group(1):
            listed = section.group(1).split("`encons.__all__`:", 1)[1]
            sentence = re.match(r"((?:`[^`]*`|[^`.])*)\.", listed, re.S).group(1)
            return sorted(n for n in re.findall(r"`([^`]+)`", sentence) if not n.startswith("__"))
    raise AssertionError("no 'From Python' section listing `encons.__all__`: in README.md or docs/*.md")


def test_encons_all_is_the_list_the_manual_gives():
    assert sorted(encons.__all__) == manual_all()


def test_every_name_of_encons_all_is_the_api_object_of_that_name():
    """``encons.<name>`` is the object the API defines under that name (``score_control``: the control
    tool's), a class or a function of that name, never a module."""
    from encons.tools.control import score_control

    expected = {name: getattr(api, name, None) for name in encons.__all__} | {"score_control": score_control}
    for name in encons.__all__:
        value = getattr(encons, name)
        assert value is expected[name] and callable(value) and value.__name__ == name, (name, value)
        assert not isinstance(value, types.ModuleType), name
    assert isinstance(encons.Run, type) and isinstance(encons.Ensemble, type)


def test_python_m_encons_names_its_commands_and_refuses_another(capsys):
    with pytest.raises(SystemExit) as stop:
        cli.main(["--help"])
    printed = capsys.readouterr().out
    assert stop.value.code == 0 and all(c in printed for c in cli.COMMANDS)
    with pytest.raises(SystemExit) as stop:
        cli.main(["fly"])
    assert stop.value.code == 2
    assert capsys.readouterr().err.strip() == (
        "encons: error: command 'fly' does not exist; allowed: " + ", ".join(cli.COMMANDS)
    )


def _python_m(*args: str, cwd: Path, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=600,
        env={**os.environ, **(env or {})},
    )


@pytest.mark.slow
def test_a_command_and_its_alias_do_the_same(tmp_path):
    """``python -m encons report DIR`` and ``python -m encons.report DIR``: the same one line and exit 2."""
    missing = str(tmp_path / "nothing")
    runs = [_python_m(*entry, missing, cwd=tmp_path) for entry in (["encons", "report"], ["encons.report"])]
    assert [r.returncode for r in runs] == [2, 2]
    assert runs[0].stderr.strip().splitlines()[-1] == runs[1].stderr.strip().splitlines()[-1]
    assert runs[0].stderr.strip().splitlines()[-1].startswith("encons: error: ")


@pytest.mark.slow
def test_the_parallel_launcher_sweep_of_the_manual_runs_two_trials(tmp_path):
    """The scale-out command ``python -m encons.train -m sweeps=hamiltonian_weight hydra/launcher=parallel
    hydra.sweeper.n_jobs=2``, shrunk to two tiny trials: its launcher's ``${encons_threads:...}`` resolves
    (registered at the entry), it exits 0 and the study stores both trials, complete."""
    proc = _python_m(
        "encons.train",
        "-m",
        "sweeps=hamiltonian_weight",
        "hydra/launcher=parallel",
        "hydra.sweeper.n_jobs=2",
        "hydra.sweeper.n_trials=2",
        "model.hidden=choice(16,32)",
        "debug=fast",
        "trainer.max_epochs=1",
        "test=false",
        cwd=tmp_path,
        env={"ENCONS_ROOT": str(tmp_path)},
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    folder = tmp_path / "multirun" / "hamiltonian_weight-mass_spring-node"
    trials = optuna.load_study(study_name=folder.name, storage=f"sqlite:///{folder / 'optuna.db'}").trials
    assert [t.state for t in trials] == [TrialState.COMPLETE] * 2
    assert sorted(p.name for p in folder.glob("trial_*")) == ["trial_0", "trial_1"]
