"""The benchmark runner: profile=smoke writes every table and figure, a rerun skips finished runs,
and ``encons.tools.report`` rebuilds the report from the runs alone."""

from __future__ import annotations

import csv
import json
import math
import re
from pathlib import Path

import pytest

from encons.config import trust
from encons.entry.cli import benchmark as main
from encons.infra.errors import ConfigError
from encons.infra.paths import config_dir
from encons.tools.benchmark import expand, optimiser
from encons.tools.report import write_report
from encons.training.build import compose

FIGURES = (
    "traj_rel_err.png",
    "rel_err_vs_time.png",
    "energy_err_vs_time.png",
    "energy_rmse.png",
    "data_efficiency.png",
)


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
    # the floor beside the models (the true field, same evaluation), and the optimiser each model used
    assert "| pendulum1 | oracle (true field) |" in md and "optimiser |" in md.splitlines()[2]
    # the budget in optimiser steps too (an epoch is one window per trajectory here: 2 × ceil(n_train / batch))
    hnn16 = next(line for line in md.splitlines() if line.startswith("| pendulum1 | hnn | 16 |"))
    assert hnn16.endswith("| AdamW lr 0.001, weight_decay 0.01; constant lr; 2 epochs (4 steps) |")
    oracle_row = next(line for line in md.splitlines() if "oracle (true field)" in line)
    assert float(oracle_row.split("|")[md.splitlines()[2].split("|").index(" geom_rel_err ")].split("±")[0]) < 1e-6
    for name in ("summary.csv", *FIGURES):
        assert (out / name).stat().st_size > 0, name
    stamps = {p: p.stat().st_mtime_ns for p in (out / "runs").glob("*/result.json")}
    capsys.readouterr()
    main(["profile=smoke", f"out={out}", f"cache_dir={cache}"])
    printed = capsys.readouterr().out  # the stream training logs to, not stderr
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
    assert f"resuming from {killed.parent / 'checkpoints' / 'last.ckpt'}" in capsys.readouterr().out
    after = json.loads(killed.read_text())
    assert {k: v for k, v in after.items() if k.startswith("test/")} == {
        k: v for k, v in before.items() if k.startswith("test/")
    }


def test_profiles_expand_and_carry_published_numbers():
    finzi = expand(compose(["profile=finzi"], config_name="benchmark"))
    assert len(finzi) == 2 * 2 * 3 and all("data.noise=0.0" in r.overrides for r in finzi)
    lim_kasim = expand(compose(["profile=lim_kasim"], config_name="benchmark"))
    assert {r.label for r in lim_kasim} >= {"node+C_H", "hnn", "nsf", "node+C_D"}
    assert next(r for r in lim_kasim if r.label == "node+C_H" and r.system == "pendulum").paper == {
        "energy_rmse_median": 0.024
    }
    quick = expand(compose(["profile=quick"], config_name="benchmark"))
    assert len(quick) == 11 * 4 * 3
    zhong = expand(compose(["profile=zhong"], config_name="benchmark"))
    assert {r.n_train for r in zhong} == {None, 10, 100, 1000, 10000}
    two_networks = {r.label for r in zhong if "model.shared_trunk=false" in r.overrides}
    assert two_networks == {"hnn_structure", "hnn_structure_angle", "lnn_structure", "lnn_structure_angle"}
    assert all(("system.min_sin_theta=0.0" in r.overrides) == (r.system == "gyroscope") for r in zhong)
    santos = expand(compose(["profile=santos"], config_name="benchmark"))
    assert len(santos) == 5 * 2 * 6 and {r.system for r in santos} == {"pendulum_control", "cartpole"}
    big = next(r for r in santos if r.n_train == 128 and r.system == "cartpole" and r.label == "symo")
    assert {"data.batch_size=17", "optimizer.lr=1e-3", "model.hidden=256", "objective=residual"} <= set(big.overrides)
    part = expand(compose(["profile=lim_kasim", "only=[mass_spring,pendulum/hnn]"], config_name="benchmark"))
    assert [r.id for r in part][-1] == "pendulum-hnn-seed0" and {r.system for r in part[:-1]} == {"mass_spring"}
    with pytest.raises(ConfigError, match="only=\\['nope'\\] selects none"):
        expand(compose(["profile=lim_kasim", "only=[nope]"], config_name="benchmark"))
    xiao = expand(compose(["profile=xiao"], config_name="benchmark"))
    assert len(xiao) == 16 and next(
        r for r in xiao if r.label == "glnn-h200-d3" and r.system == "damped_oscillator"
    ).paper == {"accel_mse": 1.94e-4}


