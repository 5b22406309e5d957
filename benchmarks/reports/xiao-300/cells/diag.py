"""The diagnostics of ../cells.md ("Why GLNN's compound rollout is worse than the baseline's"): the compound
pendulum's GLNN (200 × 4) and baseline (second order, 200 × 3) runs of ``best_vs_last.py``, each at its best and its
last (epoch 300) checkpoint.

    cd benchmarks/reports/xiao-300/cells      # OMP_NUM_THREADS=1, the repository's python (encons importable)
    nice -n 5 python diag.py OUT              # OUT: best_vs_last.py's folder (its runs/ trained); writes diag.json

Every run is loaded as ``encons.load(OUT/runs/<id>, ckpt=best|last)`` (the model in float64, as its evaluation
computes: ``module.evaluation.precise``), on its own data (training states; held-out states = the test
trajectories' first ``data.n_steps`` + 1 states, t < 10 s, as ``encons.evaluators.Acceleration`` scores them; late
states = the rest, 10 ≤ t ≤ 20 s). q̈ errors are ``encons.numerics.metrics.acceleration_mse`` of
``encons.numerics.integrators.state_derivative`` against the system's true field. Measured:

- accel_mse on training, held-out and late states, and along the model's own rollout for t < 10 s (the model's field
  at its rollout's states against the true field at the same states; the rollout is the run's evaluation,
  ``module.evaluation.rollout``: dopri5 at rtol 1e-10, float64, from the test trajectories' first states);
- the squared q̈ error and ‖q̈‖² by time window (t < 0.5 s, 0.5–2 s, ≥ 2 s) on held-out and training trajectories,
  and the held-out error's range over 0.1 ≤ t ≤ 0.2 s (the mean over trajectories at each time);
- the share of held-out states where the model's field gains energy: dE/dt = ∇E · f̂ > 0 for the system's true
  energy E (forward-mode autodiff, ``torch.func.jvp``), with the true field's share beside it;
- GLNN only, on held-out states: its terms of eq. (11), ∇_q L, H = ∇_q̇∇_q̇ᵀ L and (∇_q∇_q̇ᵀ L) q̇ (the model's own
  ``lagrangian_derivatives``, checked against ``encons.models.lnn.lagrangian_derivatives``, torch.func of L), and F:
  the RMS of F and of H⁻¹F (the q̈ that F adds, by the model's ``guarded_solve``) beside the true friction's M⁻¹Q,
  the eigenvalues of H beside those of the true M(q), and accel_mse with F removed (H⁻¹[∇_q L − (∇_q∇_q̇ᵀ L) q̇]);
  RMS = the root mean square over states and both coordinates;
- on both systems, what predicting q̈ = 0 scores on the held-out states (E‖q̈‖²) and h² times it;
- along the rollout: E(ŝ) − E(s) at t = 1, 5, 10 s (mean, min, max over the 10 test trajectories), how many have
  E(ŝ) > E(s) at 5 s, and the state MSE against time (``encons.numerics.metrics.mse_curves``: ``state_mse_raw``,
  the plain mean over trajectories and coordinates, angles on the circle, as the evaluation scores it) after one
  step, over 0.1–0.2 s, at 1 s and 10 s, with the least-squares slope of its logarithm over 0.1 ≤ t ≤ 1 s (/s).
"""

from __future__ import annotations

import json
import os
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import torch
from torch.func import jvp

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from best_vs_last import git_commit  # noqa: E402 - beside this script

RUNS = {"glnn": "compound_pendulum-glnn-h200-d4-seed0", "baseline": "compound_pendulum-second_order-h200-d3-seed0"}
ZERO = {  # the data of each system's held-out states: any run of it (the same data for every cell)
    "damped_oscillator": "damped_oscillator-second_order-h200-d3-seed0",
    "compound_pendulum": RUNS["baseline"],
}
CKPTS = ("best", "last")
MARKS_S = (1.0, 5.0, 10.0)


