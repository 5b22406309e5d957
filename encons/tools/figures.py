"""Figures across runs of a benchmark or a profile (comparison, energy, control, data efficiency, Santos),
written by ``encons.tools.report``."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import torch

from encons.evaluators.figures import (
    ENERGY_ERR,
    ENERGY_MSE,
    PIXEL_MSE,
    REL_ERR,
    STATE_MSE,
    TIME,
    plain_log_ticks,
    save_png,
    subplots,
)

N_TRAIN_OFFSET = 1.04  # per model, on the log n_train axis


MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*")


STYLES = ("-", "--", "-.", ":")


SANTOS_PANELS = {
    "test/mse_train": "one-step train MSE of q [rad², m²]",
    "test/mse_test": "one-step test MSE of q [rad², m²]",
    "test/mse_integration": "integration MSE of q, 500 steps [rad², m²]",
    "test/energy_mse_integration": "energy MSE along the integration [J²]",
    "test/mass_mse": "M(q) MSE [(kg m²)²]",
}


#: A curve's mean past this ends the curve, as a non-finite one does: only a diverged rollout reaches it (its
#: threshold, ``encons.numerics.metrics.DIVERGED_ENERGY_ERROR``, is 1e10 in energy), and matplotlib's log axis
#: cannot place ticks past ~1e280 (an OverflowError instead of a figure; a Xiao compound GLNN member's energy MSE)
SHOWN_MAX = 1e100


def comparison_figures(rows: list[dict], summary: list[dict], out_dir: Path, horizon: int = 4) -> list[Path]:
    """The papers' comparison plots over a benchmark grid, one panel per system.

    Trajectory relative error per model (Zhong et al. Fig. 2: mean and std of its log over test
    trajectories, diverged trajectories left out; beside it the arithmetic mean the summary table gives),
    and relative error, absolute energy error and
    pixel MSE (runs on frames) vs time averaged over test trajectories and seeds (Figs. 3–4), and the
    state and energy MSE vs time (Xiao et al. Figs. 3 and 5, the whole curve: a single late-time value
    rewards a model that stops moving over one that drifts in phase), read
    from each run's ``test_curves.npz``; a curve no run has is left out.
    """
    import numpy as np

    systems = list(dict.fromkeys(e["system"] for e in summary))
    paths = []
    fig, axes = subplots(1, len(systems), figsize=(5.5 * len(systems), 5), squeeze=False)
    for ax, system in zip(axes[0], systems):
        errors: dict[str, list] = {}  # per test trajectory, pooled over seeds
        for row in rows:
            path = Path(row["run_dir"]) / "test_curves.npz"
            if row["system"] == system and path.is_file():
                with np.load(path) as f:
                    errors.setdefault(row["model"], []).append(f["rel_err"][:, : horizon + 1].sum(1))
        models = list(errors)
        logs = [np.log10(np.concatenate(errors[m])) for m in models]
        mean = np.array([lg[np.isfinite(lg)].mean() for lg in logs])
        std = np.array([lg[np.isfinite(lg)].std() for lg in logs])
        ax.errorbar(
            range(len(models)),
            10**mean,
            yerr=[10**mean - 10 ** (mean - std), 10 ** (mean + std) - 10**mean],
            fmt="o",
            capsize=3,
            label="geometric mean over test trajectories and seeds,\nbars: ± 1 std of log₁₀",
        )
        arithmetic = [np.concatenate(errors[m]).mean() for m in models]  # the summary table's traj_rel_err
        ax.plot(
            range(len(models)),
            arithmetic,
            "D",
            color="C3",
            ms=5,
            mfc="none",
            label="arithmetic mean (the table's traj_rel_err)",
        )
        ax.set_xticks(range(len(models)), models, rotation=60, ha="right", rotation_mode="anchor")
        ax.set_yscale("log")
        plain_log_ticks(ax.yaxis)
        ax.set_title(system)
        ax.set_xlabel("model")
        ax.set_ylabel(f"trajectory relative error, Σ over t ≤ {horizon} steps [–]")
        ax.legend(fontsize=7)
    paths.append(save_png(fig, out_dir / "traj_rel_err.png"))

    for key, label, name in (
        ("rel_err", REL_ERR, "rel_err_vs_time.png"),
        ("energy_err", ENERGY_ERR, "energy_err_vs_time.png"),
        ("state_mse_model", STATE_MSE, "state_mse_vs_time.png"),
        ("energy_mse_model", ENERGY_MSE, "energy_mse_vs_time.png"),
        ("pixel_mse", PIXEL_MSE, "pixel_mse_vs_time.png"),
    ):
        if not any(key in _curve_keys(row) for row in rows):
            continue
        fig, axes = subplots(1, len(systems), figsize=(4.5 * len(systems) + 2, 4), squeeze=False)
        styles: dict[str, int] = {}  # one colour and line style per model, the same in every panel (11+ models)
        for ax, system in zip(axes[0], systems):
            curves: dict[str, list] = {}
            for row in rows:
                path = Path(row["run_dir"]) / "test_curves.npz"
                if row["system"] == system and path.is_file():
                    with np.load(path) as f:
                        if key in f.files:
                            curve = f[key] if f[key].ndim == 1 else f[key].mean(0)  # MSE curves: already means
                            curves.setdefault(row["model"], []).append((f["t"], curve))
            for model, runs in curves.items():
                k = styles.setdefault(model, len(styles))
                mean = np.mean([c for _, c in runs], 0)[1:]
                ax.plot(
                    runs[0][0][1:],
                    np.where(np.isfinite(mean) & (np.abs(mean) < SHOWN_MAX), mean, np.nan),
                    label=model,
                    color=matplotlib.colormaps["tab20"](k % 20),
                    linestyle=("-", "--", ":")[k // 10 % 3],
                )
            ax.set_yscale("log")
            ax.set_xlabel(TIME)
            ax.set_ylabel(label)
            ax.set_title(system)
        handles = {h.get_label(): h for ax in axes[0] for h in ax.get_lines()}
        fig.legend(list(handles.values()), list(handles), loc="center right", fontsize=7)
        fig.suptitle("mean over test trajectories and seeds (a diverged rollout ends its model's curve)", fontsize=9)
        fig.tight_layout(rect=(0, 0, 1 - 2.2 / fig.get_figwidth(), 1))
        paths.append(save_png(fig, out_dir / name, layout=False))
    return paths


def _curve_keys(row: dict) -> list[str]:
    """The curves a benchmark run saved in its ``test_curves.npz`` (none without the file)."""
    import numpy as np

    path = Path(row["run_dir"]) / "test_curves.npz"
    if not path.is_file():
        return []
    with np.load(path) as f:
        return list(f.files)


def energy_rmse_figure(summary: list[dict], paper: dict[str, dict], out_dir: Path) -> list[Path]:
    """Lim & Kasim Table 1 as a plot: median energy-deviation RMSE per model with its 2.5–97.5 %
    range over test trajectories (averaged over seeds), the paper's median as a cross, per system."""
    entries = [e for e in summary if "test/energy_rmse_median" in e]
    systems = list(dict.fromkeys(e["system"] for e in entries))
    if not systems:
        return []
    fig, axes = subplots(1, len(systems), figsize=(4.5 * len(systems), 4), squeeze=False)
    for ax, system in zip(axes[0], systems):
        rows = [e for e in entries if e["system"] == system]
        x = range(len(rows))
        med = [e["test/energy_rmse_median"] for e in rows]
        lo = [m - e["test/energy_rmse_p2_5"] for m, e in zip(med, rows)]
        hi = [e["test/energy_rmse_p97_5"] - m for m, e in zip(med, rows)]
        ax.errorbar(x, med, yerr=[lo, hi], fmt="o", capsize=3, label="encons (median, 2.5–97.5 %)")
        published = [(k, paper.get(f"{system}/{e['model']}", {}).get("energy_rmse_median")) for k, e in enumerate(rows)]
        published = [(k, v) for k, v in published if v is not None and v != float("inf")]
        if published:
            ax.plot(*zip(*published), "x", color="k", label="paper (median)")
        ax.set_xticks(list(x), [e["model"] for e in rows], rotation=60)
        ax.set_yscale("log")
        ax.set_ylabel("RMSE of E(ŝ_t) − E(s_t) [energy units]")
        ax.set_title(system)
        ax.legend(fontsize=7)
    return [save_png(fig, out_dir / "energy_rmse.png")]


