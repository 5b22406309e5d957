"""Seed ensembles (``seeds=[...]``, ``encons.training.ensemble``): each member is the separate run of its seed."""

from __future__ import annotations

import csv
import json
import math

import pytest
import torch

from encons.entry import api
from encons.infra.errors import ConfigError
from encons.training import ensemble
from tests.helpers import SANTOS_TINY

TINY = [
    "debug=fast",
    "logger=csv",
    "trainer.enable_progress_bar=false",
    "trainer.enable_model_summary=false",
    "evaluation.method=rk4",
    "data.n_test=2",
    "figures=false",
]


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """One data cache for the module's runs: every run of a system trains on the same simulated data."""
    return tmp_path_factory.mktemp("cache")


@pytest.fixture
def run(tmp_path, cache):
    def train(name, overrides):
        cfg = api.compose(*TINY, *overrides, output_dir=tmp_path / name, cache_dir=cache)
        return api.train(cfg, summary=False)

    return train


def _losses(folder, key="train/loss"):
    """The per-step training losses the CSV logger wrote under ``folder`` (its latest version: a resume's)."""
    with sorted(folder.glob("csv/*/metrics.csv"))[-1].open() as f:
        return [float(row[key]) for row in csv.DictReader(f) if row.get(key)]


def _assert_member_is(ens, seed, separate, folder):
    member = ens.members[ens.seeds.index(seed)]
    got, want = _losses(ens.run_dir, f"seed{seed}/train/loss"), _losses(folder)
    assert len(got) == len(want) > 1
    assert got == pytest.approx(want, rel=1e-4)
    tests = {k: v for k, v in separate.metrics.items() if k.startswith(("test/", "best/")) or k == "best_epoch"}
    assert tests and {k: member.metrics[k] for k in tests} == pytest.approx(tests, rel=1e-4, nan_ok=True)


@pytest.mark.parametrize(
    "model, system, path, extra",
    [
        pytest.param(
            "node",
            "pendulum_control",
            "stacked",
            ["scheduler=plateau", "scheduler.patience=0", *SANTOS_TINY],
            marks=pytest.mark.slow,
        ),  # controls; ReduceLROnPlateau on each member's own val/loss
        pytest.param(
            "chnn", "gyroscope", "stacked", [], marks=pytest.mark.slow
        ),  # member-stacked masses and rollout cache
        pytest.param("lnn", "pendulum2", "stacked", [], marks=pytest.mark.slow),  # guarded_solve's per-sample mask
        pytest.param("hnn_angle", "pendulum2", "stacked", [], marks=pytest.mark.slow),
        pytest.param("node", "mass_spring", "stacked", ["regulariser=hamiltonian"], marks=pytest.mark.slow),
        pytest.param("e2e_symo", "pendulum_control", "stacked", SANTOS_TINY, marks=pytest.mark.slow),
        pytest.param(
            "e2e_symo",
            "pendulum_control",
            "stacked",
            [*SANTOS_TINY, "trainer.gradient_clip_val=0.01"],
            marks=pytest.mark.slow,
            id="e2e_symo-clipped",
        ),  # the control profile's clipping, per member
        pytest.param("glnn", "damped_oscillator", "stacked", [], marks=pytest.mark.slow),
        ("node", "pixel_pendulum", "stacked", []),  # each member's own autoencoder; its test scores decoded frames
    ],
)
def test_members_equal_their_separate_runs(tmp_path, run, monkeypatch, model, system, path, extra):
    """The stacked path forced (a run takes it only where it measures faster than the loop)."""
    monkeypatch.setattr(ensemble, "_module", lambda c, m, s, d, _, real=ensemble._module: real(c, m, s, d, True))
    ovr = [f"model={model}", f"system={system}", *extra]
    ens = run("ens", [*ovr, "seeds=[0,1]"])
    assert ens.path.startswith(path) and not ens.diverged
    for seed in (0, 1):
        separate = run(f"seed{seed}", [*ovr, f"seed={seed}"])
        _assert_member_is(ens, seed, separate, tmp_path / f"seed{seed}")
    saved = json.loads((tmp_path / "ens" / "test_metrics.json").read_text())
    values = [m.metrics["test/traj_rel_err"] for m in ens.members]
    assert saved["traj_rel_err"] == pytest.approx(sum(values) / 2)
    assert saved["traj_rel_err_sd"] == pytest.approx(abs(values[0] - values[1]) / math.sqrt(2))
    assert (saved["traj_rel_err_min"], saved["traj_rel_err_max"]) == (min(values), max(values))


