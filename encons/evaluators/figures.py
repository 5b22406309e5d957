"""One run's figures (test rollouts, errors, energies, pixels, control), saved as PNG and logged to the run's
logger, and the helpers every figure shares (labels, units, colours, PNG writing)."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import torch
from matplotlib.figure import Figure
from torch import Tensor

from encons.infra.io import save_figure
from encons.numerics import metrics


def subplots(*grid: int, figsize: tuple[float, float], **kwargs):
    """``(figure, axes)`` like ``pyplot.subplots``, on a bare ``Figure``: no pyplot state and no backend
    choice, so figures are drawn the same in a script, on a server and in a notebook."""
    fig = Figure(figsize=figsize)
    return fig, fig.subplots(*grid, **kwargs)


TIME = "time t [s]"


REL_ERR = "relative error ‖ŝₜ − sₜ‖ / ‖sₜ‖ [–]"


ENERGY_ERR = "energy error |E(ŝₜ) − E(sₜ)| [J]"


STATE_MSE = "state MSE, each coordinate / its test-set spread [–]"


ENERGY_MSE = "energy MSE of E(ŝₜ) against E(sₜ) [J²]"


def coordinate_names(width: int, layout=None) -> list[str]:
    """Names of the 2n state entries of a (common-chart) state of ``width`` entries: q₁…qₙ, q̇₁…q̇ₙ; with a
    Cartesian ``layout`` (``CartesianLayout``), each point's axes, x₁ y₁ z₁ x₂ … and ẋ₁ …, point k of body b
    named ``b<b>.<k>`` (a multi-body figure groups its lines by body)."""
    sub = str.maketrans("0123456789", "₀₁₂₃₄₅₆₇₈₉")
    n = width // 2
    if layout is None or layout.size != n:
        return [f"q{str(i + 1).translate(sub)}" for i in range(n)] + [f"q̇{str(i + 1).translate(sub)}" for i in range(n)]
    body = {p: (b, k) for b, points in enumerate(layout.bodies) for k, p in enumerate(points)}
    several = len(layout.bodies) > 1 or any(len(points) > 1 for points in layout.bodies)
    names = [
        f"{'xyz'[a]}{str(p + 1).translate(sub)}" + (f" (body {body[p][0] + 1})" if several and p in body else "")
        for p in range(layout.n_points)
        for a in range(layout.dim)
    ]
    return names + [name[0] + "\u0307" + name[1:] for name in names]


def colours(k: int) -> list:
    """``k`` distinguishable colours: tab10 up to 10, tab20's dark then light halves up to 20, else evenly
    spaced hues of ``turbo``."""
    if k <= 10:
        return [matplotlib.colormaps["tab10"](i) for i in range(k)]
    if k <= 20:
        return [matplotlib.colormaps["tab20"](2 * i if i < 10 else 2 * (i - 10) + 1) for i in range(k)]
    return [matplotlib.colormaps["turbo"](i / (k - 1)) for i in range(k)]


def unit_label(units: tuple[str, ...], rate: bool = False) -> str:
    """``[rad]`` (``[rad/s]`` for rates) when every coordinate shares one unit, else ``[see legend]``."""
    unique = set(units)
    return f"[{next(iter(unique))}{'/s' if rate else ''}]" if len(unique) == 1 else "[see legend]"


def _band(ax, t: Tensor, values: Tensor, ylabel: str, time_label: str = TIME) -> None:
    """Median over trajectories with the 2.5–97.5 percentile band, log scale."""
    lo, med, hi = torch.quantile(values.double(), torch.tensor([0.025, 0.5, 0.975], dtype=torch.float64), dim=0)
    ax.plot(t, med, label="median over test trajectories")
    ax.fill_between(t, lo, hi, alpha=0.25, label="2.5–97.5 percentile")
    ax.set_yscale("log")
    ax.set_xlabel(time_label)
    ax.set_ylabel(ylabel)
    ax.legend()


def window_offset(true: Tensor, angles: Tensor | None) -> Tensor:
    """Per window (N, 1, D): 2πk on each angle entry, k such that the window's first true angle minus it
    lies in [−π, π); zero elsewhere. Subtracted from truth and predictions alike, it draws a window of an
    unwrapped recording (at −42 rad, say) where the angle is, without the jumps that wrapping every sample makes."""
    if angles is None:
        return torch.zeros_like(true[..., :1, :])
    turns = torch.round(true[..., :1, :] / (2 * torch.pi)) * (2 * torch.pi)
    return torch.where(angles.to(true.device), turns, torch.zeros_like(turns))


ROLLOUT_GROUP = 3  # coordinates per rollout panel: a 12-coordinate gyroscope is 4 rows of 3, not 12 lines a panel


def _state_grid(true: Tensor, units: tuple[str, ...] | None, names: list[str] | None, angles: Tensor | None):
    """What a figure of state panels needs: n, the coordinate ``names`` and ``units`` (defaults: q₁…, unitless),
    the per-window 2πk ``shift`` (``window_offset``), a colour per coordinate and the coordinate groups of a panel."""
    n = true.shape[-1] // 2
    groups = [range(g, min(g + ROLLOUT_GROUP, n)) for g in range(0, n, ROLLOUT_GROUP)]
    return (
        n,
        names or coordinate_names(true.shape[-1]),
        tuple(units) if units is not None else ("–",) * n,
        window_offset(true, angles),
        colours(n),
        groups,
    )


def _state_panels(
    axes,
    t: Tensor,
    true: Tensor,
    pred: Tensor,
    n: int,
    units: tuple[str, ...],
    palette: list,
    groups: list[range],
    baseline: Tensor | None = None,
    band: tuple[Tensor, Tensor] | None = None,
) -> None:
    """One column of state panels (``axes``: one per group, positions then velocities) of one trajectory (T, D):
    the truth wide and pale, the ``baseline`` dotted, the ``band`` (low, high) shaded, the model dashed on top."""
    for g, group in enumerate(groups):
        for rate in (False, True):
            ax = axes[2 * g + rate]
            for d in group:
                idx = d + n * rate
                ax.plot(t, true[:, idx], lw=2.6, alpha=0.45, color=palette[d], zorder=2)
                if band is not None:
                    ax.fill_between(t, band[0][:, idx], band[1][:, idx], color=palette[d], alpha=0.2, lw=0, zorder=1)
                if baseline is not None:
                    ax.plot(t, baseline[:, idx], ":", color=palette[d], lw=1.0, zorder=2.5)
                ax.plot(t, pred[:, idx], "--", color=palette[d], lw=1.3, zorder=3)
            unit = unit_label(units[group.start : group.stop], rate)
            ax.set_ylabel(f"{'velocity q̇' if rate else 'position q'} {unit}")


def _coordinate_handles(names: list[str], units: tuple[str, ...], n: int, palette: list) -> list:
    """Legend entries: a colour per coordinate (its position and velocity) and the wide pale truth."""
    from matplotlib.lines import Line2D

    return [
        Line2D([], [], color=palette[d], lw=2, label=f"{names[d]} [{units[d]}], {names[d + n]} [{units[d]}/s]")
        for d in range(n)
    ] + [Line2D([], [], color="k", lw=2.6, alpha=0.45, label="truth")]


def rollout_figures(
    t: Tensor,
    pred: Tensor,
    true: Tensor,
    energies: list[Tensor] | None,
    title: str,
    units: tuple[str, ...] | None = None,
    baseline: Tensor | None = None,
    angles: Tensor | None = None,
    names: list[str] | None = None,
    time_label: str | None = None,
    chart: str | None = None,
) -> dict[str, Figure]:
    """Rollout vs truth (every coordinate, positions and velocities) of three test trajectories — the
    best, median and worst by relative error summed over the rollout, each labelled so — with the
    linear-ODE ``baseline``'s rollout if given; relative error vs time and (if known) energy error vs
    time. States are in the system's common chart (``chart``, named in the title), whose coordinate
    ``units`` label the axes (default: unitless) and ``names`` the legend (default q₁…, q̇₁…); ``angles``
    (bool (D,)) are scored on the circle and drawn offset by the 2πk that puts each window's start in
    [−π, π) (``window_offset``). At most ``ROLLOUT_GROUP`` coordinates share a panel (one row of panels per
    group, positions then velocities); the truth is drawn wide and pale, the model dashed on top of it.
    Figures by file stem, laid out: ``rollout``, ``relative_error``, ``energy_error``."""
    from matplotlib.lines import Line2D

    figures = {}
    time_label = time_label or TIME
    n, names, units, shift, palette, groups = _state_grid(true, units, names, angles)
    pred, true = pred - shift, true - shift
    baseline = None if baseline is None else baseline - shift
    score = metrics.relative_error(pred, true, angles).nan_to_num(float("inf")).sum(-1)
    order = torch.argsort(score).tolist()
    picks = dict.fromkeys([order[0], order[len(order) // 2], order[-1]])  # best, median, worst (distinct)
    tags = {order[0]: "best", order[len(order) // 2]: "median", order[-1]: "worst"}
    fig, axes = subplots(
        2 * len(groups),
        len(picks),
        figsize=(4.6 * len(picks) + 1.9, 2.2 + 2.4 * 2 * len(groups)),
        squeeze=False,
        sharex=True,
    )
    for col, k in enumerate(picks):
        _state_panels(
            axes[:, col],
            t,
            true[k],
            pred[k],
            n,
            units,
            palette,
            groups,
            baseline=None if baseline is None else baseline[k],
        )
        turns = [
            f"{names[d]} {'−' if turn > 0 else '+'} {abs(turn)}·2π"
            for d in range(n)
            if (turn := round(float(shift[k, 0, d]) / (2 * torch.pi)))
        ]
        axes[0, col].set_title(
            f"test trajectory {k} ({tags[k]} of {len(order)} by relative error)"
            + (f"\ndrawn as {', '.join(turns)}" if turns else ""),
            fontsize=9,
        )
        axes[-1, col].set_xlabel(time_label)
    handles = _coordinate_handles(names, units, n, palette)
    handles.append(Line2D([], [], color="k", ls="--", lw=1.3, label="model"))
    if baseline is not None:
        handles.append(Line2D([], [], color="k", ls=":", lw=1.0, label="linear-ODE baseline"))
    fig.legend(handles=handles, loc="center right", fontsize=7)
    fig.suptitle(title + (f"\nstates drawn in the {chart} chart (where the metrics compare)" if chart else ""))
    fig.tight_layout(rect=(0, 0, 1 - 1.9 / fig.get_figwidth(), 1 - 0.25 / fig.get_figheight()))
    figures["rollout"] = fig

    fig, ax = subplots(figsize=(6, 4))
    _band(ax, t[1:], metrics.relative_error(pred, true, angles)[:, 1:], REL_ERR, time_label)
    ax.set_title(f"{title}\nrelative error of the state", fontsize=9)
    figures["relative_error"] = laid_out(fig)

    if energies is not None:
        fig, ax = subplots(figsize=(6, 4))
        _band(ax, t[1:], metrics.energy_abs_error(*energies)[:, 1:].clamp_min(1e-12), ENERGY_ERR, time_label)
        ax.set_title(f"{title}\nabsolute error in true energy", fontsize=9)
        figures["energy_error"] = laid_out(fig)
    return figures


def ensemble_figures(
    t: Tensor,
    preds: Tensor,
    true: Tensor,
    title: str,
    seeds: list[int],
    units: tuple[str, ...] | None = None,
    angles: Tensor | None = None,
    names: list[str] | None = None,
    time_label: str | None = None,
) -> dict[str, Figure]:
    """A seed ensemble's spread where a reader looks: ``ensemble_rollout``, the members' rollouts ``preds``
    (K, N, T, D) of the test trajectory whose error (of the members' mean) is the median, as their mean (dashed)
    inside the band of the members' min–max, beside the truth (wide, pale), every coordinate, at most
    ``ROLLOUT_GROUP`` a panel; ``ensemble_relative_error``, each member's median relative error over the test
    trajectories against time, and their mean."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    time_label = time_label or TIME
    n, names, units, shift, palette, groups = _state_grid(true, units, names, angles)
    preds, true = preds - shift, true - shift
    errors = torch.stack([metrics.relative_error(p, true, angles) for p in preds])  # (K, N, T)
    score = errors.mean(0).nan_to_num(float("inf")).sum(-1)
    k = int(torch.argsort(score)[len(score) // 2])
    fig, axes = subplots(2 * len(groups), 1, figsize=(7.5, 2.2 + 2.4 * 2 * len(groups)), squeeze=False, sharex=True)
    _state_panels(
        axes[:, 0],
        t,
        true[k],
        preds[:, k].mean(0),
        n,
        units,
        palette,
        groups,
        band=(preds[:, k].amin(0), preds[:, k].amax(0)),
    )
    axes[-1, 0].set_xlabel(time_label)
    handles = _coordinate_handles(names, units, n, palette) + [
        Line2D([], [], color="k", ls="--", lw=1.3, label=f"mean of {len(seeds)} members"),
        Patch(color="k", alpha=0.2, label="members' min–max"),
    ]
    fig.legend(handles=handles, loc="center right", fontsize=7)
    fig.suptitle(
        f"{title} × seeds {', '.join(map(str, seeds))}\ntest trajectory {k} (median of {len(score)} by "
        f"the members' mean relative error)",
        fontsize=9,
    )
    fig.tight_layout(rect=(0, 0, 1 - 2.2 / fig.get_figwidth(), 1 - 0.3 / fig.get_figheight()))
    figures = {"ensemble_rollout": fig}

    fig, ax = subplots(figsize=(6, 4))
    medians = errors[..., 1:].double().median(1).values  # (K, T - 1)
    for seed, curve in zip(seeds, medians):
        ax.plot(t[1:], curve, lw=0.9, alpha=0.6, label=f"seed {seed}")
    ax.plot(t[1:], medians.mean(0), "k--", lw=1.5, label="mean of the members")
    ax.set_yscale("log")
    ax.set_xlabel(time_label)
    ax.set_ylabel(REL_ERR)
    ax.set_title(f"{title}\nmedian over test trajectories, per member", fontsize=9)
    ax.legend(fontsize=7)
    figures["ensemble_relative_error"] = laid_out(fig)
    return figures


def plain_log_ticks(axis, values=None) -> None:
    """Readable ticks on a log ``axis``: at ``values`` if given, else at 1, 2 and 5 per decade (1 only
    over more than three decades; evenly spaced within one), as plain numbers (0.05, 200), no minor labels."""
    from matplotlib import ticker

    if values is not None:
        axis.set_major_locator(ticker.FixedLocator(sorted(values)))
    else:
        axis.axes.autoscale_view()
        low, high = axis.get_view_interval()
        span = high / max(low, 1e-300)
        axis.set_major_locator(
            ticker.LogLocator(base=10, subs=(1.0,) if span > 1e3 else (1.0, 2.0, 5.0))
            if span > 10
            else ticker.MaxNLocator(nbins=6)
        )
    axis.set_major_formatter(ticker.FuncFormatter(lambda v, _: f"{v:g}"))
    axis.set_minor_formatter(ticker.NullFormatter())


def laid_out(fig: Figure) -> Figure:
    """``fig`` after ``tight_layout``: a figure handed to a writer is laid out where it is drawn."""
    fig.tight_layout()
    return fig


def save_png(fig, path: Path, layout: bool = True) -> Path:
    """``fig`` as a PNG at ``path`` (atomically, ``encons.infra.io.save_figure``), laid out tight unless ``layout`` is
    false."""
    if layout:
        fig.tight_layout()
    return save_figure(fig, path, dpi=110)


def log_figures(logger, paths: list[Path]) -> None:
    """Send saved PNGs to a logger that takes images (wandb); others keep them on disk only."""
    if logger is not None and hasattr(logger, "log_image"):
        for path in paths:
            logger.log_image(key=f"figures/{path.stem}", images=[str(path)])


def integration_figure(
    t: Tensor, pred: Tensor, true: Tensor, energy_pred: Tensor, energy_true: Tensor, chart: str, title: str
) -> dict[str, Figure]:
    """Santos et al. §7's unforced integration, its trajectory 0: configuration (every q, truth and
    model) and true energy against time (``integration``). States (N, T, 2n), energies (N, T)."""
    n = true.shape[-1] // 2
    fig, (ax_q, ax_e) = subplots(1, 2, figsize=(10, 3.8))
    for d in range(n):
        (line,) = ax_q.plot(t, true[0, :, d], lw=1.4, label=f"q{d + 1} truth")
        ax_q.plot(t, pred[0, :, d], "--", color=line.get_color(), lw=1.1, label=f"q{d + 1} model")
    ax_q.set_xlabel("time (s)")
    ax_q.set_ylabel(f"configuration ({chart} chart; rad or m)")
    ax_q.set_title("unforced integration, trajectory 0", fontsize=9)
    ax_q.legend(fontsize=7)
    ax_e.plot(t, energy_true[0], lw=1.4, label="truth")
    ax_e.plot(t, energy_pred[0], "--", lw=1.1, label="model")
    ax_e.set_xlabel("time (s)")
    ax_e.set_ylabel("true energy E (J)")
    ax_e.set_title("energy along the integration, trajectory 0", fontsize=9)
    ax_e.legend(fontsize=7)
    fig.suptitle(title)
    return {"integration": laid_out(fig)}


CEILING = 1e200  # top of a log MSE axis: matplotlib's log ticks overflow (OverflowError) near float64's 1.8e308


def mse_figure(
    t: Tensor,
    curves: dict[str, dict[str, Tensor]],
    title: str,
    units: tuple[str, ...] | None = None,
    time_label: str = TIME,
) -> dict[str, Figure]:
    """State MSE and (if known) energy MSE against time of the model and the baselines on the test
    windows (Xiao et al. Figs. 3 and 5; curves from ``metrics.long_rollout_errors``), from the first step
    (at t = 0 every rollout starts on the truth): ``mse_vs_time``. The axis spans the curves within
    1e6 of the model's range; a curve wholly below it (the constant predictor's energy error, ~1e-14:
    no motion keeps the energy of s₀) is named in the legend with its largest value instead. Values past
    ``CEILING`` (a runaway rollout, the linear baseline's blow-up) are drawn at it."""
    keys = list(curves["model"])
    mixed = ", ".join(
        f"({u})²" if "/" in u else f"{u}²"
        for u in dict.fromkeys([*(units or ("–",)), *(f"{u}/s" for u in (units or ("–",)))])
    )
    labels = {
        "state_mse": STATE_MSE,
        "state_mse_raw": f"state MSE, raw mean over every q and q̇ [mixed: {mixed}]",
        "energy_mse": "energy MSE [J²]",
    }
    for key in keys:  # one unit family each (metrics.unit_families)
        if key.startswith("state_mse_") and key != "state_mse_raw":
            unit = key.removeprefix("state_mse_").replace("_per_", "/").replace("_", " ")
            labels[key] = f"MSE of the {'rates' if '/' in unit else 'coordinates'} in {unit} [{unit}]²"
    if "state_mse_raw" in keys and sum(k.startswith("state_mse_") for k in keys) > 1:
        keys.remove("state_mse_raw")  # the unit families say it in their own units
    fig, axes = subplots(1, len(keys), figsize=(5 * len(keys), 4), squeeze=False)
    for ax, key in zip(axes[0], keys):
        model = curves["model"][key][1:]
        finite = model[torch.isfinite(model) & (model > 0)]
        floor = float(finite.min()) * 1e-6 if finite.numel() else 1e-16
        for name, c in curves.items():
            values = c[key][1:]
            label = name.removeprefix("baseline_").replace("_", " ")
            if name != "model" and float(values.max()) < floor:
                label += f" (below the axis: ≤ {float(values.max()):.1g})"
            ax.plot(
                t[1:],
                values.double().clamp(floor / 10, CEILING),
                label=label,
                lw=1.8 if name == "model" else 1.1,
                ls="-" if name == "model" else "--",
            )
        ax.set_yscale("log")
        every = torch.cat([c[key][1:].double() for c in curves.values()])
        every = every[torch.isfinite(every) & (every >= floor)].clamp_max(CEILING)
        if every.numel():
            ax.set_ylim(float(every.min()) / 2, float(every.max()) * 2)
        ax.set_xlabel(time_label)
        ax.set_ylabel(labels[key])
        ax.legend(title="mean over test windows", fontsize=8)
    fig.suptitle(f"{title}\nlong-rollout error against time, model vs trivial baselines", fontsize=9)
    return {"mse_vs_time": laid_out(fig)}


PIXEL_MSE = "pixel MSE [intensity², intensity in 0–1]"


DATA_TIME = "time t [the data's time unit]"


def pixel_mse_figure(t: Tensor, mse: Tensor, title: str, references: dict[str, Tensor]) -> dict[str, Figure]:
    """Pixel MSE (N, T) of decoded predictions against the true frames over time, median and 2.5–97.5 %
    band over test videos, with the mean and the means of ``references`` (name: (N, ≤ T), from t[0] on)
    (``pixel_mse``)."""
    fig, ax = subplots(figsize=(6.5, 4))
    _band(ax, t, mse.clamp_min(1e-12), PIXEL_MSE)
    ax.plot(t, mse.mean(0), "k--", lw=1, label="mean over test videos")
    for (name, ref), style in zip(references.items(), (":", "-.")):
        ax.plot(t[: ref.shape[1]], ref.mean(0), color="grey", ls=style, lw=1.2, label=f"{name} (mean)")
    ax.set_xlabel(DATA_TIME)
    ax.legend(fontsize=8)
    ax.set_title(f"{title}\npredicted frames from the first encoded state", fontsize=9)
    return {"pixel_mse": laid_out(fig)}


def latent_phase_figure(pred: Tensor, encoded: Tensor, title: str, n_show: int = 5) -> dict[str, Figure]:
    """Lim & Kasim Fig. 4: latent rollouts (N, T, d) of a few test videos in their phase plane — for
    d = 2 the latent (z₁, z₂) itself, else its first two principal components over the encoded test
    states — with the encoder's states of the true frames (``latent_phase``)."""
    d = pred.shape[-1]
    if d == 2:
        project, names = (lambda z: z), ("latent z₁ (position-like) [–]", "latent z₂ (velocity-like) [–]")
    else:
        flat = encoded.reshape(-1, d).double()
        mean = flat.mean(0)
        axes_ = torch.linalg.svd(flat - mean, full_matrices=False).Vh[:2].T
        project = lambda z: (z.double() - mean) @ axes_  # noqa: E731
        names = (f"1st principal component of the {d}-d latent [–]", "2nd principal component [–]")
    shown = min(n_show, pred.shape[0])
    fig, ax = subplots(figsize=(5.5, 5))
    for k in range(shown):
        p, e = project(pred[k]), project(encoded[k])
        (line,) = ax.plot(p[:, 0], p[:, 1], lw=1.2, label="model rollout (one colour per video)" if k == 0 else None)
        ax.plot(
            e[:, 0],
            e[:, 1],
            ".",
            ms=2.5,
            color=line.get_color(),
            label="encoded true frames (same colour)" if k == 0 else None,
        )
        ax.plot(p[:1, 0], p[:1, 1], "o", color=line.get_color(), ms=5)
    ax.set_xlabel(names[0])
    ax.set_ylabel(names[1])
    ax.legend(fontsize=8, title=f"{shown} test videos (○ start)", title_fontsize=8)
    ax.set_title(f"{title}\nlatent phase portrait (Lim & Kasim Fig. 4)", fontsize=9)
    return {"latent_phase": laid_out(fig)}


def frames_figure(t: Tensor, pred: Tensor, true: Tensor, title: str, n_times: int = 6) -> dict[str, Figure]:
    """Lim & Kasim Figs. 5–6: true (top) and predicted (bottom) frames of the first test video at
    ``n_times`` times from 0 to the end (``frames``)."""
    picks = torch.linspace(0, len(t) - 1, n_times).round().long().tolist()
    fig, axes = subplots(2, n_times, figsize=(1.6 * n_times, 3.8), squeeze=False)
    for col, k in enumerate(picks):
        for row, (frames, name) in enumerate(((true, "true"), (pred, "predicted"))):
            ax = axes[row, col]
            ax.imshow(frames[0, k].clamp(0, 1), cmap="gray", vmin=0, vmax=1)
            ax.set_xticks([])
            ax.set_yticks([])
            if col == 0:
                ax.set_ylabel(name)
            if row == 1:
                ax.set_xlabel(f"t = {t[k]:.0f}")
    fig.suptitle(f"{title}\ntest video 0: true vs predicted frames (grey level = pixel intensity, 0–1)", fontsize=9)
    return {"frames": laid_out(fig)}


def control_figures(
    t: Tensor,
    learned: tuple[Tensor, Tensor],
    oracle: tuple[Tensor, Tensor],
    t_up: tuple[Tensor, Tensor],
    energy,
    error,
    system,
    out_dir: Path,
    title: str,
    n_show: int = 6,
) -> list[Path]:
    """Closed loops of the controller built from a learned model beside the same controller built from the
    true model (``encons.tools.control``), on the true system: phase portrait of the (pole) angle, true energy
    and input against time for ``n_show`` starts, and the fraction of starts held upright against time.

    ``energy`` and ``error`` are the true plant's E(s) and s − s* (angles wrapped)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    angle = system.n - 1  # the (pole) angle: last coordinate
    unit = "N·m" if system.n == 1 else "N"
    shown = min(n_show, t_up[0].shape[0])
    colours = matplotlib.colormaps["tab10"](range(shown))
    labels = ("controller from the learned model", "same controller from the true model (oracle)")
    paths = []

    fig, axes = subplots(1, 2, figsize=(11, 4.5), sharex=True, sharey=True)
    for ax, (states, _), label in zip(axes, (learned, oracle), labels):
        x = error(states[:shown])
        theta = x[..., angle].clone()
        theta[:, 1:][(theta[:, 1:] - theta[:, :-1]).abs() > torch.pi] = torch.nan  # no line across ±π
        for k in range(shown):
            ax.plot(theta[k], x[k, :, system.n + angle], color=colours[k], lw=1, label=f"start {k}")
            ax.plot(x[k, 0, angle], x[k, 0, system.n + angle], "o", color=colours[k], ms=4)
        ax.plot(0, 0, "k*", ms=10, label="upright")
        ax.set_title(label, fontsize=9)
        ax.set_xlabel("angle from upright θ [rad]")
    axes[0].set_ylabel("angular velocity θ̇ [rad/s]")
    axes[1].legend(fontsize=7, loc="upper right", title="● start", title_fontsize=7)
    fig.suptitle(f"{title}\nphase portrait on the true system")
    paths.append(save_png(fig, out_dir / "control_phase.png"))

    fig, axes = subplots(2, 1, figsize=(8, 6.5), sharex=True)
    target = energy(torch.zeros(1, 2 * system.n, dtype=torch.float64))[0]
    for (states, inputs), style, label in zip((learned, oracle), ("-", "--"), labels):
        e = energy(states[:shown])
        for k in range(shown):
            axes[0].plot(t, e[k], style, color=colours[k], lw=1, label=label if k == 0 else None)
            axes[1].step(
                t[:-1], inputs[k, :, 0], style, where="post", color=colours[k], lw=1, label=label if k == 0 else None
            )
    axes[0].axhline(target, color="k", lw=0.8, ls=":", label="upright energy (true)")
    for bound in (system.u_max, -system.u_max):
        axes[1].axhline(bound, color="k", lw=0.8, ls=":", label="input limit ±u_max" if bound > 0 else None)
    axes[0].set_ylabel("true energy E [J]")
    axes[1].set_ylabel(f"input u [{unit}]")
    axes[1].set_xlabel(TIME)
    axes[0].legend(fontsize=7)
    axes[1].legend(fontsize=7)
    fig.suptitle(f"{title}\nenergy and input, {shown} starts (one colour each)")
    paths.append(save_png(fig, out_dir / "control_energy_input.png"))

    fig, ax = subplots(figsize=(6, 4))
    for times, label in zip(t_up, labels):
        ax.plot(t, (times[:, None] <= t[None, :]).double().mean(0), label=label)
    ax.set_xlabel(TIME)
    ax.set_ylabel("fraction of starts upright from t on [–]")
    ax.set_ylim(-0.02, 1.02)
    ax.legend(fontsize=7)
    ax.set_title(f"{title}\nheld upright (tolerance kept to the end)", fontsize=9)
    paths.append(save_png(fig, out_dir / "control_success.png"))
    return paths


def phase_portrait_figure(fields: tuple, system, out_dir: Path, title: str, points: int = 41) -> list[Path]:
    """The free flow (u = 0) of the learned and of the true continuous field in the (pole) angle's phase
    plane — (θ, θ̇) over [−π, π] × [−2π, 2π], the cart at rest at the origin — as streamlines coloured by
    |θ̈|, side by side on one grid (``fields``: (learned, true) maps of states (N, 2n) to ds/dt)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    angle = system.n - 1
    theta = torch.linspace(-torch.pi, torch.pi, points, dtype=torch.float64)
    rate = torch.linspace(-2 * torch.pi, 2 * torch.pi, points, dtype=torch.float64)
    grid_rate, grid_theta = torch.meshgrid(rate, theta, indexing="ij")
    s = torch.zeros(points * points, 2 * system.n, dtype=torch.float64)
    s[:, angle], s[:, system.n + angle] = grid_theta.flatten(), grid_rate.flatten()
    accel = [field(s)[:, system.n + angle].detach().reshape(points, points) for field in fields]
    top = max(float(a.abs().max()) for a in accel)
    fig, axes = subplots(1, 2, figsize=(11, 4.5), sharex=True, sharey=True)
    for ax, a, label in zip(axes, accel, ("learned model", "true system")):
        lines = ax.streamplot(
            theta.numpy(),
            rate.numpy(),
            grid_rate.numpy(),
            a.numpy(),
            density=1.1,
            color=a.abs().numpy(),
            cmap="viridis",
            norm=matplotlib.colors.Normalize(0, top),
            linewidth=0.8,
        )
        ax.plot(0, 0, "k*", ms=10, label="upright")
        ax.set_title(label, fontsize=9)
        ax.set_xlabel("angle from upright θ [rad]")
    axes[0].set_ylabel("angular velocity θ̇ [rad/s]")
    fig.subplots_adjust(top=0.83, wspace=0.08)
    fig.colorbar(lines.lines, ax=axes, label="|θ̈| [rad/s²]")
    fig.suptitle(f"{title}\nfree flow (u = 0){', cart at rest at x = 0' if system.n > 1 else ''}: learned vs true")
    return [save_png(fig, out_dir / "control_portrait.png", layout=False)]
