"""The benchmark runner: profile=smoke writes every table and figure, a rerun skips finished runs,
and ``encons.report`` rebuilds the report from the runs alone."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from encons.benchmark import expand
from encons.build import compose
from encons.cli import benchmark as main
from encons.errors import ConfigError
from encons.paths import config_dir
from encons.report import write_report

FIGURES = ("traj_rel_err.png", "rel_err_vs_time.png", "energy_err_vs_time.png", "energy_rmse.png",
           "data_efficiency.png")


def test_smoke_profile_writes_report_and_resumes(tmp_path, capsys):
    out, cache = tmp_path / "bench", tmp_path / "cache"
    main(["profile=smoke", f"out={out}", f"cache_dir={cache}"])
    with (out / "results.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 6 and not any(r["error"] for r in rows)
    assert all(float(r["test/traj_rel_err"]) > 0 for r in rows)
    assert len({(r["system"], r["model"], r["n_train"]) for r in rows}) == 6  # no configuration trained twice
    assert len(list(cache.iterdir())) == 3  # n_train 4, 8 and the grid runs' 16
    md = (out / "summary.md").read_text()
    assert "| pendulum1 | hnn | 16 |" in md and "traj_rel_err" in md
    for name in ("summary.csv", *FIGURES):
        assert (out / name).stat().st_size > 0, name
    stamps = {p: p.stat().st_mtime_ns for p in (out / "runs").glob("*/result.json")}
    capsys.readouterr()
    main(["profile=smoke", f"out={out}", f"cache_dir={cache}"])
    printed = capsys.readouterr().err
    assert printed.count("finished before, skipped") == 6 and "benchmark run 6 of 6 done" in printed
    assert stamps == {p: p.stat().st_mtime_ns for p in (out / "runs").glob("*/result.json")}
    (out / "summary.md").unlink()
    write_report(out)  # the report alone, from the finished runs
    assert (out / "summary.md").read_text() == md
    # a run killed after its last checkpoint but before its result resumes there and scores the same
    killed = next(iter(stamps))
    before = json.loads(killed.read_text())
    killed.unlink()
    main(["profile=smoke", f"out={out}", f"cache_dir={cache}"])
    assert f"resuming from {killed.parent / 'checkpoints' / 'last.ckpt'}" in capsys.readouterr().err
    after = json.loads(killed.read_text())
    assert {k: v for k, v in after.items() if k.startswith("test/")} == {
        k: v for k, v in before.items() if k.startswith("test/")}


def test_profiles_expand_and_carry_published_numbers():
    finzi = expand(compose(["profile=finzi"], config_name="benchmark"))
    assert len(finzi) == 2 * 2 * 3 and all("data.noise=0.0" in r.overrides for r in finzi)
    lim_kasim = expand(compose(["profile=lim_kasim"], config_name="benchmark"))
    assert {r.label for r in lim_kasim} >= {"node+C_H", "hnn", "nsf", "node+C_D"}
    assert next(r for r in lim_kasim if r.label == "node+C_H" and r.system == "pendulum").paper == {
        "energy_rmse_median": 0.024}
    quick = expand(compose(["profile=quick"], config_name="benchmark"))
    assert len(quick) == 11 * 4 * 3
    zhong = expand(compose(["profile=zhong"], config_name="benchmark"))
    assert {r.n_train for r in zhong} == {None, 10, 100, 1000, 10000}


def test_unknown_profile_is_one_line_error():
    with pytest.raises(ConfigError, match="profile=nope is unknown; allowed: .*quick"):
        compose(["profile=nope"], config_name="benchmark")


def test_report_of_a_folder_without_runs(tmp_path):
    with pytest.raises(ConfigError, match="no finished benchmark runs"):
        write_report(tmp_path)


@pytest.mark.parametrize("arg", ["train=[trainer.max_epochs=3]", "profile=nope", "seeds=[0"])
def test_bad_command_line_is_one_line_exit_2(tmp_path, capsys, arg):
    with pytest.raises(SystemExit) as exit_:
        main([arg, f"out={tmp_path}"])
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and "\n" not in err and err.startswith("encons: error: ") and "allowed:" in err


def test_help_lists_the_profiles_and_trains_nothing(tmp_path, capsys):
    main(["--help", f"out={tmp_path}"])
    out = capsys.readouterr().out
    profiles = sorted(p.stem for p in (Path(config_dir()) / "profile").glob("*.yaml"))
    assert {"finzi", "lim_kasim", "pixels", "quick", "smoke", "zhong"} <= set(profiles)
    assert f"profiles: {', '.join(profiles)}" in out and "seeds:" in out
    assert not any(tmp_path.iterdir())
