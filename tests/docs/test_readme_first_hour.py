"""The README's first hour: one python form after activating the venv, the console scripts it names
exist and run, a short first command near the top, measured durations (docs/speed.md), committed example
results the report reads."""

from __future__ import annotations

import importlib
import re
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).parents[2]
README = (ROOT / "README.md").read_text()


def test_one_python_form_after_activating_the_venv():
    top = README[: README.index("## From Python")]
    assert "source .venv/bin/activate" in top
    assert not re.search(r"^\s*\.venv/bin/python -m", README, re.M)  # one form: python -m after activation
    assert "python -m encons.train model=hnn_angle system=pendulum1 debug=fast" in top


def test_every_console_script_is_named_in_the_readme_and_has_a_main():
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert {"encons-train", "encons-evaluate", "encons-benchmark", "encons-report"} <= set(scripts)
    for name, target in scripts.items():
        assert f"`{name}`" in README, name
        module, _, function = target.partition(":")
        assert callable(getattr(importlib.import_module(module), function)), target


def test_the_docs_state_measured_durations_with_their_load():
    speed = (ROOT / "docs" / "speed.md").read_text()
    section = speed[speed.index("## How long things take") : speed.index("## Training step against its floor")]
    assert re.search(r"load average \d+–\d+", section) and "benchmarks/reports/durations/README.md" in section
    rows = [
        line.split("|")[1:5] for line in section.splitlines() if line.startswith("| python") or line.startswith("| the")
    ]
    assert len(rows) >= 8 and all(re.fullmatch(r" [\d.]+ ", cell) for _, *cells in rows for cell in cells), rows
    for command in (
        "debug=fast",
        "system=pendulum2",
        "model=chnn system=gyroscope",
        "encons.evaluate",
        "profile=smoke",
        "encons.report",
        "-m model=node",
    ):
        assert command in section, command
    for command in ("make install", "make test-fast", "make test"):
        assert command in section, command


def test_the_committed_example_results_rebuild_with_the_report(tmp_path):
    import shutil

    from encons.tools.report import write_report

    out = tmp_path / "smoke"
    shutil.copytree(ROOT / "examples" / "results" / "smoke", out)
    summary = (out / "summary.md").read_text()
    (out / "summary.md").unlink()
    files = write_report(out)
    assert (out / "summary.md").read_text() == summary
    assert {p.name for p in files} >= {"traj_rel_err.png", "data_efficiency.png", "summary.csv"}
    # issue 51: every file the README's report command writes is the committed one, so a clone stays clean; the
    # command itself, in a fresh process as a user runs it (matplotlib's text rendering keeps process-wide state,
    # so figures drawn after other tests' in one worker can differ in a few pixels)
    subprocess.run([sys.executable, "-m", "encons.report", str(out)], check=True, capture_output=True, timeout=300)
    committed = ROOT / "examples" / "results" / "smoke"
    changed = [
        p.name
        for p in files
        if p.read_bytes().replace(str(out).encode(), b"examples/results/smoke") != (committed / p.name).read_bytes()
    ]  # results.csv names each run's folder as the README's run
    assert not changed, f"examples/results/smoke is stale; rebuild it with python -m encons.report: {changed}"
