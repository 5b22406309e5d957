"""The papers' error and energy metrics: pure functions on (N, T, D) trajectories."""

from __future__ import annotations

import torch
from torch import Tensor


def relative_error(pred: Tensor, true: Tensor) -> Tensor:
    """‖ŝ_t − s_t‖₂ / ‖s_t‖₂ per step (Zhong et al. §4.1); shape (N, T)."""
    return (pred - true).norm(dim=-1) / true.norm(dim=-1)


def trajectory_relative_error(pred: Tensor, true: Tensor, horizon: int = 4) -> Tensor:
    """Σ_{t=0..horizon} of the relative error (Zhong et al. §4.1, T = 4); shape (N,)."""
    return relative_error(pred[..., : horizon + 1, :], true[..., : horizon + 1, :]).sum(-1)


def geometric_mean_relative_error(pred: Tensor, true: Tensor) -> Tensor:
    """Finzi et al. (2020): geometric mean over t ≥ 1 of ‖ŝ−s‖ / (‖ŝ‖ + ‖s‖); shape (N,).

    t = 0 is left out: a rollout starts on the truth, where the error is exactly zero.
    """
    err = (pred - true).norm(dim=-1) / (pred.norm(dim=-1) + true.norm(dim=-1))
    return err[..., 1:].clamp_min(1e-30).log().mean(-1).exp()


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
    return torch.quantile(values.double(), torch.tensor(qs, dtype=torch.float64)).tolist()


def summarise(pred: Tensor, true: Tensor, pred_energy: Tensor | None, true_energy: Tensor | None,
              horizon: int = 4) -> dict[str, float]:
    """Scalar test metrics of rollouts ``pred`` against ``true`` in one common chart."""
    tre = trajectory_relative_error(pred, true, horizon)
    out = {
        "traj_rel_err": tre.mean().item(),
        "traj_rel_err_std": tre.std().item() if tre.numel() > 1 else 0.0,
        "rel_err_final": relative_error(pred, true)[..., -1].mean().item(),
        "geom_rel_err": geometric_mean_relative_error(pred, true).mean().item(),
    }
    if pred_energy is not None and true_energy is not None:
        out["energy_abs_err"] = energy_abs_error(pred_energy, true_energy).mean().item()
        lo, med, hi = percentiles(energy_deviation_rmse(pred_energy, true_energy))
        out.update(energy_rmse_median=med, energy_rmse_p2_5=lo, energy_rmse_p97_5=hi)
    return out


# Santos, Ekal & Ventura §7: mean squared errors in configuration space, energy and inertia.
def configuration_mse(pred_q: Tensor, true_q: Tensor) -> Tensor:
    """MSE over every step and coordinate of configurations (N, T, n) (Santos et al. §7); a scalar."""
    return ((pred_q - true_q) ** 2).mean()


def energy_mse(pred_energy: Tensor, true_energy: Tensor) -> Tensor:
    """Per-trajectory MSE over time of the true energy of ŝ_t against E(s_t), averaged over trajectories."""
    return ((pred_energy - true_energy) ** 2).mean(-1).mean()


def mass_matrix_mse(pred_mass: Tensor, true_mass: Tensor) -> Tensor:
    """MSE over entries of learned against true M(q), (..., n, n) (Santos et al. §7 "inertial loss")."""
    return ((pred_mass - true_mass) ** 2).mean()
