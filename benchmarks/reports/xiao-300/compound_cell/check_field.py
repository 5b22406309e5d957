"""Section 1 of ../compound_cell.md: encons' compound pendulum is Xiao et al.'s eq. (12), and the size of q̈.

    cd benchmarks/reports/xiao-300/compound_cell
    OMP_NUM_THREADS=1 python check_field.py          # prints the table, writes check_field.json beside itself

The system is the one ``python -m encons.benchmark profile=xiao`` builds for the compound pendulum
(conf/profile/xiao.yaml, conf/system/compound_pendulum.yaml: m = d = 1, I = 1/12, g = 10, γ₁ = γ₂ = 0.5), with
its data (``profile_data.py``). In torch float64, on 10,000 states uniform in [−3, 3]⁴ (torch generator seed 0),
``CompoundPendulum.vector_field``'s q̈ is checked against

(a) sympy's solution for (θ̈₁, θ̈₂) of eq. (12) as printed in Xiao, Zhang & Tang (2024) §4.3;
(b) an independent Euler–Lagrange derivation (sympy) from the bodies' positions: each body a mass m at
    distance d from its axle (body 1's at the axle Q, which sits at d from P; body 2's at d below Q) plus a
    moment of inertia I about its axle, i.e. T = ½m|ẋ₁|² + ½m|ẋ₂|² + ½I(θ̇₁² + θ̇₂²), U = mg(y₁ + y₂), the axle
    frictions as the generalised forces −∂R/∂θ̇ of R = ½γ₁θ̇₁² + ½γ₂(θ̇₁ − θ̇₂)²;
(c) the energy balance dE/dt = −γ₁θ̇₁² − γ₂(θ̇₁ − θ̇₂)², dE/dt = ∇E·f by forward-mode autodiff of
    ``CompoundPendulum.energy`` along the field;

each as the maximum absolute error over the states. Then E‖q̈‖² (what predicting q̈ = 0 scores, ‖·‖² summed
over the two coordinates, mean over points) on: the paper's layout (20 trajectories × 500 points from
[−1, 1]⁴, h = 0.02), 20 draws (generator seeds 0–19), their mean (min–max); encons' 10 training
trajectories and 10 test trajectories (their first 500 states) of the profile's data, and the 20 together;
and 2000 trajectories (generator seed 20) by time window. Trajectories are simulated as encons simulates its
data (``encons.data.simulate.sample_trajectories``: RK4, 10 substeps per step).
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable
from pathlib import Path

import sympy as sp
import torch
from torch.func import jvp

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from profile_data import profile_data  # noqa: E402 - beside this script

N_STATES, BOX, SEED = 10_000, 3.0, 0
DRAWS, PAPER_TRAJ, POINTS = 20, 20, 500
MANY, WINDOWS = 2000, ((0.0, 0.5), (0.5, 1.0), (1.0, 2.0), (2.0, 5.0), (5.0, 10.0))

th1, th2, w1, w2, a1, a2 = sp.symbols("theta1 theta2 omega1 omega2 alpha1 alpha2", real=True)
m, d, inertia, g, gamma1, gamma2 = sp.symbols("m d I g gamma1 gamma2", positive=True)


def eq12() -> tuple[sp.Expr, sp.Expr]:
    """(θ̈₁, θ̈₂) solved from eq. (12) as printed (left side = right side)."""
    s, c = sp.sin(th1 - th2), sp.cos(th1 - th2)
    first = sp.Eq(
        -gamma1 * w1 - gamma2 * (w1 - w2),
        2 * m * d**2 * a1 + inertia * a1 + m * d**2 * a2 * c + m * d**2 * w2**2 * s + 2 * m * g * d * sp.sin(th1),
    )
    second = sp.Eq(
        gamma2 * (w1 - w2),
        m * d**2 * a2 + inertia * a2 + m * d**2 * a1 * c - m * d**2 * w1**2 * s + m * g * d * sp.sin(th2),
    )
    solution = sp.solve([first, second], [a1, a2], dict=True)[0]
    return solution[a1], solution[a2]


def euler_lagrange() -> tuple[sp.Expr, sp.Expr]:
    """(θ̈₁, θ̈₂) from the bodies' positions: d/dt ∂L/∂θ̇ − ∂L/∂θ = −∂R/∂θ̇ (see the module docstring)."""
    t = sp.symbols("t", real=True)
    q1, q2 = sp.Function("q1")(t), sp.Function("q2")(t)
    x1, y1 = d * sp.sin(q1), -d * sp.cos(q1)  # body 1's mass, at the axle Q
    x2, y2 = x1 + d * sp.sin(q2), y1 - d * sp.cos(q2)  # body 2's mass, at d below Q
    v1 = sp.diff(x1, t) ** 2 + sp.diff(y1, t) ** 2
    v2 = sp.diff(x2, t) ** 2 + sp.diff(y2, t) ** 2
    dq1, dq2 = sp.diff(q1, t), sp.diff(q2, t)
    kinetic = m * v1 / 2 + m * v2 / 2 + inertia * (dq1**2 + dq2**2) / 2
    lagrangian = kinetic - m * g * (y1 + y2)
    rayleigh = gamma1 * dq1**2 / 2 + gamma2 * (dq1 - dq2) ** 2 / 2
    plain = {sp.diff(q1, t, 2): a1, sp.diff(q2, t, 2): a2, dq1: w1, dq2: w2, q1: th1, q2: th2}
    equations = []
    for q, dq in ((q1, dq1), (q2, dq2)):
        lhs = sp.diff(sp.diff(lagrangian, dq), t) - sp.diff(lagrangian, q)
        equations.append(sp.Eq(lhs.subs(plain), (-sp.diff(rayleigh, dq)).subs(plain)))
    solution = sp.solve(equations, [a1, a2], dict=True)[0]
    return sp.simplify(solution[a1]), sp.simplify(solution[a2])