@pytest.mark.parametrize("stacked", [True, pytest.param(False, marks=pytest.mark.slow)])
def test_a_diverged_member_leaves_the_other_its_separate_run(tmp_path, run, monkeypatch, stacked):
    """NaN in member seed=1's weights from the start: it is reported diverged; seed 0 is its separate run."""
    original = ensemble._module

    def poisoned(cfg, members, seeds, data, _):
        module = original(cfg, members, seeds, data, stacked)
        assert module.path.startswith("stacked" if stacked else "loop")
        with torch.no_grad():
            weights = module.stacked.model.weights if stacked else module.members[1].parameters()
            for w in weights:
                (w[1] if stacked else w).fill_(math.nan)
        return module

    monkeypatch.setattr(ensemble, "_module", poisoned)
    ovr = ["model=node", "system=pendulum1"]
    ens = run("ens", [*ovr, "seeds=[0,1]"])
    assert list(ens.diverged) == [1] and "diverged" in ens.diverged[1]
    assert ens.members[1].metrics == {} and ens.members[1].checkpoint is None
    assert ens.metrics["members"] == 2 and ens.metrics["diverged"] == 1
    separate = run("seed0", [*ovr, "seed=0"])
    _assert_member_is(ens, 0, separate, tmp_path / "seed0")


def test_a_members_best_checkpoint_is_a_single_seed_run(tmp_path, run):
    ens = run("ens", ["model=node", "system=pendulum1", "seeds=[3,4]"])
    member = ens.members[1]
    assert member.run_dir == tmp_path / "ens" / "seed4" and member.checkpoint.parent == member.run_dir / "checkpoints"
    loaded = api.load(member.run_dir)
    assert loaded.config.seed == 4 and loaded.config.seeds is None and loaded.checkpoint == member.checkpoint
    again = api.evaluate(loaded)
    assert again == {k: v for k, v in member.metrics.items() if k.startswith("test/")}


@pytest.mark.parametrize(
    "system, stacked, extra",
    [
        ("pendulum1", True, []),
        ("pendulum1", False, []),
        ("pixel_pendulum", True, ["validation.criterion=none"]),  # the autoencoders' weights too, never validated
    ],
)
def test_ckpt_last_of_an_ensemble_gives_every_members_last_weights(tmp_path, run, monkeypatch, system, stacked, extra):
    """With no best checkpoint the members test their last weights; ``evaluate(folder, ckpt="last")`` and
    ``evaluate(<its last.ckpt>)`` read those weights from the ensemble's one ``last.ckpt`` and give each member's
    test metrics to the digit."""
    real = ensemble._module
    monkeypatch.setattr(ensemble, "_module", lambda c, m, s, d, _: real(c, m, s, d, stacked))
    ovr = ["model=node", f"system={system}", "seeds=[0,1]", "~callbacks.best", "trainer.max_epochs=3", *extra]
    ens = run("ens", ovr)
    assert ens.path.startswith("stacked" if stacked else "loop")
    want = [{k: v for k, v in m.metrics.items() if k.startswith("test/")} for m in ens.members]
    last = tmp_path / "ens" / "checkpoints" / "last.ckpt"
    for source, ckpt in ((tmp_path / "ens", "last"), (last, "best")):
        loaded = api.load(source, ckpt=ckpt)
        assert isinstance(loaded, api.Ensemble) and [m.checkpoint for m in loaded.members] == [last, last]
        assert [api.evaluate(m) for m in loaded.members] == want
    single = torch.load(last, weights_only=True)
    del single["encons_ensemble"]  # what a single run's checkpoint lacks
    torch.save(single, tmp_path / "single.ckpt")
    with pytest.raises(ConfigError, match="is not the checkpoint of the ensemble"):
        api.load(tmp_path / "ens", ckpt=str(tmp_path / "single.ckpt"))