def _control_panels(summary: list[dict], width: float):
    """The rows of ``summary`` scored by ``encons.tools.control`` by system, and a figure of one panel per system
    (None: no such row)."""
    entries = [e for e in summary if "test/control/success_rate" in e]
    by_system = {
        system: [e for e in entries if e["system"] == system] for system in dict.fromkeys(e["system"] for e in entries)
    }
    if not by_system:
        return None
    fig, axes = subplots(1, len(by_system), figsize=(width * len(by_system), 4), squeeze=False, sharey=True)
    return fig, axes, by_system


def control_success_figure(summary: list[dict], out_dir: Path) -> list[Path]:
    """Swing-up success rate per model (``encons.tools.control``, mean ± std over seeds) beside the same
    controller built from the true model (oracle), one panel per system."""
    panels = _control_panels(summary, 4.5)
    if panels is None:
        return []
    fig, axes, by_system = panels
    for ax, (system, rows) in zip(axes[0], by_system.items()):
        x = torch.arange(len(rows), dtype=torch.float64)
        for offset, side, label in (
            (-0.2, "control", "controller from the learned model"),
            (0.2, "oracle", "same controller from the true model"),
        ):
            ax.bar(
                x + offset,
                [e[f"test/{side}/success_rate"] for e in rows],
                width=0.4,
                yerr=[e.get(f"test/{side}/success_rate_sd", 0.0) for e in rows],
                capsize=3,
                label=label,
            )
        ax.set_xticks(x.tolist(), [e["model"] for e in rows])
        ax.set_ylim(0, 1.3)
        ax.set_yticks([0, 0.2, 0.4, 0.6, 0.8, 1.0])
        ax.set_title(system)
        ax.set_xlabel("model")
        ax.legend(fontsize=7, loc="upper center")
    axes[0, 0].set_ylabel("success rate (held upright) [–]")
    return [save_png(fig, out_dir / "control_success_rate.png")]