def numeric(exprs: tuple[sp.Expr, sp.Expr], system) -> Callable[[torch.Tensor], torch.Tensor]:
    """The expressions with the system's parameters, as a torch function of states (..., 4) -> q̈ (..., 2)."""
    values = {m: system.m, d: system.d, inertia: system.inertia, g: system.g, gamma1: system.gamma1}
    values[gamma2] = system.gamma2
    fn = sp.lambdify(
        (th1, th2, w1, w2), [e.subs(values) for e in exprs], modules=[{"sin": torch.sin, "cos": torch.cos}]
    )

    def qdd(s: torch.Tensor) -> torch.Tensor:
        return torch.stack([torch.as_tensor(v, dtype=s.dtype).expand(s.shape[:-1]) for v in fn(*s.unbind(-1))], -1)

    return qdd


def qdd_sq(system, traj: torch.Tensor) -> torch.Tensor:
    """‖q̈‖² at every state of trajectories (N, T, 4): (N, T)."""
    return (system.vector_field(traj, "angle")[..., 2:] ** 2).sum(-1)


def simulated(system, n: int, seed: int, dt: float) -> torch.Tensor:
    from encons.data.simulate import sample_trajectories

    t = torch.arange(POINTS, dtype=torch.float64) * dt
    return sample_trajectories(system, n, t, torch.Generator().manual_seed(seed), substeps=10)[0]


