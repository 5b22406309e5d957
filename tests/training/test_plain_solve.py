"""``experiment=paper``'s solve (``encons.training.attempts``): the plain inverse Hessian of Cranmer et al. / Xiao et
al. (``model.guard=0``) unless that training diverges, then again from scratch at the model's guard; the run says which.
And the presets of ``experiment=paper`` and ``debug=fast`` composed together."""

from __future__ import annotations

import json

import lightning.pytorch as pl
import pytest
import torch
from omegaconf import OmegaConf

from encons.config.check import apply_presets
from encons.entry import api
from encons.infra.errors import DivergenceError
from encons.models.lnn import LNN
from encons.tools.benchmark import resume_or_clear
from encons.training import attempts, runs
from encons.training.build import Request, catalogue, compose

PAPER = ["experiment=paper", "debug=fast", "system=pendulum1"]


def paper_run(tmp_path, *overrides: str):
    cfg = api.compose(*PAPER, *overrides, output_dir=tmp_path / "run", cache_dir=tmp_path / "cache")
    return runs.train(cfg)


def test_experiment_paper_with_debug_fast_composes_both():
    """debug comes after experiment: the paper's optimiser and plain solve at debug's sizes, both groups' presets."""
    cfg = compose(["model=chnn", *PAPER])
    assert (cfg.trainer.max_epochs, cfg.model.hidden, cfg.model.depth, cfg.data.n_train) == (2, 16, 2, 16)
    assert cfg.model.activation == "softplus" and cfg.optimizer.lr == 1e-3 and not cfg.scheduler  # not chnn's own
    assert cfg.plain_solve is True
    assert OmegaConf.to_container(cfg.preset_keys) == {
        "debug": ["model.hidden", "model.depth"],
        "experiment": ["model.hidden", "model.depth", "model.activation"],
    }


@pytest.mark.parametrize(
    "presets", [{"debug": ["model.hidden"], "experiment": ["model.activation"]}, ["model.hidden", "model.activation"]]
)  # the list of a config saved before
def test_every_groups_presets_are_dropped_where_the_constructor_lacks_them(presets):
    cfg = OmegaConf.create(
        {
            "model": {
                "_target_": "encons.numerics.evaluation.Evaluation",
                "hidden": 3,
                "activation": "tanh",
                "substeps": 2,
            },
            "preset_keys": presets,
        }
    )
    apply_presets(cfg, Request())
    assert OmegaConf.to_container(cfg.model) == {"_target_": "encons.numerics.evaluation.Evaluation", "substeps": 2}


def test_only_models_with_a_guard_get_the_plain_attempt_first():
    """Read from the model class (``guard: Guard``), not from a list of names; other models train once, unchanged."""
    configs = {m: compose([f"model={m}", *PAPER]) for m in catalogue("model")}
    plans = {m: attempts.plan(cfg, Request.of(cfg)) for m, cfg in configs.items()}
    guarded = {m for m, p in plans.items() if len(p) == 2}
    assert guarded == {"lnn", "lnn_angle", "glnn"}
    for m, plan in plans.items():
        if m in guarded:
            assert [(a.plain, a.cfg.model.guard) for a in plan] == [(True, 0.0), (False, 1e-3)]
        else:
            assert len(plan) == 1 and plan[0].plain is None and "guard" not in plan[0].cfg.model
    cfg = compose(["model=lnn", *PAPER[1:]])  # without experiment=paper: the guard as configured, once
    assert [(a.plain, a.cfg.model.guard) for a in attempts.plan(cfg, Request.of(cfg))] == [(None, 1e-3)]


def test_a_singular_hessian_at_guard_0_stops_training_as_a_divergence(tmp_path):
    """No NaN trained on: the first step's loss is NaN and Lightning's fit ends in a DivergenceError."""
    cfg = api.compose(
        "model=lnn",
        "system=pendulum1",
        "debug=fast",
        "model.guard=0",
        output_dir=tmp_path / "run",
        cache_dir=tmp_path / "cache",
    )
    data, module = api.build(cfg)
    with torch.no_grad():
        for p in module.model.lagrangian_net.parameters():
            p.zero_()  # L constant: ∇²_q̇L = 0 everywhere
    trainer = pl.Trainer(
        max_steps=3, logger=False, enable_checkpointing=False, enable_progress_bar=False, enable_model_summary=False
    )
    with pytest.raises(DivergenceError, match=r"loss is nan at epoch 1, step 0"):
        trainer.fit(module, datamodule=data)


