"""Figures a reader can read: distinct colours per coordinate, one legend, units from the system, a
labelled choice of test trajectories, the model's config name, an MSE axis not stretched by a ~1e-14
baseline, and plain log ticks."""

from __future__ import annotations

import pytest
import torch

from encons.evaluators import figures as run_figures
from encons.numerics import metrics
from encons.systems.controlled import CartPole
from encons.systems.mass_spring import MassSpring
from encons.systems.pendulum import NPendulum
from encons.tools import figures as cross_figures
from encons.training.build import run_config


def described(fig) -> dict:
    """What a reader sees of a figure: its legends and, per axes, labels, title, limits, ticks and lines."""
    fig.canvas.draw()
    axes = [
        (
            ax.get_ylabel(),
            ax.get_title(),
            ax.get_legend() is not None,
            ax.get_ylim(),
            [t.get_text() for t in ax.get_yticklabels()],
            [t.get_text() for t in ax.get_xticklabels()],
            [line.get_label() for line in ax.get_lines()],
        )
        for ax in fig.axes
    ]
    return {
        "legends": len(fig.legends),
        "axes": axes,
        "legend_labels": [t.get_text() for lg in fig.legends for t in lg.get_texts()],
    }


@pytest.fixture
def saved(monkeypatch):
    """The figures ``save_png`` saves, by file name, described before they are closed."""
    figures = {}
    original = run_figures.save_png

    def keep(fig, path, layout=True):
        path = original(fig, path, layout)
        figures[path.name] = described(fig)
        return path

    for module in (run_figures, cross_figures):
        monkeypatch.setattr(module, "save_png", keep)
    return figures


def test_colours_are_distinct_for_twelve_and_more_coordinates():
    for k in (3, 12, 20, 30):
        assert len({tuple(round(c, 3) for c in colour) for colour in run_figures.colours(k)}) == k


def test_rollout_figure_one_legend_units_and_a_labelled_choice():
    t = torch.arange(11) * 0.1
    true = torch.randn(7, 11, 24)
    pred = true + torch.linspace(0.01, 1.0, 7)[:, None, None]  # trajectory 0 best, 6 worst
    figures = run_figures.rollout_figures(
        t, pred, true, None, "hnn_angle on gyroscope", units=("rad",) * 12, baseline=true * 0.5, chart="cartesian"
    )
    assert list(figures) == ["rollout", "relative_error"]  # no energies: no energy_error
    fig = described(figures["rollout"])
    assert fig["legends"] == 1 and not any(has_legend for _, _, has_legend, *_ in fig["axes"])
    labels = fig["legend_labels"]
    assert "q₁₂ [rad], q̇₁₂ [rad/s]" in labels and "linear-ODE baseline" in labels and "model" in labels
    # issue 51: 12 coordinates are 4 rows of 3 per panel (truth, model, baseline each), the model on top
    assert len(fig["axes"]) == 8 * 3 and all(len(lines) == 9 for *_, lines in fig["axes"])
    rollout = figures["rollout"]
    truth, model = rollout.axes[0].get_lines()[:3:2]
    assert model.get_linestyle() == "--" and model.get_zorder() > truth.get_zorder()
    assert rollout.legends[0].get_title().get_text() == ""  # no unexplained "common chart"
    assert "states drawn in the cartesian chart" in rollout._suptitle.get_text()
    ylabels = {ylabel for ylabel, *_ in fig["axes"]}
    assert ylabels == {"position q [rad]", "velocity q̇ [rad/s]"}
    titles = [title for _, title, *_ in fig["axes"] if title]
    assert titles == [
        "test trajectory 0 (best of 7 by relative error)",
        "test trajectory 3 (median of 7 by relative error)",
        "test trajectory 6 (worst of 7 by relative error)",
    ]


def test_units_come_from_the_system():
    assert NPendulum(2).units("angle") == ("rad", "rad") and NPendulum(2).units("cartesian") == ("m",) * 4
    assert CartPole().units("angle") == ("m", "rad") and MassSpring().units("angle") == ("m",)
    assert (
        run_figures.unit_label(("m", "rad")) == "[see legend]"
        and run_figures.unit_label(("rad",), rate=True) == "[rad/s]"
    )


