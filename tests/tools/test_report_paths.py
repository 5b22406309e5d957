"""Reports record paths relative to their ``out`` (or a folder outside it by its name), never the machine's
absolute folder: the writer (``encons.tools.report.recorded``), the rows and ``benchmark.yaml`` it writes, and the
committed reports rewritten through it."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

from encons.tools.benchmark import recorded_config
from encons.tools.report import recorded, recorded_override, write_report

ROOT = Path(__file__).parents[2]


def test_recorded_is_relative_to_out_or_a_name():
    out = Path("/somewhere/machine/out")
    assert recorded(out / "runs" / "pendulum1-node-seed0", out) == "runs/pendulum1-node-seed0"
    assert recorded(out, out) == "."
    assert recorded("/scratch/cache_px", out) == "cache_px"
    assert recorded_config({"out": str(out), "cache_dir": "/scratch/cache", "seeds": [0]}, out) == {
        "out": ".",
        "cache_dir": "cache",
        "seeds": [0],
    }


def test_the_report_writer_records_run_dir_relative_to_out(tmp_path):
    out = tmp_path / "bench"
    run = out / "runs" / "pendulum1-node-seed0"
    run.mkdir(parents=True)
    row = {
        "system": "pendulum1",
        "model": "node",
        "seed": 0,
        "n_train": 8,
        "data_efficiency": False,
        "run_dir": str(run),
        "error": "stopped",
        "wall_time_s": 1.0,
        "overrides": "",
        "optimiser": "AdamW",
    }
    (run / "result.json").write_text(json.dumps(row))
    write_report(out)
    with (out / "results.csv").open(newline="") as f:
        assert [r["run_dir"] for r in csv.DictReader(f)] == ["runs/pendulum1-node-seed0"]
    assert str(tmp_path) not in (out / "results.csv").read_text() + (out / "summary.md").read_text()


def test_committed_reports_hold_no_machine_folder():
    found = [
        f"{p.relative_to(ROOT)}:{i}"
        for p in sorted((ROOT / "benchmarks" / "reports").rglob("*"))
        if p.is_file() and p.suffix in {".csv", ".md", ".yaml", ".json", ".jsonl", ".py", ".txt"}
        for i, line in enumerate(p.read_text(errors="replace").splitlines(), 1)
        if re.search(r"(?<![\w.])/(?:work|home|tmp|root|Users)/", line)
    ]
    assert not found, "absolute machine folders in committed reports:\n" + "\n".join(found)


def test_an_absolute_path_override_is_recorded_by_its_name(tmp_path):
    """``train=["data.path=/abs/file.npz"]`` (cause.md's offset data, every run trained on one file) reaches every
    run and is recorded by name in the rows and ``benchmark.yaml``; other overrides stay as they are."""
    import torch
    import yaml

    from encons.data import store
    from encons.entry.cli import benchmark

    out = tmp_path / "bench"
    assert recorded_override(f"data.path={tmp_path / 'offset.npz'}", out) == "data.path=offset.npz"
    assert recorded_override(f"data.path={out / 'data' / 'x.npz'}", out) == "data.path=data/x.npz"
    assert recorded_override("model=hnn", out) == "model=hnn"
    assert recorded_override("data.path=rel/x.npz", out) == "data.path=rel/x.npz"
    t = torch.arange(11, dtype=torch.float64) * 0.1
    phase = torch.linspace(0, 3, 12, dtype=torch.float64)[:, None] + t  # 12 trajectories of a rotation, q̇ = 1
    states = torch.stack([phase + 6.0, torch.ones_like(phase)], -1)  # beyond (−π, π): the file's, not simulated
    data = tmp_path / "offset.npz"
    store.save(data, t, {"train": states[:8], "val": states[8:10], "test": states[10:]}, "angle")
    benchmark(
        [
            "profile=smoke",
            "models=[node]",
            "n_train=[]",
            f"out={out}",
            f"cache_dir={tmp_path / 'cache'}",
            f'train=["data.path={data}"]',
        ]
    )
    row = json.loads(next((out / "runs").glob("*/result.json")).read_text())
    assert not row["error"] and row["overrides"].endswith(" data.path=offset.npz")
    assert row["test/windows"] == 2  # the file's two test trajectories, not debug=fast's four simulated
    assert yaml.safe_load((out / "benchmark.yaml").read_text())["train"] == ["data.path=offset.npz"]
    written = "".join(p.read_text() for p in (out / "results.csv", out / "benchmark.yaml", out / "summary.md"))
    assert str(tmp_path) not in written
