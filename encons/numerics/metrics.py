"""The papers' error and energy metrics: pure functions on (N, T, D) trajectories.

Angles. Every function of states takes ``angles``, a boolean mask (D,) of the entries that are angles
(``System.angle_entries``; None: none), and compares those on the circle, as Zhong et al. §3.3 say an
angle lives ("q and q ± 2π represent the same angle … each angular coordinate lies on S¹"): the error
of an angle is the wrapped difference ``wrap(q̂ − q)`` in [−π, π) (the geodesic distance on S¹), and
the scale ‖s‖ of a relative error takes each angle as ``wrap(q)``, its distance from the angle's zero
on the circle. Neither moves when q̂ and q (or either) shift by 2πk, so a score measures the model, not
where an unwrapping began; on states whose angles lie in [−π, π) both equal the plain definitions.
Zhong et al. and Finzi et al. (2020) score pendulums and the gyroscope in Cartesian coordinates (the
common chart of those systems here), where a 2πk shift cannot appear; the wrapped scale is the
angle-chart counterpart for systems known only in angles (recordings, Xiao's and Santos's systems).
"""

from __future__ import annotations

import math
from typing import Callable

import torch
from torch import Tensor


def wrapped(values: Tensor, angles: Tensor | None) -> Tensor:
    """``values`` (..., D) with the entries marked in ``angles`` (D,) wrapped into [−π, π)."""
    if angles is None:
        return values
    angles = angles.to(values.device)
    return torch.where(angles, torch.remainder(values + math.pi, 2 * math.pi) - math.pi, values)


def difference(pred: Tensor, true: Tensor, angles: Tensor | None = None) -> Tensor:
    """ŝ − s with angle entries wrapped into [−π, π): the error on the circle."""
    return wrapped(pred - true, angles)


def magnitude(states: Tensor, angles: Tensor | None = None) -> Tensor:
    """‖s‖₂ with each angle taken as ``wrap(q)``: a scale that a 2πk shift leaves as it is; (...,)."""
    return wrapped(states, angles).norm(dim=-1)


def relative_error(pred: Tensor, true: Tensor, angles: Tensor | None = None) -> Tensor:
    """‖ŝ_t − s_t‖₂ / ‖s_t‖₂ per step (Zhong et al. §4.1), angles on the circle; shape (N, T)."""
    return difference(pred, true, angles).norm(dim=-1) / magnitude(true, angles)


def trajectory_relative_error(pred: Tensor, true: Tensor, horizon: int = 4, angles: Tensor | None = None) -> Tensor:
    """Σ_{t=0..horizon} of the relative error (Zhong et al. §4.1, T = 4); shape (N,)."""
    return relative_error(pred[..., : horizon + 1, :], true[..., : horizon + 1, :], angles).sum(-1)


def geometric_mean_relative_error(pred: Tensor, true: Tensor, angles: Tensor | None = None) -> Tensor:
    """Finzi et al. (2020): geometric mean over t ≥ 1 of ‖ŝ−s‖ / (‖ŝ‖ + ‖s‖), angles on the circle; shape (N,).

    t = 0 is left out: a rollout starts on the truth, where the error is exactly zero.
    """
    err = difference(pred, true, angles).norm(dim=-1) / (magnitude(pred, angles) + magnitude(true, angles))
    return err[..., 1:].clamp_min(1e-30).log().mean(-1).exp()


def valid_prediction_time(
    pred: Tensor, true: Tensor, dt: float, threshold: float, angles: Tensor | None = None
) -> Tensor:
    """Valid prediction time per trajectory (N,): the last time t_k = k·dt such that the relative error
    ‖ŝ_τ − s_τ‖₂ / ‖s_τ‖₂ stays ≤ ``threshold`` at every step τ ≤ k (Jin et al. 2020's VPT; Botev et al.
    2021 use the same definition on a normalised MSE). A rollout that never exceeds it scores its horizon
    t_{T−1}: the value is censored there, so compare VPTs only over one horizon. A non-finite error
    counts as exceeding.
    """
    within = (relative_error(pred, true, angles) <= threshold).long()  # NaN compares False
    return (within.cumprod(-1).sum(-1) - 1).clamp_min(0).double() * dt


def energy_abs_error(pred_energy: Tensor, true_energy: Tensor) -> Tensor:
    """|E(ŝ_t) − E(s_t)| in the true energy (Zhong et al. §4.1); shape (N, T)."""
    return (pred_energy - true_energy).abs()