def _against_n_train(ax, entries: list[dict], key: str, spread) -> set[int]:
    """One line per model (first-seen order, colour ``C<k>``, its own marker and line style) of ``key`` against
    ``n_train`` over ``entries`` (summary rows of one system), bars ± ``spread(row)`` (the lower one cut at 95 %
    of the value, so that it stays on a log axis), on log axes; each model's points are shifted by a few
    percent in n_train (``N_TRAIN_OFFSET``), so that equal values do not hide one line under another.
    Returns the sizes drawn."""
    sizes: set[int] = set()
    models = list(dict.fromkeys(e["model"] for e in entries))
    for k, model in enumerate(models):
        rows = sorted((e for e in entries if e["model"] == model and key in e), key=lambda e: e["n_train"])
        if not rows:
            continue
        mean = [e[key] for e in rows]
        bars = [spread(e) for e in rows]
        nudge = N_TRAIN_OFFSET ** (k - (len(models) - 1) / 2)
        ax.errorbar(
            [e["n_train"] * nudge for e in rows],
            mean,
            yerr=[[min(b, 0.95 * m) for b, m in zip(bars, mean)], bars],
            marker=MARKERS[k % len(MARKERS)],
            ls=STYLES[k % len(STYLES)],
            capsize=3,
            color=f"C{k % 10}",
            alpha=0.85,
            label=model,
        )
        sizes.update(e["n_train"] for e in rows)
    ax.set_yscale("log")
    ax.legend(fontsize=7, title=f"points shifted ×{N_TRAIN_OFFSET:g}ᵏ in n_train to stay apart", title_fontsize=7)
    return sizes