def test_a_diverging_plain_inverse_trains_again_at_the_guard_and_the_run_says_so(tmp_path, monkeypatch, capsys, caplog):
    """∇²_q̇L forced singular everywhere: guard 0 diverges at once; guard 1e-3 solves it (q̈ = 0 there)."""
    derivatives = LNN.lagrangian_derivatives

    def singular(self, s):
        dl_dq, hessian, mixed = derivatives(self, s)
        return dl_dq, hessian * 0, mixed

    monkeypatch.setattr(LNN, "lagrangian_derivatives", singular)
    run = paper_run(tmp_path, "model=lnn")
    aside = run.run_dir / attempts.SET_ASIDE
    assert OmegaConf.load(aside / "config.yaml").model.guard == 0 and (aside / "checkpoints").is_dir()
    assert run.config.model.guard == 1e-3 and OmegaConf.load(run.run_dir / "config.yaml").model.guard == 1e-3
    assert run.checkpoint.parent == run.run_dir / "checkpoints"
    assert run.metrics["test/plain_inverse"] == 0
    assert json.loads((run.run_dir / "test_metrics.json").read_text())["plain_inverse"] == 0
    assert "training again from scratch at model.guard=0.001" in caplog.text
    summary = " ".join(capsys.readouterr().out.split())
    assert "solve: guarded (model.guard=0.001): the plain inverse (model.guard=0) diverged first" in summary
    for ckpt in (run.run_dir / "checkpoints" / "last.ckpt", "last"):  # a resume continues the guarded attempt
        cfg = api.compose(*PAPER, "model=lnn", f"ckpt_path={ckpt}", output_dir=tmp_path / "again")
        assert [(a.plain, a.cfg.model.guard) for a in attempts.plan(cfg, Request.of(cfg))] == [(False, 1e-3)]


def test_a_paper_run_that_does_not_diverge_keeps_the_plain_inverse(tmp_path, capsys):
    run = paper_run(tmp_path, "model=lnn")
    assert run.config.model.guard == 0 and run.metrics["test/plain_inverse"] == 1
    assert json.loads((run.run_dir / "test_metrics.json").read_text())["plain_inverse"] == 1
    assert not (run.run_dir / attempts.SET_ASIDE).exists()
    assert "solve: the plain inverse (model.guard=0)" in " ".join(capsys.readouterr().out.split())
    cfg = api.compose(*PAPER, "model=lnn", "ckpt_path=last", output_dir=tmp_path / "again")
    plan = attempts.plan(cfg, Request.of(cfg))  # a resume of the plain attempt, then the guarded one from scratch
    assert [(a.plain, a.cfg.model.guard, a.cfg.ckpt_path) for a in plan] == [(True, 0, "last"), (False, 1e-3, None)]
    cfg = api.compose(*PAPER, "model=lnn", output_dir=run.run_dir)
    resume_or_clear(cfg, run.run_dir / "checkpoints")  # the benchmark's resume finds the plain attempt's checkpoint
    assert cfg.ckpt_path == str(run.run_dir / "checkpoints" / "last.ckpt")


def test_a_table_marks_a_metric_a_model_does_not_report_apart_from_a_failed_run():
    """plain_inverse exists for lnn rows only: an hnn row shows – there, a row whose runs all failed 'failed'."""
    from encons.tools.report import markdown

    base = {"system": "pendulum2", "n_train": 800, "data_efficiency": False, "runs": 1, "optimiser": ""}
    summary = [
        {
            **base,
            "model": "lnn",
            "failed": 0,
            "test/traj_rel_err": 1.0,
            "test/traj_rel_err_sd": 0.0,
            "test/plain_inverse": 1.0,
            "test/plain_inverse_sd": 0.0,
        },
        {**base, "model": "hnn", "failed": 0, "test/traj_rel_err": 2.0, "test/traj_rel_err_sd": 0.0},
        {**base, "model": "node", "failed": 1},
    ]
    rows = {line.split(" | ")[1]: line.split(" | ")[4:6] for line in markdown(summary, {}).splitlines()[2:5]}
    assert rows == {"lnn": ["1", "1"], "hnn": ["2", "—"], "node": ["failed", "failed"]}  # one run: no "± 0"
