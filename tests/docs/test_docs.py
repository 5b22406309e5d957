"""The manual as a reader meets it: result tables equal a fresh render of the committed reports (and a
changed report value is named by file and table), links between README.md and docs/ resolve, and every
fenced command either runs in the suite at a small size or is listed as documentation only."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest

from encons.tools import docs
from tests.docs import doc_commands

ROOT = Path(__file__).parents[2]


def test_result_tables_equal_a_fresh_render_of_their_reports():
    stale = docs.stale(ROOT)
    assert not stale, "\n".join(
        f"{doc}: the table from {source} differs from its report; run python -m encons.report --docs"
        for doc, source in stale
    )


def test_a_changed_report_value_fails_naming_the_file_and_the_table(tmp_path):
    shutil.copy(ROOT / "README.md", tmp_path / "README.md")
    shutil.copytree(ROOT / "docs", tmp_path / "docs")
    shutil.copytree(
        ROOT / "benchmarks" / "reports",
        tmp_path / "benchmarks" / "reports",
        ignore=shutil.ignore_patterns("*.png", "*.npz"),
    )
    assert docs.stale(tmp_path) == []
    csv = tmp_path / "benchmarks" / "reports" / "finzi-2000" / "summary.csv"
    text = csv.read_text()
    assert "2.1e-05" in text
    csv.write_text(text.replace("2.1e-05", "2.2e-05", 1))  # Finzi et al.'s CHNN gyroscope cell
    assert docs.stale(tmp_path) == [("README.md", "benchmarks/reports/finzi-2000/summary.csv")]
    docs.write(tmp_path)
    assert docs.stale(tmp_path) == [] and "| 2.2e-05 |" in (tmp_path / "README.md").read_text()


def test_a_marker_naming_a_missing_column_is_one_line(tmp_path):
    from encons.infra.errors import ConfigError

    with pytest.raises(ConfigError, match=r"columns=\['nope'\] not in benchmarks/reports/finzi-2000/summary.csv"):
        docs.table("benchmarks/reports/finzi-2000/summary.csv | system, nope", ROOT)


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*]", "", heading.strip().lower())
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def test_links_between_the_readme_and_docs_resolve():
    broken = []
    for doc in docs.documents(ROOT):
        text = re.sub(r"```.*?```", "", doc.read_text(), flags=re.S)
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+://", target):
                continue
            path, _, anchor = target.partition("#")
            file = (doc.parent / path).resolve() if path else doc
            if not file.exists():
                broken.append(f"{doc.relative_to(ROOT)}: {target} (no such file)")
            elif anchor and file.suffix == ".md":
                headings = {_slug(h) for h in re.findall(r"^#+ (.*)$", file.read_text(), re.M)}
                if anchor not in headings:
                    broken.append(f"{doc.relative_to(ROOT)}: {target} (no heading #{anchor})")
    assert not broken, "\n".join(broken)
    readme = (ROOT / "README.md").read_text()
    for page in sorted((ROOT / "docs").glob("*.md")):
        assert f"(docs/{page.name})" in readme, f"README's map of docs/ lacks {page.name}"


def fenced_commands() -> dict[str, str]:
    """command -> the file it is in, for every fenced block of README.md and docs/ (a Python block by its
    first line)."""
    found = {}
    for doc in docs.documents(ROOT):
        for lang, body in re.findall(r"```(\w*)\n(.*?)```", doc.read_text(), re.S):
            if lang == "python":
                found[re.sub(r"\s+# .*$", "", body.strip().splitlines()[0])] = doc.name
                continue
            for line in body.replace("\\\n", " ").splitlines():
                line = re.sub(r"\s+", " ", re.sub(r"\s+# .*$", "", line)).strip()
                if line:
                    found[line] = doc.name
    return found


PYTHON_BLOCKS = {
    "import torch, encons": "tests/entry/test_api.py::test_notebook_workflow_round_trips_a_run",
    "import encons": "tests/tools/test_control.py::test_the_docs_control_snippet_runs_as_written",
}


def test_every_fenced_command_runs_in_a_test_or_is_documentation_only():
    commands = fenced_commands()
    tested = {**doc_commands.RUN, **PYTHON_BLOCKS}
    unlisted = [f"{doc}: {c}" for c, doc in commands.items() if c not in tested and c not in doc_commands.DOC_ONLY]
    assert not unlisted, (
        "fenced commands neither run by a test nor listed as documentation only "
        "(tests/docs/doc_commands.py):\n" + "\n".join(unlisted)
    )
    gone = [c for c in [*tested, *doc_commands.DOC_ONLY] if c not in commands]
    assert not gone, "tests/docs/doc_commands.py lists commands the docs no longer have:\n" + "\n".join(gone)
    for command, node in tested.items():
        file, _, name = node.partition("::")
        assert re.search(rf"^\s*def {name}\(", (ROOT / file).read_text(), re.M), f"{command}: {node} does not exist"
    assert all(reason.strip() for reason in doc_commands.DOC_ONLY.values())


@pytest.mark.slow
def test_the_readme_small_sweep_runs_both_models(tmp_path, cli):
    done = cli(
        "-m",
        "model=node,hnn_angle",
        "system=pendulum1",
        "debug=fast",
        f"hydra.sweep.dir={tmp_path}/multirun",
        f"paths.cache_dir={tmp_path}/cache",
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr
    assert len(list((tmp_path / "multirun").glob("*/test_metrics.json"))) == 2


@pytest.mark.slow
def test_symo_paper_composes_with_debug_fast_and_trains(train_run):
    """``experiment=symo_paper`` trains on whole trajectories (``data.chunk_len: null``), so ``debug=fast``'s
    10 steps give windows of 11 states instead of a refusal."""
    m = train_run(
        [
            "model=e2e_symo",
            "system=cartpole",
            "experiment=symo_paper",
            "optimizer.lr=1e-3",
            "trainer.max_epochs=1",
            "evaluators.santos.steps=10",
            "evaluators.santos.n_trajectories=2",
        ]
    )
    assert m["test/traj_rel_err"] > 0


def test_the_readme_sweep_folder_is_not_named_after_a_model_it_does_not_run(tmp_path):
    """Issue 51: `-m model=node,hnn_angle` left multirun/pendulum1-hnn/<ts>/multirun.yaml (the default model's
    name) beside the jobs' folders; the sweep's folder names no model, each job's folder its own."""
    from omegaconf import OmegaConf

    from encons.training.build import compose

    cfg = compose(["model=node", "system=pendulum1"], output_dir=tmp_path)
    raw = OmegaConf.to_container(cfg.hydra.sweep)  # unresolved: what Hydra resolves once per sweep, once per job
    assert "name" not in raw["dir"] and "choices" not in raw["dir"], raw
    assert raw["subdir"] == "${hydra.job.num}-${name}"
    assert "multirun/" in (ROOT / "README.md").read_text().split("## Where outputs land")[1].split("\n## ")[0]