def main() -> None:
    start = time.perf_counter()
    system, splits, dt = profile_data()
    states = BOX * (2 * torch.rand(N_STATES, 4, generator=torch.Generator().manual_seed(SEED), dtype=torch.float64) - 1)
    field = system.vector_field(states, "angle")
    encons_qdd = field[..., 2:]
    printed, derived = numeric(eq12(), system)(states), numeric(euler_lagrange(), system)(states)
    rate = jvp(lambda s: system.energy(s, "angle"), (states,), (field,))[1]
    w = states[..., 2:]
    balance = -system.gamma1 * w[..., 0] ** 2 - system.gamma2 * (w[..., 0] - w[..., 1]) ** 2
    checks = {
        "eq12_sympy_max_abs_err": (encons_qdd - printed).abs().max().item(),
        "euler_lagrange_max_abs_err": (encons_qdd - derived).abs().max().item(),
        "eq12_vs_euler_lagrange_max_abs_err": (printed - derived).abs().max().item(),
        "dEdt_max_abs_err": (rate - balance).abs().max().item(),
        "max_abs_qdd_encons": encons_qdd.abs().max().item(),
        "max_abs_qdd_euler_lagrange": derived.abs().max().item(),
        "max_abs_dEdt": balance.abs().max().item(),
    }

    draws = torch.stack([qdd_sq(system, simulated(system, PAPER_TRAJ, k, dt)).mean() for k in range(DRAWS)])
    train, test = splits["train"], splits["test"][:, :POINTS]
    many = qdd_sq(system, simulated(system, MANY, DRAWS, dt))
    times = torch.arange(POINTS, dtype=torch.float64) * dt
    by_window = {
        f"{lo:g}-{hi:g}s": many[:, (times >= lo - 1e-9) & (times < hi - 1e-9)].mean().item() for lo, hi in WINDOWS
    }
    scale = {
        "paper_layout_draws": draws.tolist(),
        "paper_layout_mean": draws.mean().item(),
        "paper_layout_min": draws.min().item(),
        "paper_layout_max": draws.max().item(),
        "encons_train_10": qdd_sq(system, train).mean().item(),
        "encons_test_10_first500": qdd_sq(system, test).mean().item(),
        "encons_train_and_test_20": qdd_sq(system, torch.cat([train, test])).mean().item(),
        "many_2000_by_window": by_window,
        "many_2000_all": many.mean().item(),
    }
    result = {
        "what": "../compound_cell.md section 1: CompoundPendulum.vector_field against eq. (12) and an "
        "Euler-Lagrange derivation, the energy balance, and E|qdd|^2 (check_field.py)",
        "states": N_STATES,
        "box": BOX,
        "seed": SEED,
        "dtype": "float64",
        "system": {k: getattr(system, k) for k in ("m", "d", "inertia", "g", "gamma1", "gamma2", "init_range")},
        "dt": dt,
        "data": {k: list(v.shape) for k, v in splits.items()},
        "field": checks,
        "qdd_sq": scale,
        "wall_s": round(time.perf_counter() - start, 1),
    }
    (HERE / "check_field.json").write_text(json.dumps(result, indent=2) + "\n")

    print("| check (10,000 states in [−3, 3]⁴, float64) | max abs error |")
    print("|---|---|")
    print(f"| q̈ vs sympy's solution of eq. (12) | {checks['eq12_sympy_max_abs_err']:.2g} |")
    print(f"| q̈ vs Euler–Lagrange from body positions | {checks['euler_lagrange_max_abs_err']:.2g} |")
    print(f"| dE/dt vs −γ₁θ̇₁² − γ₂(θ̇₁ − θ̇₂)² | {checks['dEdt_max_abs_err']:.2g} |")
    print(f"\nmax |q̈|: {checks['max_abs_qdd_encons']:.3g} (encons), {checks['max_abs_qdd_euler_lagrange']:.3g} (E–L)\n")
    print("| data | E‖q̈‖² |")
    print("|---|---|")
    print(
        f"| paper's layout ({PAPER_TRAJ} trajectories × {POINTS} points), {DRAWS} draws | "
        f"{scale['paper_layout_mean']:.3g} ({scale['paper_layout_min']:.3g}–{scale['paper_layout_max']:.3g}) |"
    )
    print(f"| encons' 10 training trajectories | {scale['encons_train_10']:.3g} |")
    print(f"| encons' 10 test trajectories, first {POINTS} states | {scale['encons_test_10_first500']:.3g} |")
    print(f"| encons' 20 trajectories together | {scale['encons_train_and_test_20']:.3g} |")
    windows = " / ".join(f"{lo:g}–{hi:g}" for lo, hi in WINDOWS)
    values = " / ".join(f"{v:.3g}" for v in by_window.values())
    print(f"| {MANY} trajectories, by time window: {windows} s | {values} |")
    print(f"\nwall {result['wall_s']} s; wrote {HERE / 'check_field.json'}")


if __name__ == "__main__":
    main()