def energy_deviation_rmse(pred_energy: Tensor, true_energy: Tensor) -> Tensor:
    """RMSE over time of E(ŝ_t) − E(s_t) per trajectory (Lim & Kasim, Table 1); shape (N,).

    Against the true energy at each time, so that it also holds for dissipative systems; for
    conservative ones E(s_t) = E(s_0).
    """
    return ((pred_energy - true_energy) ** 2).mean(-1).sqrt()


def percentiles(values: Tensor, qs: tuple[float, ...] = (0.025, 0.5, 0.975)) -> list[float]:
    """Quantiles of a 1-D tensor (the median with 2.5/97.5 percentiles by default)."""
    return torch.quantile(values.double(), torch.tensor(qs, dtype=torch.float64, device=values.device)).tolist()


DIVERGED_ENERGY_ERROR = 1e10  # |E(ŝ_t) − E(s_t)| at which a rollout counts as diverged (in the system's units)


def diverged(pred: Tensor, pred_energy: Tensor | None = None, true_energy: Tensor | None = None) -> Tensor:
    """Per rollout (N,): a non-finite state, or, given energies, an energy error that is non-finite or
    reaches ``DIVERGED_ENERGY_ERROR`` at any time — a rollout thrown that far from the physics has left
    every metric's meaningful range even while its states are still finite numbers."""
    out = ~pred.isfinite().all(-1).all(-1)
    if pred_energy is not None and true_energy is not None:
        error = (pred_energy - true_energy).abs()
        out |= ~(error < DIVERGED_ENERGY_ERROR).all(-1)  # NaN compares False: counted
    return out


def summarise(
    pred: Tensor,
    true: Tensor,
    pred_energy: Tensor | None,
    true_energy: Tensor | None,
    horizon: int = 4,
    dt: float = 1.0,
    vpt_threshold: float = 0.1,
    angles: Tensor | None = None,
) -> dict[str, float]:
    """Scalar test metrics of rollouts ``pred`` against ``true`` in one common chart, sampled every ``dt``,
    ``angles`` compared on the circle.

    ``diverged`` is the fraction of rollouts that diverged (``diverged``: a non-finite state, or an
    energy error ≥ ``DIVERGED_ENERGY_ERROR``); with a non-finite one the means over trajectories are NaN
    on purpose (the horizon-``horizon`` ``traj_rel_err`` may still be finite); ``traj_rel_err_window`` sums
    the relative error over the whole window, every step of ``pred``. ``vpt``
    is the mean ``valid_prediction_time`` at ``vpt_threshold``, ``vpt_censored`` the fraction of
    rollouts still valid at the last step (their VPT is the horizon).
    """
    tre = trajectory_relative_error(pred, true, horizon, angles)
    vpt = valid_prediction_time(pred, true, dt, vpt_threshold, angles)
    out = {
        "diverged": diverged(pred, pred_energy, true_energy).double().mean().item(),
        "traj_rel_err": tre.mean().item(),
        "traj_rel_err_std": tre.std().item() if tre.numel() > 1 else 0.0,
        "traj_rel_err_window": trajectory_relative_error(pred, true, pred.shape[-2] - 1, angles).mean().item(),
        "rel_err_final": relative_error(pred, true, angles)[..., -1].mean().item(),
        "geom_rel_err": geometric_mean_relative_error(pred, true, angles).mean().item(),
        "vpt": vpt.mean().item(),
        "vpt_censored": (vpt == (pred.shape[-2] - 1) * dt).double().mean().item(),
    }
    if pred_energy is not None and true_energy is not None:
        out["energy_abs_err"] = energy_abs_error(pred_energy, true_energy).mean().item()
        lo, med, hi = percentiles(energy_deviation_rmse(pred_energy, true_energy))
        out.update(energy_rmse_median=med, energy_rmse_p2_5=lo, energy_rmse_p97_5=hi)
    return out


# Santos, Ekal & Ventura §7: mean squared errors in configuration space, energy and inertia.
def configuration_mse(pred_q: Tensor, true_q: Tensor, angles: Tensor | None = None) -> Tensor:
    """MSE over every step and coordinate of configurations (N, T, n) (Santos et al. §7), angles (n,) on the
    circle; a scalar."""
    return (difference(pred_q, true_q, angles) ** 2).mean()


def energy_mse(pred_energy: Tensor, true_energy: Tensor) -> Tensor:
    """Per-trajectory MSE over time of the true energy of ŝ_t against E(s_t), averaged over trajectories."""
    return ((pred_energy - true_energy) ** 2).mean(-1).mean()


