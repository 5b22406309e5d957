"""Controllers from learned models (``encons.tools.control``): the oracle swings up, the LQR is the Riccati
solution of the true linearisation, models without an energy are refused, and one command scores a run."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.linalg
import scipy.signal
import torch

from encons.entry import cli
from encons.infra.errors import ConfigError
from encons.models.hnn import HNNStructure
from encons.models.lnode import forced_euler_lagrange
from encons.models.node import NODE
from encons.systems.controlled import CartPole, ControlledPendulum
from encons.systems.pendulum import NPendulum
from encons.tools import control


@pytest.mark.parametrize("system", [ControlledPendulum(), CartPole()], ids=["pendulum", "cartpole"])
def test_forced_euler_lagrange_of_the_true_mass_and_potential_is_the_true_field(system):
    """The field every controller is built from, fed the true M(q), V(q), B, is the closed-form dynamics."""
    s = system.sample_initial(64, torch.Generator().manual_seed(1))
    u = system.sample_controls(64, torch.Generator().manual_seed(2))
    field = forced_euler_lagrange(system.mass_matrix, system.potential, system.input_matrix(), s, u)
    torch.testing.assert_close(field, system.vector_field(s, "angle", u), rtol=1e-10, atol=1e-10)


def true_swing_up(system, h: float, starts: int):
    """The controller built from the true model on ``system``, run on it from ``starts`` seeded (0) starts
    over its declared ``controller`` duration at control period ``h``: plant, settings, closed-loop states and inputs,
    metrics and each start's time to upright (``control.score``)."""
    settings = system.controller
    plant = control.true_plant(system)
    init = system.sample_initial(starts, torch.Generator().manual_seed(0))
    states, inputs = control.closed_loop(
        system, control.SwingUp(plant, system, h), init, h, round(settings.duration / h)
    )
    return plant, settings, states, inputs, *control.score(plant, states, inputs, settings, h)


def test_true_pendulum_controller_swings_up_and_holds_95_percent_within_time_and_input_limit():
    """Energy pumping + LQR from the true model: ≥ 95 % of 100 seeded starts upright (|θ| ≤ 0.1 rad,
    |θ̇| ≤ 0.5 rad/s) and held the last 2 s of 10 s, with |u| ≤ u_max = 2 N·m."""
    system, h = ControlledPendulum(), 0.1
    plant, settings, states, inputs, metrics, t_up = true_swing_up(system, h, 100)
    assert metrics["success_rate"] >= 0.95
    assert inputs.abs().max() <= system.u_max
    assert t_up[torch.isfinite(t_up)].max() <= settings.duration - settings.hold
    held = plant.error(states[torch.isfinite(t_up), -round(settings.hold / h) :])
    assert (held[..., 0].abs() <= 0.1).all() and (held[..., 1].abs() <= 0.5).all()


def test_cartpole_lqr_from_the_linearised_true_model_matches_the_closed_form_riccati_gain():
    """A, B by jacrev of the true field equal the closed-form linearisation at upright, and K equals the
    discrete LQR gain of that closed form (ZOH by scipy.signal, scipy's DARE) to 1e-6."""
    system, h = CartPole(), 0.05
    mc, mp, l, g = system.mc, system.mp, system.l, system.g  # noqa: E741 - l: the pole's length, as the paper writes it
    mass = np.array([[mc + mp, mp * l], [mp * l, 4 / 3 * mp * l**2]])  # M(0)
    gravity = np.array([[0.0, 0.0], [0.0, mp * g * l]])  # −∂²V/∂q² at θ = 0 (V = m_p g l cos θ)
    a = np.block([[np.zeros((2, 2)), np.eye(2)], [np.linalg.solve(mass, gravity), np.zeros((2, 2))]])
    b = np.concatenate([np.zeros((2, 1)), np.linalg.solve(mass, np.array([[1.0], [0.0]]))])
    lin_a, lin_b = control.linearise(control.true_plant(system), 1)
    np.testing.assert_allclose(lin_a.numpy(), a, atol=1e-12)
    np.testing.assert_allclose(lin_b.numpy(), b, atol=1e-12)

    weights = np.diag(CartPole.controller.q_weights)
    r = np.eye(1) * CartPole.controller.r_weight
    ad, bd, *_ = scipy.signal.cont2discrete((a, b, np.eye(4), np.zeros((4, 1))), h, method="zoh")
    p = scipy.linalg.solve_discrete_are(ad, bd, weights, r)
    reference = np.linalg.solve(r + bd.T @ p @ bd, bd.T @ p @ ad)
    gain, cost = control.lqr(lin_a, lin_b, torch.from_numpy(weights), torch.from_numpy(r), h)
    np.testing.assert_allclose(gain.numpy(), reference, rtol=0, atol=1e-6)
    np.testing.assert_allclose(cost.numpy(), p, rtol=1e-6)
    closed = ad - bd @ gain.numpy()
    assert np.abs(np.linalg.eigvals(closed)).max() < 1  # the sampled closed loop is stable