def test_quick_gives_every_model_one_optimiser_and_schedule():
    """quick's table compares models, not optimisers: one optimiser, weight decay, schedule and budget for all
    11 models, the same on every system; the peak lr is the one its family's sweep chose (per_family), so two
    models of one family never differ."""
    profile = compose(["profile=quick"], config_name="benchmark")
    runs = expand(profile)
    per_system = {}
    for r in runs:
        per_system.setdefault((r.label, r.seed), set()).add(
            tuple(o for o in r.overrides if not o.startswith("system="))
        )
    assert len(per_system) == 11 * 3 and all(len(v) == 1 for v in per_system.values())
    configs = {r.label: compose(r.overrides) for r in runs if r.system == "pendulum2" and r.seed == 0}
    used = {m: optimiser(c) for m, c in configs.items()}
    assert len({re.sub(r"lr [^,]+, ", "", u) for u in used.values()}) == 1, used
    assert all("; constant lr; 20 epochs" in u for u in used.values()), used
    family = {m: trust.locate(c.model._target_, "model").family for m, c in configs.items()}
    assert set(family.values()) == set(profile.per_family)
    chosen = {
        f: [float(o.split("=")[1]) for o in ovr if o.startswith("optimizer.lr=")]
        for f, ovr in profile.per_family.items()
    }
    assert {m: [c.optimizer.lr] for m, c in configs.items()} == {m: chosen[family[m]] for m in configs}


def test_a_family_the_profile_does_not_list_is_refused():
    with pytest.raises(ConfigError, match="per_family has no entry for model=hnn \\(family canonical\\); allowed"):
        expand(
            compose(["profile=smoke", '++per_family={unstructured: ["optimizer.lr=1e-2"]}'], config_name="benchmark")
        )


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
    assert {"control", "finzi", "lim_kasim", "pixels", "quick", "santos", "smoke", "xiao", "zhong"} <= set(profiles)
    assert f"profiles: {', '.join(profiles)}" in out and "seeds:" in out
    assert not any(tmp_path.iterdir())


TINY_SANTOS = [
    'train=["figures=false","evaluation.rtol=1e-6","evaluation.atol=1e-8","data.n_val=2","data.n_test=2","model.hidden=8","trainer.max_epochs=1",'
    '"evaluators.santos.steps=4","evaluators.santos.n_trajectories=2"]',
    "n_train=[2]",
    "per_n_train={}",
]