def data_efficiency_figure(summary: list[dict], out_dir: Path) -> list[Path]:
    """Zhong et al. Fig. 5: test trajectory relative error against the number of training
    trajectories, one line per model (mean over seeds), one panel per system. Bars: ± 1 std over seeds
    where a point has two or more seeds, else ± 1 std over test trajectories (cut at the axis where it
    reaches below 0)."""
    systems = list(dict.fromkeys(e["system"] for e in summary))
    seeds = min(e.get("runs", 1) for e in summary)
    fig, axes = subplots(1, len(systems), figsize=(6.5 * len(systems), 4.2), squeeze=False)
    for ax, system in zip(axes[0], systems):
        sizes = _against_n_train(
            ax,
            [e for e in summary if e["system"] == system],
            "test/traj_rel_err",
            lambda e: e["test/traj_rel_err_sd"] if seeds >= 2 else e.get("test/traj_rel_err_std", 0.0),
        )
        ax.set_xscale("log")
        plain_log_ticks(ax.xaxis, sizes)
        plain_log_ticks(ax.yaxis)
        ax.set_xlabel("training trajectories")
        ax.set_ylabel("trajectory relative error (T = 4) [–]")
        ax.set_title(
            f"data efficiency on {system}\nmean over {seeds} seed(s); bars: ± 1 std over "
            + ("seeds" if seeds >= 2 else "test trajectories"),
            fontsize=9,
        )
    return [save_png(fig, out_dir / "data_efficiency.png")]


def santos_figures(summary: list[dict], out_dir: Path) -> list[Path]:
    """Santos et al. Figs. 3 (pendulum) and 4 (cart-pole): each §7 metric against N_train, one line per
    model (mean over seeds; bars: std), one figure ``santos_<system>.png`` per system with these metrics."""
    paths = []
    for system in dict.fromkeys(e["system"] for e in summary if "test/mse_integration" in e):
        entries = [e for e in summary if e["system"] == system]
        fig, axes = subplots(1, len(SANTOS_PANELS), figsize=(4 * len(SANTOS_PANELS), 3.8))
        for ax, (key, label) in zip(axes, SANTOS_PANELS.items()):
            _against_n_train(ax, entries, key, lambda e, key=key: e[f"{key}_sd"])
            ax.set_xscale("log", base=2)
            ax.set_xlabel("training trajectories N_train")
            ax.set_ylabel(label)
        fig.suptitle(f"Santos et al. §7 metrics against N_train on {system}")
        paths.append(save_png(fig, out_dir / f"santos_{system}.png"))
    return paths


def control_n_train_figure(summary: list[dict], out_dir: Path) -> list[Path]:
    """Swing-up success rate against the number of training trajectories per model (mean ± std over
    seeds), the oracle's (the same controller from the true model) as a dashed line, one panel per system."""
    panels = _control_panels(summary, 5)
    if panels is None:
        return []
    fig, axes, by_system = panels
    for ax, (system, rows) in zip(axes[0], by_system.items()):
        for k, model in enumerate(dict.fromkeys(e["model"] for e in rows)):
            line = sorted((e for e in rows if e["model"] == model), key=lambda e: e["n_train"])
            ax.errorbar(
                [e["n_train"] for e in line],
                [e["test/control/success_rate"] for e in line],
                yerr=[e.get("test/control/success_rate_sd", 0.0) for e in line],
                marker="o",
                capsize=3,
                color=f"C{k}",
                label=model,
            )
        oracle = [e["test/oracle/success_rate"] for e in rows]
        ax.axhline(sum(oracle) / len(oracle), color="k", ls="--", lw=1, label="oracle (true model)")
        ax.set_xscale("log", base=2)
        ax.set_ylim(-0.05, 1.1)
        ax.set_title(system)
        ax.set_xlabel("training trajectories N_train")
        ax.legend(fontsize=7)
    axes[0, 0].set_ylabel("success rate (held upright) [–]")
    return [save_png(fig, out_dir / "control_success_n_train.png")]