def qdd_sq_error(pred: torch.Tensor, true: torch.Tensor) -> torch.Tensor:
    """‖q̈̂ − q̈‖² at every state (the per-point term of ``acceleration_mse``)."""
    from encons.numerics import metrics

    return metrics.acceleration_mse(pred, true, reduce=lambda e: e)


def window_means(per_state: torch.Tensor, t: torch.Tensor) -> dict[str, float]:
    """Means of a (N, T) quantity over t < 0.5 s, 0.5 ≤ t < 2 s and t ≥ 2 s."""
    eps = 1e-9
    masks = {"t<0.5s": t < 0.5 - eps, "0.5<=t<2s": (t >= 0.5 - eps) & (t < 2 - eps), "t>=2s": t >= 2 - eps}
    return {k: per_state[:, m].mean().item() for k, m in masks.items()}


def rms(x: torch.Tensor) -> float:
    return x.pow(2).mean().sqrt().item()


def diagnose(run_dir: Path, ckpt: str) -> dict:
    import encons
    from encons.infra import checkpoints
    from encons.models.glnn import GLNN
    from encons.models.lnn import guarded_solve, lagrangian_derivatives
    from encons.numerics import metrics
    from encons.numerics.integrators import state_derivative

    started = time.perf_counter()
    run = encons.load(run_dir, ckpt=ckpt)
    module, data = run.module, run.data
    system, chart = module.system, module.model.chart
    model = module.evaluation.precise(module.model)
    ckpt_file = checkpoints.find(run_dir, ckpt)
    span = data.n_steps + 1
    test = data.arrays["test"]["states"].double()
    train = data.arrays["train"]["states"].double()
    t_test = module.times(test.shape[1], test)
    t_train = module.times(train.shape[1], train)
    held, late = test[:, :span], test[:, span:]

    def field(s: torch.Tensor) -> torch.Tensor:
        with torch.no_grad():
            return state_derivative(model, s).detach()

    def truth(s: torch.Tensor) -> torch.Tensor:
        return system.field(s, chart)

    out: dict = {"checkpoint": str(ckpt_file.relative_to(run_dir.parent.parent)), "epoch": 0}
    out["epoch"] = int(checkpoints.read(ckpt_file)["epoch"]) + 1
    f_held, f_true_held = field(held), truth(held)
    err_held = qdd_sq_error(f_held, f_true_held)
    err_train = qdd_sq_error(field(train), truth(train))
    out["accel_mse"] = {
        "training": err_train.mean().item(),
        "held_out": err_held.mean().item(),
        "late": metrics.acceleration_mse(field(late), truth(late)).item(),
    }
    t_held = t_test[:span]
    early = (t_held >= 0.1 - 1e-9) & (t_held <= 0.2 + 1e-9)
    per_time = err_held.mean(0)
    out["by_window"] = {
        "held_out_sq_err": window_means(err_held, t_held),
        "training_sq_err": window_means(err_train, t_train),
        "held_out_qdd_sq": window_means((f_true_held[..., 2:] ** 2).sum(-1), t_held),
        "training_qdd_sq": window_means((truth(train)[..., 2:] ** 2).sum(-1), t_train),
        "held_out_sq_err_0.1-0.2s": [per_time[early].min().item(), per_time[early].max().item()],
        "held_out_early_share": (err_held[:, t_held < 0.5 - 1e-9].sum() / err_held.sum()).item(),
    }

    def energy(s: torch.Tensor) -> torch.Tensor:
        return system.energy(s, chart)

    gain = jvp(energy, (held,), (f_held,))[1]
    gain_true = jvp(energy, (held,), (f_true_held,))[1]
    out["energy_gain_share"] = {
        "model": (gain > 0).double().mean().item(),
        "truth": (gain_true > 0).double().mean().item(),
    }

    if isinstance(model, GLNN):
        with torch.no_grad():
            dl_dq, hessian, mixed = model.lagrangian_derivatives(held)
            force = model.force(held)
            added = guarded_solve(hessian, force, model.guard)
            without = guarded_solve(hessian, dl_dq - mixed, model.guard)
        auto = lagrangian_derivatives(model.lagrangian, held[:, ::10])  # torch.func, every 10th held-out state
        closed = (dl_dq[:, ::10], hessian[:, ::10], mixed[:, ::10])
        check = max(((a - c).abs().max() / a.abs().max()).item() for a, c in zip(auto, closed))
        qd = held[..., 2:]
        friction = torch.linalg.solve(system.mass_matrix(held[..., :2]), system.force(held).unsqueeze(-1)).squeeze(-1)
        eig, eig_true = torch.linalg.eigvalsh(hessian), torch.linalg.eigvalsh(system.mass_matrix(held[..., :2]))
        rebuilt = torch.cat([qd, guarded_solve(hessian, dl_dq - mixed + force, model.guard)], -1)
        out["glnn"] = {
            "derivatives_vs_torch_func_max_rel_err": check,
            "field_rebuilt_max_abs_err": (rebuilt - f_held).abs().max().item(),
            "rms_F": rms(force),
            "rms_Hinv_F": rms(added),
            "rms_true_Minv_Q": rms(friction),
            "eig_H_min_max": [eig.min().item(), eig.max().item()],
            "eig_true_M_min_max": [eig_true.min().item(), eig_true.max().item()],
            "accel_mse_without_F": metrics.acceleration_mse(torch.cat([qd, without], -1), f_true_held).item(),
        }

    ten = test[:, : span + 1]  # t = 0 .. 10 s
    t_ten = t_test[: span + 1]
    with torch.no_grad():
        pred = module.evaluation.rollout(module.model, ten[:, 0], t_ten)  # the run's evaluation, float64
    out["accel_mse"]["own_rollout"] = metrics.acceleration_mse(field(pred[:, :span]), truth(pred[:, :span])).item()
    e_pred, e_true = energy(pred), energy(ten)
    marks = {f"{s:g}s": int(round(s / module.dt)) for s in MARKS_S}
    gap = e_pred - e_true
    out["energy_gap"] = {
        k: {
            "t": t_ten[i].item(),
            "mean": gap[:, i].mean().item(),
            "min": gap[:, i].min().item(),
            "max": gap[:, i].max().item(),
        }
        for k, i in marks.items()
    }
    out["energy_gap"]["above_at_5s"] = f"{int((gap[:, marks['5s']] > 0).sum())}/{len(gap)}"
    curves = metrics.mse_curves(module.to_common(pred), module.to_common(ten), e_pred, e_true, module.compared_angles)
    raw = curves["state_mse_raw"]
    fit = (t_ten >= 0.1 - 1e-9) & (t_ten <= 1.0 + 1e-9)
    tt, ll = t_ten[fit], raw[fit].log()
    slope = (((tt - tt.mean()) * (ll - ll.mean())).sum() / ((tt - tt.mean()) ** 2).sum()).item()
    out["state_mse_raw"] = {
        "one_step": raw[1].item(),
        "0.1-0.2s": [raw[:span][early].min().item(), raw[:span][early].max().item()],
        "1s": raw[marks["1s"]].item(),
        "10s": raw[marks["10s"]].item(),
        "mean_t<=10s": raw.mean().item(),
        "log_slope_0.1-1s_per_s": slope,
    }
    out["energy_mse_t<=10s"] = curves["energy_mse"].mean().item()
    out["wall_s"] = round(time.perf_counter() - started, 1)
    return out