def mass_matrix_mse(pred_mass: Tensor, true_mass: Tensor) -> Tensor:
    """MSE over entries of learned against true M(q), (..., n, n) (Santos et al. §7 "inertial loss")."""
    return ((pred_mass - true_mass) ** 2).mean()


# Xiao, Zhang & Tang §3: the acceleration error of a field at given states, no rollout.
def acceleration_mse(
    pred_rates: Tensor, true_rates: Tensor, reduce: Callable[[Tensor], Tensor] = Tensor.mean
) -> Tensor:
    """Mean over points of ‖q̈̂ − q̈‖², the squared error summed over the n coordinates, from state derivatives
    (..., 2n) whose second half is q̈ (a (q, q̇) chart): Xiao et al.'s loss (1/|S|) Σ ‖q̈̃ − q̈‖² (§3); a scalar
    (``reduce``: the mean over points, e.g. per ensemble member)."""
    error = pred_rates - true_rates
    return reduce((error[..., error.shape[-1] // 2 :] ** 2).sum(-1))


# Long-rollout errors against time (Xiao, Zhang & Tang, Figs. 3 and 5) and two trivial baselines.
def unit_families(units: tuple[str, ...]) -> dict[str, Tensor]:
    """The state entries (q then q̇, bool (2n,)) of each unit family, by name (``rad``, ``rad_per_s``, ``m``,
    ...), from the units of the coordinates q (a rate's unit is that per second)."""
    per_entry = [*units, *(f"{u}/s" for u in units)]
    return {
        u.replace("/", "_per_").replace(" ", "_"): torch.tensor([e == u for e in per_entry])
        for u in dict.fromkeys(per_entry)
    }


def coordinate_spread(true: Tensor, angles: Tensor | None = None) -> Tensor:
    """Each coordinate's spread over the test set: the standard deviation (D,) of ``true`` (..., D) over every
    window and time, an angle's taken about its circular mean on the circle; a coordinate that never moves
    (spread 0) gets 1, so its error stays in its own unit rather than dividing by zero."""
    flat = true.reshape(-1, true.shape[-1])
    if angles is not None:
        centre = torch.atan2(flat.sin().mean(0), flat.cos().mean(0))
        flat = wrapped(flat - torch.where(angles.to(flat.device), centre, 0.0), angles)
    spread = flat.std(0, correction=0) if len(flat) > 1 else torch.zeros_like(flat[0])
    return torch.where(spread > 0, spread, torch.ones_like(spread))


def mse_curves(
    pred: Tensor,
    true: Tensor,
    pred_energy: Tensor | None = None,
    true_energy: Tensor | None = None,
    angles: Tensor | None = None,
    families: dict[str, Tensor] | None = None,
) -> dict[str, Tensor]:
    """State MSE against time (T,) each: ``state_mse``, the mean over trajectories and coordinates of the
    error of each coordinate divided by its spread over the test set (``coordinate_spread`` of ``true``;
    dimensionless, so rad² and (rad/s)² are never added); ``state_mse_raw``, the plain mean over every
    coordinate (Xiao et al.'s, whose units mix); per unit family ``state_mse_<family>`` (over the entries of
    each mask of ``families``, one unit each) and, given energies, energy MSE (over trajectories). Angles
    are compared on the circle."""
    squared = difference(pred, true, angles) ** 2
    spread = coordinate_spread(true, angles).to(squared)
    curves = {"state_mse": (squared / spread**2).mean((0, -1)), "state_mse_raw": squared.mean((0, -1))}
    for name, mask in (families or {}).items():
        curves[f"state_mse_{name}"] = squared[..., mask.to(squared.device)].mean((0, -1))
    if pred_energy is not None and true_energy is not None:
        curves["energy_mse"] = ((pred_energy - true_energy) ** 2).mean(0)
    return curves


def constant_rollout(start: Tensor, steps: int) -> Tensor:
    """The no-motion predictor ŝ_t = s_0 from states (..., D) for ``steps`` times: (..., steps, D)."""
    return start.unsqueeze(-2).expand(*start.shape[:-1], steps, start.shape[-1]).clone()


def fit_linear_ode(states: Tensor, dt: float) -> Tensor:
    """The least-squares linear ODE ṡ = A s + b through trajectories (N, T, D) sampled every ``dt`` (inputs
    of a controlled system are ignored: a trivial baseline).

    ṡ is estimated by central differences (second order; one-sided at both ends, so T >= 3), then
    (A, b) = argmin Σ ‖A s + b − ṡ‖² over every sample (minimum-norm where the samples do not fix
    it). Returns the generator G = [[A, b], [0, 0]] (D + 1, D + 1) of the augmented state (s, 1).
    """
    rates = torch.gradient(states, spacing=dt, dim=-2, edge_order=2)[0]
    features = torch.cat([states, torch.ones_like(states[..., :1])], -1).reshape(-1, states.shape[-1] + 1)
    # On the CPU: CUDA's lstsq has only `gels` (full rank), not the minimum-norm `gelsd`; the fit is (D+1)-wide.
    coeffs = torch.linalg.lstsq(features.cpu(), rates.reshape(-1, states.shape[-1]).cpu(), driver="gelsd").solution
    coeffs = coeffs.to(states.device)
    return torch.cat([coeffs.T, torch.zeros_like(coeffs[:, :1].T)], 0)


def linear_ode_rollout(generator: Tensor, start: Tensor, t: Tensor) -> Tensor:
    """The exact flow of ṡ = A s + b (``generator`` from ``fit_linear_ode``) from states (..., D) over
    times ``t`` (T,) from t[0]: s(t) = first D entries of expm(G (t − t₀)) (s₀, 1); (..., T, D)."""
    flows = torch.linalg.matrix_exp((t - t[0])[:, None, None] * generator)
    augmented = torch.cat([start, torch.ones_like(start[..., :1])], -1)
    return torch.einsum("tij,...j->...ti", flows, augmented)[..., :-1]


def baseline_rollouts(true: Tensor, train: Tensor, dt: float) -> dict[str, Tensor]:
    """The two trivial baselines rolled out over the test windows ``true`` (N, T, 2n) from their first states,
    by name: ``baseline_constant`` (ŝ_t = s_0) and ``baseline_linear_ode`` (the linear ODE least-squares
    fitted to the training states ``train``, ``fit_linear_ode``)."""
    t = torch.arange(true.shape[-2], dtype=true.dtype, device=true.device) * dt
    return {
        "baseline_constant": constant_rollout(true[..., 0, :], len(t)),
        "baseline_linear_ode": linear_ode_rollout(fit_linear_ode(train, dt), true[..., 0, :], t),
    }


def long_rollout_errors(
    true: Tensor,
    pred: Tensor,
    baselines: dict[str, Tensor],
    to_common: Callable[[Tensor], Tensor] = lambda s: s,
    energy: Callable[[Tensor], Tensor] | None = None,
    angles: Tensor | None = None,
    families: dict[str, Tensor] | None = None,
) -> tuple[dict[str, float], dict[str, dict[str, Tensor]]]:
    """State and energy MSE against time (Xiao et al. Figs. 3 and 5) of the model's rollouts ``pred`` and
    of the ``baselines`` (``baseline_rollouts``) on the same test windows ``true`` (N, T, 2n).

    States are compared after ``to_common`` (the common chart, whose ``angles`` are compared on the circle); energies
    (``energy``, None when the physics is unknown) in the data chart; ``families`` (``unit_families``) add one state MSE
    per unit. Returns scalars — ``state_mse`` (normalised per coordinate, ``mse_curves``; over all times) and
    ``state_mse_final`` (last step), the same for ``energy_mse``, the model's also for ``state_mse_raw`` and each
    family; a baseline's under ``<baseline name>/`` — and the curves {predictor: {"state_mse", ...: (T,)}}.
    """
    predictions = {"model": pred, **baselines}
    true_c = to_common(true)
    true_e = None if energy is None else energy(true)
    scalars, curves = {}, {}
    for name, p in predictions.items():
        p_c, prefix = to_common(p), "" if name == "model" else f"{name}/"
        curves[name] = mse_curves(p_c, true_c, None if energy is None else energy(p), true_e, angles, families)
        for key, curve in curves[name].items():
            if name != "model" and key.startswith("state_mse_"):
                continue  # per-family scalars of the model only; every curve is kept
            scalars.update({f"{prefix}{key}": curve.mean().item(), f"{prefix}{key}_final": curve[-1].item()})
    return scalars, curves


def curves_table(t: Tensor, curves: dict[str, dict[str, Tensor]], marks: int = 4) -> str:
    """The curves of ``long_rollout_errors`` at ``marks`` evenly spaced times, as a text table."""
    at = sorted({round(i * (len(t) - 1) / marks) for i in range(1, marks + 1)})
    lines = [f"{'MSE vs time t =':<36}" + "".join(f"{t[i].item():>11.4g}" for i in at)]
    for name, c in curves.items():
        lines += [f"{key + ' ' + name:<36}" + "".join(f"{v[i].item():>11.3e}" for i in at) for key, v in c.items()]
    return "\n".join(lines)