def test_mse_axis_is_not_stretched_by_a_constant_baseline_energy_error():
    t = torch.arange(21) * 0.1
    rising = torch.logspace(-3, 0, 21)
    curves = {
        "model": {"state_mse": rising, "energy_mse": rising},
        "baseline_constant": {"state_mse": rising * 3, "energy_mse": torch.full((21,), 1e-14)},
        "baseline_linear_ode": {"state_mse": rising * 2, "energy_mse": rising * 5},
    }
    figure = run_figures.mse_figure(t, curves, "node on pendulum", units=("rad",))["mse_vs_time"]
    (state_label, _, _, state_lim, *_), (_, _, _, energy_lim, _, _, energy_lines) = described(figure)["axes"]
    assert state_label == "state MSE, each coordinate / its test-set spread [–]"
    assert energy_lim[0] > 1e-5 and energy_lim[1] / energy_lim[0] < 1e5  # not 14 decades
    assert "constant (below the axis: ≤ 1e-14)" in energy_lines


def test_an_mse_curve_that_runs_away_to_the_float_limit_is_drawn_at_the_ceiling():
    t = torch.arange(21) * 0.1
    runaway = torch.logspace(
        -3, 308, 21, dtype=torch.float64
    )  # a rollout's MSE reaching 1e308: the axis top once overflowed
    runaway[-1] = float("inf")
    curves = {"model": {"state_mse": runaway}, "baseline_constant": {"state_mse": torch.logspace(-3, 0, 21)}}
    figure = run_figures.mse_figure(t, curves, "lnn on pendulum4", units=("rad",))["mse_vs_time"]
    ((_, _, _, limits, *_),) = described(figure)["axes"]
    assert limits[1] == pytest.approx(2 * run_figures.CEILING) and limits[0] == pytest.approx(10 ** (311 / 20 - 3) / 2)


def test_data_efficiency_ticks_are_the_sizes_and_bars_are_drawn(tmp_path, saved):
    summary = [
        {
            "system": "pendulum2",
            "model": m,
            "n_train": n,
            "runs": 1,
            "test/traj_rel_err": e,
            "test/traj_rel_err_sd": 0.0,
            "test/traj_rel_err_std": e / 2,
        }
        for m in ("hnn", "node")
        for n, e in ((10, 1.28), (100, 0.5), (1000, 0.2))
    ]
    cross_figures.data_efficiency_figure(summary, tmp_path)
    ((_, title, _, _, yticks, xticks, _),) = saved["data_efficiency.png"]["axes"]
    assert [x for x in xticks if x] == ["10", "100", "1000"] and "×" not in "".join(yticks)
    assert "bars: ± 1 std over test trajectories" in title


def test_data_efficiency_does_not_hide_a_model_under_another(tmp_path, monkeypatch):
    """Issue 51: two models with equal values drew one line exactly over the other."""
    kept = {}
    for module in (run_figures, cross_figures):
        monkeypatch.setattr(module, "save_png", lambda fig, path, layout=True: kept.setdefault(path.name, fig) and path)
    summary = [
        {
            "system": "pendulum2",
            "model": m,
            "n_train": n,
            "runs": 1,
            "test/traj_rel_err": 0.5,
            "test/traj_rel_err_sd": 0.0,
            "test/traj_rel_err_std": 0.1,
        }
        for m in ("hnn", "node")
        for n in (10, 100)
    ]
    cross_figures.data_efficiency_figure(summary, tmp_path)
    hnn, node = (c.lines[0] for c in kept["data_efficiency.png"].axes[0].containers)
    assert list(hnn.get_xdata()) != list(node.get_xdata()) and hnn.get_marker() != node.get_marker()
    assert hnn.get_linestyle() != node.get_linestyle()