def test_true_cartpole_controller_swings_up():
    system = CartPole()
    *_, metrics, _ = true_swing_up(system, 0.05, 40)
    assert metrics["success_rate"] >= 0.95 and metrics["max_abs_u"] <= system.u_max


def test_a_model_without_an_energy_is_refused_in_one_line():
    with pytest.raises(ConfigError) as err:
        control.learned_plant(NODE(ControlledPendulum()), ControlledPendulum(), "encons.models.node.NODE")
    line = str(err.value)
    assert "\n" not in line and "gives no an energy" not in line
    assert (
        line.startswith("model._target_=encons.models.node.NODE gives no energy") and "allowed: a run of lnode" in line
    )


def test_a_run_on_a_system_without_inputs_is_refused_in_one_line():
    system = NPendulum(1)
    with pytest.raises(
        ConfigError,
        match=r"^system=pendulum1 has no controller here .*; allowed: a run on a system that declares "
        r"them, e.g. pendulum_control or cartpole$",
    ):
        control.learned_plant(HNNStructure(system), system, "encons.models.hnn.HNNStructure")


FAST = ["debug=fast", "figures=false", "logger=none", "trainer.enable_progress_bar=false", "~evaluators/santos"]


@pytest.mark.slow
@pytest.mark.parametrize(
    "model,system", [("lnode", "pendulum_control"), ("symo", "cartpole"), ("hnn_structure", "cartpole")]
)
def test_control_command_scores_a_tiny_trained_run(model, system, tmp_path, capsys):
    """Train a debug-size model, then ``python -m encons.control RUN`` (``encons.entry.cli.control``): metrics,
    figures."""
    from encons.entry import api

    api.train(
        api.compose(
            *FAST, f"model={model}", f"system={system}", output_dir=tmp_path / "run", cache_dir=tmp_path / "cache"
        )
    )
    cli.control([str(tmp_path / "run"), "starts=6", "seed=3", "duration=3"])
    out = tmp_path / "run" / "control"
    saved = json.loads((out / "control_metrics.json").read_text())
    assert saved["starts"] == 6 and saved["duration_s"] == pytest.approx(3.0)
    for key in ("success_rate", "time_to_upright_s", "effort", "max_abs_u"):
        assert f"control/{key}" in saved and f"oracle/{key}" in saved
    assert 0 <= saved["control/success_rate"] <= 1 and saved["control/max_abs_u"] <= 2.0 + 1e-12
    assert np.isfinite(saved["control/pred_rmse"]) and saved["control/pred_rmse"] > 0
    assert 0 < saved["control/a_rel_err"] < np.inf and 0 < saved["control/b_rel_err"] < np.inf
    for name in ("control_phase", "control_energy_input", "control_success", "control_portrait"):
        assert (out / f"{name}.png").stat().st_size > 10_000
    printed = capsys.readouterr().out
    assert "success_rate [% of starts]" in printed and "oracle" in printed


def test_control_prints_success_rate_in_percent_and_effort_with_its_unit():
    from encons.systems.controlled import CartPole, ControlledPendulum
    from encons.tools.control import printed_rows

    scores = {"control/success_rate": 0.93, "oracle/success_rate": 1.0, "control/effort": 4.5, "oracle/effort": 3.0}
    rows = dict(printed_rows(scores, ControlledPendulum()))
    assert rows["success_rate [% of starts]"] == ["93", "100"]
    assert rows["effort [∫ u² dt, (N m)² s]"] == ["4.5", "3"] and rows["a_rel_err [–]"] == ["", ""]
    assert "effort [∫ u² dt, (N)² s]" in dict(printed_rows(scores, CartPole()))