@pytest.mark.parametrize(
    "bad, says",
    [
        ("seeds=[0,0]", "seeds=[0, 0]; allowed: a non-empty list of distinct"),
        ("seeds=[]", "seeds=[]; allowed"),
        ("seeds=[0,-1]", "allowed: a non-empty list"),
    ],
)
def test_bad_seeds_are_one_line(tmp_path, run, bad, says):
    with pytest.raises(ConfigError, match=says.replace("[", r"\[").replace("]", r"\]")):
        run("bad", ["model=node", "system=pendulum1", bad])


@pytest.mark.parametrize(
    "extra, says",
    [
        (["trainer=ddp", "trainer.devices=2"], "allowed: trainer.devices=1"),
        (["seed=3"], "allowed: one of seed=K or seeds"),
        (["ckpt_path=x.ckpt"], "ckpt_path=.x.ckpt. does not exist"),
        (["model=lnn", "plain_solve=true"], "allowed: plain_solve=false with seeds"),  # a model with the plain retry
    ],
)
def test_what_an_ensemble_cannot_be_is_refused(tmp_path, run, extra, says):
    with pytest.raises(ConfigError, match=says):
        run("bad", ["model=node", "system=pendulum1", "seeds=[0,1]", *extra])


@pytest.mark.slow
def test_a_profile_folds_its_seeds_into_one_ensemble_per_cell(tmp_path, cache):
    from encons.entry.cli import benchmark

    out = tmp_path / "bench"
    benchmark(
        [
            "profile=smoke",
            "seeds=[0,1]",
            "models=[node]",
            "n_train=[]",
            f"out={out}",
            f"cache_dir={cache}",
            'train=["evaluation.method=rk4","data.n_test=2"]',
        ]
    )
    with (out / "results.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert sorted(r["seed"] for r in rows) == ["0", "1"] and not any(r["error"] for r in rows)
    assert len({r["ensemble"] for r in rows}) == 1 and rows[0]["ensemble"].startswith("2 seeds, ")
    assert [p.name for p in (out / "runs").iterdir() if p.name.endswith("seeds0-1")] == ["pendulum1-node-seeds0-1"]
    for seed in (0, 1):  # each member's files in its own run folder, as a separate run's
        assert (out / "runs" / f"pendulum1-node-seed{seed}" / "test_curves.npz").is_file()
    values = [float(r["test/traj_rel_err"]) for r in rows]
    line = next(x for x in (out / "summary.md").read_text().splitlines() if x.startswith("| pendulum1 | node |"))
    mean, sd = sum(values) / 2, abs(values[0] - values[1]) / math.sqrt(2)
    assert f"{mean:.3g} ± {sd:.2g}" in line


def _stop_after_epoch(monkeypatch, epoch, stacked=None):
    """SIGTERM (what a scheduler sends) to this process at the end of training epoch ``epoch`` (from 1) of the
    next ensemble, once; ``stacked=False`` forces the loop path."""
    import os
    import signal

    original = ensemble._module

    def stopping(cfg, members, seeds, data, _):
        module = original(cfg, members, seeds, data, stacked)
        own = module.on_train_epoch_end

        def on_train_epoch_end():
            own()
            if module.current_epoch + 1 == epoch:
                os.kill(os.getpid(), signal.SIGTERM)

        module.on_train_epoch_end = on_train_epoch_end
        monkeypatch.setattr(ensemble, "_module", original)
        return module

    monkeypatch.setattr(ensemble, "_module", stopping)


@pytest.mark.slow
@pytest.mark.parametrize("stacked", [True, False])
def test_an_ensemble_stopped_by_sigterm_resumes_to_the_uninterrupted_result(tmp_path, run, monkeypatch, stacked):
    """Stopped after epoch 2 of 4: Interrupted with the resume line, last.ckpt at epoch 2; resumed from it, every
    member ends where the uninterrupted ensemble's does (its optimiser, schedule and best checkpoint came back)."""
    from encons.infra.errors import Interrupted

    ovr = [
        "model=node",
        "system=pendulum1",
        "seeds=[0,1]",
        "trainer.max_epochs=4",
        "scheduler=plateau",
        "scheduler.patience=0",
    ]
    real = ensemble._module
    monkeypatch.setattr(ensemble, "_module", lambda c, m, s, d, _: real(c, m, s, d, stacked))
    whole = run("whole", ovr)
    _stop_after_epoch(monkeypatch, 2, stacked)
    with pytest.raises(Interrupted, match=r"SIGTERM during fit, epoch 3 .*resume: python -m encons.train .*ckpt_path="):
        run("part", ovr)
    last = tmp_path / "part" / "checkpoints" / "last.ckpt"
    assert torch.load(last, weights_only=True)["epoch"] == 1 and not (tmp_path / "part" / "test_metrics.json").exists()
    resumed = run("part", [*ovr, f"ckpt_path={last}"])  # on its checkpoint's path
    assert resumed.path == whole.path and whole.path.startswith("stacked" if stacked else "loop")
    for a, b in zip(resumed.members, whole.members):
        tests = {k: v for k, v in b.metrics.items() if k.startswith(("test/", "best/")) or k == "best_epoch"}
        assert {k: a.metrics[k] for k in tests} == pytest.approx(tests, rel=1e-6)
    assert _losses(tmp_path / "part", "seed1/train/loss")[-4:] == pytest.approx(
        _losses(tmp_path / "whole", "seed1/train/loss")[-4:], rel=1e-6
    )
    epochs = json.loads((tmp_path / "part" / "costs.json").read_text())["epochs"]  # the epochs before the stop too
    assert [int(e["epoch"]) for e in epochs] == [1, 2, 3, 4]
    assert resumed.wall_time_s >= sum(e["total"] for e in epochs)  # and their time


@pytest.mark.slow
def test_a_benchmark_rerun_resumes_an_interrupted_ensemble(tmp_path, cache, monkeypatch, capsys):
    from encons.entry.cli import benchmark

    args = [
        "profile=smoke",
        "seeds=[0,1]",
        "models=[node]",
        "n_train=[]",
        f"out={tmp_path / 'bench'}",
        f"cache_dir={cache}",
        'train=["evaluation.method=rk4","data.n_test=2","trainer.max_epochs=4"]',
    ]
    _stop_after_epoch(monkeypatch, 2)
    with pytest.raises(SystemExit) as stop:
        benchmark(args)
    assert stop.value.code == 143
    assert "this ensemble resumes from its last.ckpt" in capsys.readouterr().err
    benchmark(args)
    assert "resuming from" in capsys.readouterr().out
    with (tmp_path / "bench" / "results.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert sorted(r["seed"] for r in rows) == ["0", "1"] and not any(r["error"] for r in rows)


def test_a_members_best_checkpoint_is_refused_for_resuming_in_one_line(tmp_path, run):
    ens = run("ens", ["model=node", "system=pendulum1", "seeds=[0,1]"])
    best = ens.members[0].checkpoint
    with pytest.raises(ConfigError, match="holds weights only .* allowed: evaluate it"):
        run("seed0", ["model=node", "system=pendulum1", "seed=0", f"ckpt_path={best}"])
    with pytest.raises(ConfigError, match="is not a seed ensemble's checkpoint"):
        run("ens2", ["model=node", "system=pendulum1", "seeds=[0,1]", f"ckpt_path={best}"])


def test_a_stacked_checkpoint_of_another_layout_is_refused_for_resuming_in_one_line(tmp_path, run, monkeypatch):
    """A stacked ensemble's last.ckpt from an encons that held its layers as (K, out, in) ``weight`` (before
    ``EnsembleLinear.weight_t``): one line naming the parameter, not Lightning's missing-keys traceback."""
    real = ensemble._module
    monkeypatch.setattr(ensemble, "_module", lambda c, m, s, d, _: real(c, m, s, d, True))  # not by timing
    ovr = ["model=node", "system=pendulum1", "seeds=[0,1]", "trainer.max_epochs=2"]
    ens = run("ens", ovr)
    assert ens.path.startswith("stacked")
    last = tmp_path / "ens" / "checkpoints" / "last.ckpt"
    state = torch.load(last, weights_only=True)
    old = {
        k.removesuffix("_t"): v.transpose(1, 2) if k.endswith("weight_t") else v for k, v in state["state_dict"].items()
    }
    assert old.keys() != state["state_dict"].keys()
    torch.save(state | {"state_dict": old}, last)
    with pytest.raises(
        ConfigError, match=r"parameter \S+\.weight is shape .* absent in this model; .* written by this version"
    ):
        run("ens", [*ovr, f"ckpt_path={last}"])


def test_a_spread_past_the_float_range_is_inf_not_an_overflow():
    """A member whose test rollout left the state space scores ~1e164 (the campaign's Xiao compound GLNN 400 × 4):
    the spread is inf, not an OverflowError that ends the ensemble's test and the benchmark with it."""
    metrics = ensemble.summarise(
        {0: {"test/energy_mse": 1.0}, 1: {"test/energy_mse": 9.8e163}, 2: {"test/energy_mse": 2.0}}
    )
    assert metrics["test/energy_mse_sd"] == math.inf and metrics["test/energy_mse_max"] == 9.8e163


def test_the_spread_line_names_mean_sd_min_max_and_no_spread_where_there_is_none():
    metrics = ensemble.summarise({0: {"test/traj_rel_err": 0.5}, 1: {"test/traj_rel_err": 0.7}})
    assert ensemble.spread_line(metrics, 2) == (
        "traj_rel_err 0.6 ± 0.14 (mean ± sample std over 2 members, min 0.5, max 0.7)"
    )
    assert (
        ensemble.spread_line(ensemble.summarise({0: {"test/traj_rel_err": 0.5}}), 1)
        == "traj_rel_err 0.5 (mean over 1 member, no spread)"
    )
    same = ensemble.summarise({0: {"test/geom_rel_err": 0.1 + 1e-17}, 1: {"test/geom_rel_err": 0.1}})
    assert "no spread" in ensemble.spread_line(same, 2)


def test_ensemble_figures_draw_the_members_band_around_their_mean():
    from encons.evaluators import figures

    t = torch.linspace(0, 1, 11)
    true = torch.stack([torch.sin(t), torch.cos(t)], -1).expand(5, 11, 2)
    preds = torch.stack([true + 0.01 * k for k in range(3)])  # member k off by 0.01 k
    figures = figures.ensemble_figures(t, preds, true, "node on pendulum1", [0, 1, 2], units=("rad",))
    assert set(figures) == {"ensemble_rollout", "ensemble_relative_error"}
    ax = figures["ensemble_rollout"].axes[0]
    band = ax.collections[0].get_paths()[0].vertices[:, 1]
    assert band.min() == pytest.approx(float(true[0, :, 0].min()), abs=1e-6)  # member 0: the lower edge
    assert band.max() == pytest.approx(float(true[0, :, 0].max()) + 0.02, abs=1e-6)  # member 2: the upper edge
    assert "mean of 3 members" in [t.get_text() for t in figures["ensemble_rollout"].legends[0].get_texts()]
    assert len(figures["ensemble_relative_error"].axes[0].lines) == 4  # 3 members and their mean