def test_traj_rel_err_figure_draws_the_tables_arithmetic_mean(tmp_path, saved):
    import numpy as np

    rows = []
    for model, errors in (("hnn", [[0.1] * 5, [10.0] * 5]), ("node", [[1.0] * 5] * 2)):  # geometric 1, arithmetic 5.05
        run = tmp_path / model
        run.mkdir()
        np.savez(run / "test_curves.npz", rel_err=np.array(errors) / 5, t=np.arange(5) * 0.1)
        rows.append({"system": "pendulum1", "model": model, "run_dir": str(run)})
    cross_figures.comparison_figures(rows, [{"system": "pendulum1"}], tmp_path)
    ((*_, lines),) = saved["traj_rel_err.png"]["axes"]
    assert "arithmetic mean (the table's traj_rel_err)" in lines


def test_the_run_title_names_the_models_config(tmp_path):
    from encons.entry import api

    cfg = api.compose(
        "debug=fast", "model=hnn_angle", "system=pendulum1", output_dir=tmp_path / "run", cache_dir=tmp_path / "cache"
    )
    assert run_config(cfg).model_name == "hnn_angle"
    assert api.build(cfg)[1].run_title() == "hnn_angle on pendulum1 (learns in the angle chart)"  # not HNN


def test_the_rollout_figure_draws_the_linear_ode_baseline_that_was_scored(train_run, monkeypatch):
    """One least-squares fit and one rollout of the linear-ODE baseline per test: the figure's is the scored one."""
    from encons.numerics import metrics

    fits, drawn = [], []
    fit, figures = metrics.fit_linear_ode, run_figures.rollout_figures
    monkeypatch.setattr(metrics, "fit_linear_ode", lambda *a, **k: fits.append(1) or fit(*a, **k))
    monkeypatch.setattr(run_figures, "rollout_figures", lambda *a, **k: drawn.append(k["baseline"]) or figures(*a, **k))
    train_run(["model=node", "system=pendulum1"], figures=True)
    assert len(fits) == 1 and len(drawn) == 1 and torch.isfinite(drawn[0]).all()


def test_mse_per_unit_family_and_named_multi_body_coordinates():
    from encons.systems.base import CartesianLayout

    families = metrics.unit_families(("m", "rad"))
    assert {k: v.tolist() for k, v in families.items()} == {
        "m": [True, False, False, False],
        "rad": [False, True, False, False],
        "m_per_s": [False, False, True, False],
        "rad_per_s": [False, False, False, True],
    }
    pred, true = torch.zeros(2, 3, 4), torch.zeros(2, 3, 4)
    pred[..., 2] = 1.0  # only the m/s entry is off
    curves = metrics.mse_curves(pred, true, families=families)
    assert curves["state_mse_m_per_s"].tolist() == [1.0] * 3 and curves["state_mse_m"].tolist() == [0.0] * 3
    assert curves["state_mse_raw"].tolist() == [0.25] * 3  # Xiao's mean over every entry, units mixed
    names = run_figures.coordinate_names(24, CartesianLayout(4, 3, ((0, 1, 2, 3),)))
    assert (
        names[:4] == ["x₁ (body 1)", "y₁ (body 1)", "z₁ (body 1)", "x₂ (body 1)"] and names[12] == "x\u0307₁ (body 1)"
    )


def test_rollout_figures_draw_an_unwrapped_angle_at_its_window_start_on_the_circle():
    t = torch.arange(11) * 0.1
    true = torch.stack([torch.linspace(0.5, 1.5, 11) - 4 * torch.pi, torch.ones(11)], -1).expand(3, 11, 2).clone()
    pred = true + 0.01 * torch.arange(3)[:, None, None]
    figure = run_figures.rollout_figures(
        t, pred, true, None, "node on from_file", units=("rad",), angles=torch.tensor([True, False])
    )["rollout"]
    position = figure.axes[0]
    assert "drawn as q₁ + 2·2π" in position.get_title()
    drawn = torch.cat([torch.as_tensor(line.get_ydata()) for line in position.get_lines()])
    assert 0.4 < drawn.min() and drawn.max() < 1.6  # at 0.5..1.5 rad, not at −12 rad