@pytest.mark.slow
def test_the_docs_control_snippet_runs_as_written(tmp_path, monkeypatch):
    """docs/control.md's Python block, run as written but at debug size (issue 51: it lacked the import and
    the run)."""
    import re
    from pathlib import Path

    text = (Path(__file__).parents[2] / "docs" / "control.md").read_text()
    block = re.search(r"```python\n(import encons\n.*?)```", text, re.S).group(1)
    monkeypatch.setenv("ENCONS_ROOT", str(tmp_path))
    small = block.replace('["model=lnode",', '["debug=fast", "figures=false", "logger=none", "model=lnode",')
    assert small != block
    scope: dict = {}
    exec(compile(small, "docs/control.md", "exec"), scope)
    assert 0 <= scope["metrics"]["control/success_rate"] <= 1 and scope["metrics"]["oracle/success_rate"] > 0


def test_score_control_is_exported_from_encons():
    import encons

    assert encons.score_control is control.score_control and "score_control" in dir(encons)


def test_control_command_refuses_a_node_run_and_a_bad_option_in_one_line(tmp_path, capsys):
    from encons.entry import api

    api.train(
        api.compose(
            *FAST, "model=node", "system=pendulum_control", output_dir=tmp_path / "run", cache_dir=tmp_path / "cache"
        )
    )
    capsys.readouterr()
    for args, expected in (
        ([str(tmp_path / "run")], "encons: error: model._target_=encons.models.node.NODE gives no energy"),
        ([str(tmp_path / "run"), "starts=many"], "encons: error: starts=many is not an integer"),
        ([str(tmp_path / "run"), "steps=3"], "encons: error: steps=3 is not an option of encons.tools.control"),
    ):
        with pytest.raises(SystemExit) as stop:
            cli.control(args)
        assert stop.value.code == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith(expected) and "\n" not in err and "Traceback" not in err


def test_control_profile_lists_the_energy_models_with_inputs_on_both_systems_per_n_train():
    from encons.tools.benchmark import expand
    from encons.training.build import compose

    cfg = compose(["profile=control"], config_name="benchmark")
    runs = expand(cfg)
    models = (
        "lnode",
        "lnode-learned_g",
        "symo",
        "e2e_symo",
        "hnn_structure",
        "hnn_structure-learned_g",
        "lnn_structure",
        "lnn_structure-learned_g",
    )
    assert cfg.control is True and len(runs) == 8 * 2 * 3 * 3
    assert {(r.system, r.label, r.n_train) for r in runs} == {
        (s, m, n) for s in ("pendulum_control", "cartpole") for m in models for n in (8, 32, 128)
    }
    for r in runs:  # per-step inputs on the cart-pole (benchmarks/reports/control-b), Santos et al.'s on the pendulum
        assert ("system.inputs=steps" in r.overrides) == (r.system == "cartpole")
        assert ("trainer.max_epochs=300" in r.overrides) == (r.system == "cartpole" or r.label == "symo")  # control-c
        assert ("trainer.gradient_clip_val=1.0" in r.overrides) == (r.label == "e2e_symo")  # control-c: seed 1
        assert "model.angular=true" in r.overrides  # every model embeds the angles (control-c, control)
        assert ("model.input_matrix=learned" in r.overrides) == r.label.endswith("learned_g")


@pytest.mark.slow
def test_control_profile_reports_the_controller_beside_the_oracle(tmp_path):
    from encons.entry.cli import benchmark as main

    out = tmp_path / "bench"
    main(
        [
            "profile=control",
            "seeds=[0]",
            "n_train=[8]",
            "n_train_models=[lnode]",
            "n_train_system=[pendulum_control]",
            f"out={out}",
            f"cache_dir={tmp_path / 'cache'}",
            'train=["debug=fast"]',
        ]
    )
    row = json.loads(next((out / "runs").glob("*/result.json")).read_text())
    assert not row["error"] and row["test/oracle/success_rate"] >= 0.95
    assert 0 <= row["test/control/success_rate"] <= 1
    control_dir = out / "runs" / "pendulum_control-lnode-n8-seed0" / "control"
    assert (control_dir / "control_phase.png").is_file() and (control_dir / "control_portrait.png").is_file()
    headline = (out / "summary.md").read_text().split("## Every metric")[0]
    assert "control/success_rate" in headline and "oracle/success_rate" in headline
    assert (out / "control_success_n_train.png").stat().st_size > 10_000