@pytest.mark.slow
def test_santos_profile_at_smoke_size_writes_figures_3_4_and_resumes(tmp_path, capsys):
    """profile=santos (Santos et al. Figs. 3–4) with tiny sizes: every model × system × N_train trains,
    the §7 metrics reach the table, one five-panel figure per system is drawn, and a rerun skips."""
    out, cache = tmp_path / "santos", tmp_path / "cache"
    args = ["profile=santos", f"out={out}", f"cache_dir={cache}", *TINY_SANTOS]
    main(args)
    with (out / "results.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 * 6 and not any(r["error"] for r in rows)
    assert {r["model"] for r in rows} == {
        "node-rk4",
        "node-midpoint",
        "lnode-rk4",
        "lnode-midpoint",
        "symo",
        "e2e_symo",
    }
    assert all(("objective=residual" in r["overrides"]) == (r["model"] == "symo") for r in rows)  # the rest: onestep
    md = (out / "summary.md").read_text()
    for key in ("mse_train", "mse_test", "mse_integration", "energy_mse_integration", "mass_mse", "newton_unconverged"):
        assert key in md, key
    assert "| cartpole | e2e_symo | 2 |" in md
    for name in ("santos_pendulum_control.png", "santos_cartpole.png", "data_efficiency.png", "summary.csv"):
        assert (out / name).stat().st_size > 0, name
    capsys.readouterr()
    main(args)
    assert "".join(capsys.readouterr()).count("finished before, skipped") == 12


@pytest.mark.slow
def test_xiao_profile_at_smoke_size_writes_tables_3_4_and_mse_curves_and_resumes(tmp_path, capsys):
    """profile=xiao (Xiao et al. Tables 3–4, Figs. 3 and 5) with tiny sizes: the width/depth runs and the
    baseline on both systems, the paper's cell values beside accel_mse, state and energy MSE against time."""
    out, cache = tmp_path / "xiao", tmp_path / "cache"
    args = [
        "profile=xiao",
        f"out={out}",
        f"cache_dir={cache}",
        'train=["figures=false","evaluation.rtol=1e-6","evaluation.atol=1e-8","data.n_train=2","data.n_val=1","data.n_test=2","data.n_steps=20","data.test_steps=30",'
        '"data.chunk_len=20","trainer.max_epochs=1"]',
    ]
    main(args)
    with (out / "results.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 * 8 and not any(r["error"] for r in rows)
    md = (out / "summary.md").read_text()
    assert "| compound_pendulum | glnn-h200-d4 |" in md and "9.5e-05" in md
    assert " | accel_mse | paper accel_mse | " in md.split("\n")[2]  # the paper's cell beside the same quantity
    assert not list(out.glob("runs/*/checkpoints/best-*.ckpt"))  # no checkpoint selection: epoch max_epochs is tested
    for key in ("state_mse", "energy_mse", "baseline_linear_ode/state_mse_final"):
        assert key in md, key
    for name in ("state_mse_vs_time.png", "energy_mse_vs_time.png", "summary.csv"):
        assert (out / name).stat().st_size > 0, name
    capsys.readouterr()
    main(args)
    assert "".join(capsys.readouterr()).count("finished before, skipped") == 16


def test_a_cell_gives_no_spread_for_one_run_or_a_spread_below_float_rounding():
    """Issue 51: a one-run cell printed "± 0", identical seeds "± 8.5e-18"."""
    from encons.tools.report import markdown

    base = {"system": "pendulum1", "n_train": 800, "data_efficiency": False, "failed": 0, "optimiser": ""}
    summary = [
        {**base, "model": "one", "runs": 1, "test/vpt": 0.25, "test/vpt_sd": 0.0},
        {**base, "model": "same", "runs": 3, "test/vpt": 0.5, "test/vpt_sd": 8.5e-18},
        {**base, "model": "spread", "runs": 3, "test/vpt": 0.5, "test/vpt_sd": 0.02},
    ]
    cells = {line.split(" | ")[1]: line.split(" | ")[4] for line in markdown(summary, {}).splitlines()[2:5]}
    assert cells == {"one": "0.25", "same": "0.5", "spread": "0.5 ± 0.02"}


def test_train_debug_fast_shrinks_a_profiles_sizes_and_a_users_key_wins():
    """Issue 51: `profile=lim_kasim 'train=["debug=fast"]'` failed all 14 runs (data.chunk_len=30 beside
    debug's 10 steps) and a profile's trainer.max_epochs beat debug=fast."""
    from encons.tools.benchmark import expand
    from encons.training.build import compose

    runs = expand(compose(["profile=lim_kasim", 'train=["debug=fast"]'], config_name="benchmark"))
    for run in runs:
        cfg = compose(run.overrides)
        assert cfg.trainer.max_epochs == 2 and cfg.data.chunk_len <= cfg.data.n_steps + 1, run.id
        assert cfg.objective == "derivative"  # the profile's other keys stay
    mine = expand(
        compose(["profile=lim_kasim", 'train=["debug=fast","trainer.max_epochs=7"]'], config_name="benchmark")
    )
    assert compose(mine[0].overrides).trainer.max_epochs == 7


def test_a_member_past_the_float_range_reports_inf_and_ends_its_curve(tmp_path):
    """A diverged member (the campaign's Xiao compound GLNN 400 × 4: an energy error of 5.9e239, energy MSE curves
    at the float range's end) gives its cell a spread of inf and its figure curves that end, not an
    OverflowError from the seeds' spread or from matplotlib's log axis."""
    import numpy as np

    t = np.linspace(0.0, 1.0, 5)
    for seed, scale in ((0, 1.0), (1, 1e241)):
        run = tmp_path / "runs" / f"pendulum1-hnn-seed{seed}"
        run.mkdir(parents=True)
        row = {"system": "pendulum1", "model": "hnn", "seed": seed, "n_train": 8, "data_efficiency": False}
        row |= {"error": "", "wall_time_s": 1.0, "optimiser": "AdamW", "test/traj_rel_err": 0.1 * scale}
        (run / "result.json").write_text(json.dumps(row | {"test/energy_abs_err": 0.01 * scale}))
        np.savez(
            run / "test_curves.npz",
            t=t,
            rel_err=np.full((3, 5), 0.1 * scale),
            energy_err=np.full((3, 5), 0.01 * scale),
            energy_mse_model=np.array([1e-4, 1e-3, 1e-2, 1e-2, 1e-2])
            * (1 if seed == 0 else [1, 1e10, 1e270, math.inf, math.inf]),  # as that member's: 5e268, then inf
        )
    write_report(tmp_path)
    with (tmp_path / "summary.csv").open() as f:
        (cell,) = [r for r in csv.DictReader(f) if r["model"] == "hnn"]
    assert float(cell["test/energy_abs_err_sd"]) == math.inf
    assert all((tmp_path / name).stat().st_size > 0 for name in ("energy_err_vs_time.png", "energy_mse_vs_time.png"))