def zero_field(run_dir: Path) -> dict:
    """What predicting q̈ = 0 scores on the held-out states (accel_mse = E‖q̈‖²), and the one-step state error it
    would give, h²·E‖q̈‖² (../cells.md, 'What the paper's cell is')."""
    import encons
    from encons.numerics import metrics

    run = encons.load(run_dir, ckpt="last")
    module, data = run.module, run.data
    held = data.arrays["test"]["states"].double()[:, : data.n_steps + 1]
    true = module.system.field(held, module.model.chart)
    score = metrics.acceleration_mse(torch.zeros_like(true), true).item()
    return {
        "dt": module.dt,
        "held_out_states": list(held.shape[:2]),
        "accel_mse_of_zero": score,
        "h2_times_it": module.dt**2 * score,
    }


def main() -> None:
    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    out = Path(sys.argv[1]).resolve()
    started, load0 = datetime.now(timezone.utc), os.getloadavg()[0]
    torch.set_num_threads(1)
    results = {}
    for name, run_id in RUNS.items():
        for ckpt in CKPTS:
            print(f"{name} {ckpt} ...", flush=True)
            results[f"{name}_{ckpt}"] = diagnose(out / "runs" / run_id, ckpt)
            print(json.dumps(results[f"{name}_{ckpt}"]), flush=True)
    zero = {system: zero_field(out / "runs" / run_id) for system, run_id in ZERO.items()}
    print(json.dumps(zero), flush=True)
    record = {
        "what": "../cells.md, 'Why GLNN's compound rollout is worse than the baseline's': diagnostics of the compound "
        "pendulum's GLNN and baseline runs at their best and last checkpoints (diag.py)",
        "command": f"cd benchmarks/reports/xiao-300/cells && OMP_NUM_THREADS=1 nice -n 5 python diag.py {out.name}",
        "runs": {k: f"runs/{v}" for k, v in RUNS.items()},
        "code_commit": git_commit(),
        "date_utc": started.strftime("%Y-%m-%d %H:%M"),
        "load_1min": {"start": round(load0, 2), "end": round(os.getloadavg()[0], 2)},
        "zero_field": zero,
        "results": results,
    }
    (HERE / "diag.json").write_text(json.dumps(record, indent=1) + "\n")
    cols = [f"{n}_{c}" for n in RUNS for c in CKPTS]
    r = results

    def row(label: str, get) -> None:
        cells = []
        for c in cols:
            try:
                cells.append(get(r[c]))
            except KeyError:
                cells.append("–")
        print(f"| {label} | " + " | ".join(cells) + " |")

    print("| quantity | " + " | ".join(f"{c.replace('_', ' ')} (ep {r[c]['epoch']})" for c in cols) + " |")
    print("|---" * (len(cols) + 1) + "|")
    row("accel_mse, training states", lambda x: f"{x['accel_mse']['training']:.3g}")
    row("accel_mse, held-out / late", lambda x: f"{x['accel_mse']['held_out']:.3g} / {x['accel_mse']['late']:.2g}")
    row("accel_mse along own rollout", lambda x: f"{x['accel_mse']['own_rollout']:.3g}")
    row("held-out states gaining energy", lambda x: f"{100 * x['energy_gain_share']['model']:.0f} %")
    row("RMS of F", lambda x: f"{x['glnn']['rms_F']:.3g}")
    row("RMS of H⁻¹F (true M⁻¹Q)", lambda x: f"{x['glnn']['rms_Hinv_F']:.3g} ({x['glnn']['rms_true_Minv_Q']:.2g})")
    row(
        "eig H (true M)",
        lambda x: (
            "{:.3g}–{:.3g}".format(*x["glnn"]["eig_H_min_max"])
            + " ({:.2g}–{:.2g})".format(*x["glnn"]["eig_true_M_min_max"])
        ),
    )
    row("accel_mse without F", lambda x: f"{x['glnn']['accel_mse_without_F']:.3g}")
    row(
        "E(ŝ) − E(s) at 1 / 5 / 10 s",
        lambda x: " / ".join(f"{x['energy_gap'][k]['mean']:.2g}" for k in ("1s", "5s", "10s")),
    )
    row("E(ŝ) > E(s) at 5 s", lambda x: x["energy_gap"]["above_at_5s"])
    print(f"wrote {HERE / 'diag.json'}")


if __name__ == "__main__":
    main()
