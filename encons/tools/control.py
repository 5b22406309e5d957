"""Controllers built from a trained run's model, scored on the true simulator.

    python -m encons.control RUN_DIR|CKPT [ckpt=best|last|PATH] [starts=100] [seed=0] [duration=SECONDS]

Zhong et al. conclude that the learned structure "can be leveraged to design energy-based controllers"
(paper 000, §5) and Santos et al. motivate SyMo by prediction and control (paper 002, abstract). This module
builds, for the controlled systems of Santos et al. §7 (``pendulum_control``, ``cartpole``), a
swing-up controller from what a model learned — M(q), V(q) (so the energy E = ½ q̇ᵀ M q̇ + V, eq. (1))
and the continuous forced Euler–Lagrange field ṡ = f(s, u) of eq. (4) — and the same controller from
the true system (the oracle row), and scores both on the true simulator from one seeded set of starts.

- ``pendulum_control``: energy pumping (Åström & Furuta, "Swinging up a pendulum by energy control",
  Automatica 36 (2000)): the torque u = u_max sat(k_E (E* − E)) sgn(q̇) drives dE/dt = q̇ u towards
  E* = V(0), the learned energy of rest upright; LQR near upright.
- ``cartpole``: energy shaping fits the learned structure through the pole's energy with the cart at
  rest, E_p = E(q, (0, θ̇)): with the cart's acceleration a as the input, dE_p/dt = −M_xθ(q) θ̇ a, so
  a = k_E (E_p − E*) M_xθ θ̇ − k_x x − k_v ẋ (Åström & Furuta's pivot-acceleration law, cos θ
  replaced by the learned M_xθ; the cart terms keep it near the origin), turned into the force u by
  collocated partial feedback linearisation of the learned control-affine field (ẍ = a₀(s) + b₀(s) u,
  two field evaluations); LQR near upright. Model-predictive shooting is not needed: every model that
  takes inputs and has an energy (L-NODE, SyMo, E2E-SyMo) gives M, V and f.

LQR (both systems): f linearised at the upright equilibrium s* = 0, u = 0 by ``torch.func.jacrev``
(A = ∂f/∂s, B = ∂f/∂u), discretised for the zero-order hold at the control period h (the run's data
step, the step the discrete models take) by the matrix exponential, solved by
``scipy.linalg.solve_discrete_are``: u = −K x, x = s − s* with angles wrapped to (−π, π]. The
controller switches to it where the LQR's cost-to-go xᵀ P x is below ``switch`` and back to pumping
outside (memoryless). SyMo and E2E-SyMo learn M(q) and V(q) inside their discrete Lagrangian
(eqs. (12)–(13)); the controller uses the continuous Euler–Lagrange equations of that same M and V
(``forced_euler_lagrange``), whose midpoint discretisation the DEL is. A learned field need not vanish
exactly at s* (a learned ∇V(0) ≠ 0): the LQR then holds a small offset, which the tolerance absorbs.

Scoring: ``starts`` initial states uniform in the controller settings' ``start_range`` (the default training
distribution of Santos et al. §7, also when the data were drawn elsewhere: ``system.init_center``) with
``seed``; the true system integrated in float64 by torchdiffeq RK4 with ``substeps`` steps per control
period, u held, every start at once. A start succeeds when, from a time t_up ≤ duration − hold on,
the state stays within ``tolerance`` of upright (|θ| ≤ 0.1 rad, |θ̇| ≤ 0.5 rad/s, and |x| ≤ 1 m for
the cart) until the end; t_up is the time to upright. Effort is ∫ u² dt over the horizon. The
learned model's prediction error is the RMS one-step error ‖ŝ_{k+1} − s_{k+1}‖ (angles wrapped) of
the model's own step (its training integrator, or its Newton step) from the closed-loop states and
inputs of its own controller; ``a_rel_err`` and ``b_rel_err`` are ‖A − A_true‖_F / ‖A_true‖_F and
the same for B, of the linearisation at upright the LQR is built from. Limits: |u| ≤ u_max is
enforced by saturation; gains are fixed per system, tuned on the true model, not per learned model.

What a controller is built from is declared, not listed here: a controlled system class declares its
``controller`` (``encons.systems.controlled.ControllerSettings``: gains, weights, tolerance, horizon, starts,
pumping law) and ``input_unit``; a model declares its ``energy_structure()`` (``encons.models.base``: the
learned M(q), V(q) and input matrix; None for a model without them). A new system or model of either kind is
scored here without editing this module.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import cast

import numpy as np
import scipy.linalg
import torch
from torch import Tensor
from torch.func import jacrev
from torchdiffeq import odeint

from encons.infra.errors import ConfigError
from encons.infra.io import write_json
from encons.models.base import DynamicsModel
from encons.systems.base import System, split_state
from encons.systems.controlled import ControlledMechanical, ControllerSettings

#: Examples of the models whose ``energy_structure()`` gives M(q), V(q) and that take inputs (the refusal names them)
CONTROL_MODELS = "lnode, symo, e2e_symo, hnn_structure, lnn_structure"


#: The metrics of ``score_control`` (``test/``-prefixed in a benchmark row) a benchmark summary's headline shows
HEADLINE = (
    "control/success_rate",
    "oracle/success_rate",
    "control/time_to_upright_s",
    "oracle/time_to_upright_s",
    "control/effort",
    "oracle/effort",
    "control/pred_rmse",
    "control/b_rel_err",
)


def controller_settings(system: System) -> ControllerSettings:
    """The controller settings ``system``'s class declares (``ControlledMechanical.controller``); refuses a
    system without any, in one line."""
    declared = getattr(system, "controller", None)
    if not isinstance(system, ControlledMechanical) or declared is None:
        raise ConfigError(
            f"system={system.name} has no controller here (no control inputs, or its class declares no "
            f"controller settings, ControlledMechanical.controller); allowed: a run on a system that declares "
            f"them, e.g. pendulum_control or cartpole"
        )
    return declared


def printed_rows(metrics: dict[str, float], system) -> list[tuple[str, list[str]]]:
    """The rows of ``encons.tools.control``'s table: each metric with its unit, ``success_rate`` in percent of the
    starts (``control_metrics.json`` keeps the fraction), ``effort`` in the input's unit squared times s."""
    u = system.input_unit
    units = {
        "success_rate": "% of starts",
        "time_to_upright_s": "s",
        "effort": f"∫ u² dt, ({u})² s",
        "max_abs_u": u,
        "pred_rmse": "q and q̇ units, mixed",
        "a_rel_err": "–",
        "b_rel_err": "–",
    }
    rows = []
    for key, unit in units.items():
        scale = 100.0 if key == "success_rate" else 1.0
        cells = [metrics.get(f"{side}/{key}") for side in ("control", "oracle")]
        rows.append((f"{key} [{unit}]", ["" if v is None else f"{v * scale:.4g}" for v in cells]))
    return rows


@dataclass
class Plant:
    """What a controller needs, float64: M(q), V(q), the input matrix B (n, m), the continuous field
    f(s, u) (batched), and which coordinates are angles."""

    mass: Callable[[Tensor], Tensor]
    potential: Callable[[Tensor], Tensor]
    input_matrix: Tensor
    field: Callable[[Tensor, Tensor], Tensor]
    angles: tuple[bool, ...]

    def energy(self, s: Tensor) -> Tensor:
        """E = ½ q̇ᵀ M(q) q̇ + V(q) (Santos et al. eq. (1) with T + V)."""
        q, qd = split_state(s)
        return 0.5 * (qd.unsqueeze(-2) @ self.mass(q) @ qd.unsqueeze(-1))[..., 0, 0] + self.potential(q)

    def error(self, s: Tensor) -> Tensor:
        """s − s* with the angles wrapped to (−π, π] (s* = 0: upright, cart at the origin)."""
        wrap = torch.tensor([*self.angles, *[False] * len(self.angles)], device=s.device)
        return torch.where(wrap, torch.remainder(s + math.pi, 2 * math.pi) - math.pi, s)


def true_plant(system: ControlledMechanical) -> Plant:
    """The oracle's plant: the system's closed-form M, V, B and field."""
    return Plant(
        system.mass_matrix,
        system.potential,
        system.input_matrix(),
        lambda s, u: system.vector_field(s, "angle", u),
        tuple(system.angles),
    )


def learned_plant(model: DynamicsModel, system: System, name: str) -> Plant:
    """The plant of a trained model: its learned M(q), V(q), input matrix (the system's B, or its learned
    g(q) at upright) and the forced Euler–Lagrange field of them (eq. (4); L-NODE's own field; for
    HNN-/LNN-structure the same dynamics as their (q, p) or (q, q̇) field with the force g(q) u);
    refuses a model or system that cannot give them, in one line."""
    from encons.models.lnode import forced_euler_lagrange

    controller_settings(system)
    angles = tuple(cast(ControlledMechanical, system).angles)  # controller_settings refused any other system
    if model.energy_structure() is None or not model.supports_controls:
        missing = "energy (learned M(q) and V(q))" if model.energy_structure() is None else "energy"
        missing += "" if model.supports_controls else " and takes no inputs"
        raise ConfigError(
            f"model._target_={name} gives no {missing}, which the energy-based controller "
            f"needs; allowed: a run of {CONTROL_MODELS} or another model whose energy_structure() gives "
            f"M(q), V(q) and that takes inputs (supports_controls)"
        )
    model = copy.deepcopy(model).double().eval().requires_grad_(False)
    structure = model.energy_structure()
    assert structure is not None  # checked above, on the same (deep-copied) model's class
    mass, potential, b = structure.mass, structure.potential, structure.input_matrix
    if not callable(b):
        return Plant(
            mass,
            potential,
            cast(Tensor, b),  # not callable, and the model takes inputs (supports_controls): its constant B
            lambda s, u: forced_euler_lagrange(mass, potential, b, s, u),
            angles,
        )
    learned_g = b  # callable: a learned g(q) (the closure below keeps the narrowed type)
    # a learned g(q): (M, V, g) and (M, V, g)/c move alike, so the energy's scale is free; c = ⟨g(0), B⟩/⟨B, B⟩
    # puts it in the system's units where the physics gives B (the energy pumping's gain assumes them)
    upright, known = learned_g(torch.zeros(len(angles), dtype=torch.float64)), system.input_matrix()
    c = float((upright * known).sum() / known.square().sum())
    scaled_mass, scaled_potential = (lambda q: mass(q) / c), (lambda q: potential(q) / c)

    def g(q: Tensor) -> Tensor:
        return learned_g(q) / c

    return Plant(
        scaled_mass,
        scaled_potential,
        upright / c,
        lambda s, u: forced_euler_lagrange(scaled_mass, scaled_potential, g, s, u),
        angles,
    )


def linearise(plant: Plant, m: int) -> tuple[Tensor, Tensor]:
    """A = ∂f/∂s and B = ∂f/∂u at s* = 0, u = 0 by ``torch.func.jacrev``."""
    s0 = torch.zeros(2 * len(plant.angles), dtype=torch.float64)
    u0 = torch.zeros(m, dtype=torch.float64)
    return jacrev(lambda s, u: plant.field(s[None], u[None])[0], argnums=(0, 1))(s0, u0)


def lqr(a: Tensor, b: Tensor, q: Tensor, r: Tensor, h: float) -> tuple[Tensor, Tensor]:
    """Gain K and Riccati solution P of the discrete LQR of ẋ = A x + B u under a zero-order hold of period
    ``h``: (A_d, B_d) from expm([[A, B], [0, 0]] h), P from ``scipy.linalg.solve_discrete_are``,
    K = (R + B_dᵀ P B_d)⁻¹ B_dᵀ P A_d."""
    n, m = b.shape
    block = np.zeros((n + m, n + m))
    block[:n, :n], block[:n, n:] = a.numpy(), b.numpy()
    phi = scipy.linalg.expm(block * h)
    ad, bd = phi[:n, :n], phi[:n, n:]
    p = scipy.linalg.solve_discrete_are(ad, bd, q.numpy(), r.numpy())
    k = np.linalg.solve(r.numpy() + bd.T @ p @ bd, bd.T @ p @ ad)
    return torch.from_numpy(k), torch.from_numpy(p)


class SwingUp:
    """Energy pumping far from upright, the plant's LQR near it; ``__call__`` maps states (N, 2n) to
    inputs (N, m) with |u| ≤ u_max."""

    def __init__(self, plant: Plant, system: ControlledMechanical, h: float):
        self.plant, self.u_max, self.settings = plant, system.u_max, controller_settings(system)
        a, b = linearise(plant, system.n_controls)
        self.linear = a, b  # at upright
        weights = torch.diag(torch.tensor(self.settings.q_weights, dtype=torch.float64))
        self.gain, self.cost = lqr(
            a, b, weights, torch.eye(system.n_controls, dtype=torch.float64) * self.settings.r_weight, h
        )
        self.is_cart = self.settings.pumping == "cart"  # the law the system's controller declares
        self.target = plant.energy(torch.zeros(1, 2 * system.n, dtype=torch.float64))  # learned E at rest upright

    def pump(self, s: Tensor) -> Tensor:
        """The energy-pumping input (N, m), saturated."""
        k = self.settings.gain_energy
        if not self.is_cart:
            qd = s[..., 1:]
            sign = torch.where(qd >= 0, 1.0, -1.0).to(s)  # sgn with sgn(0) = 1: a start at rest still moves
            return self.u_max * torch.clamp(k * (self.target - self.plant.energy(s))[..., None], -1, 1) * sign
        x, theta, xd, thetad = s.unbind(-1)
        q = s[..., :2]
        pole = self.plant.energy(torch.stack([x, theta, torch.zeros_like(xd), thetad], -1))  # the cart at rest
        zero = torch.zeros_like(x)
        upright = self.plant.energy(torch.stack([x, zero, zero, zero], -1))  # at rest upright, here
        coupling = self.plant.mass(q)[..., 0, 1]
        kx, kv = self.settings.cart_gains
        accel = k * (pole - upright) * coupling * thetad - kx * x - kv * xd
        free = self.plant.field(s, torch.zeros_like(s[..., :1]))[..., 2]
        per_unit = self.plant.field(s, torch.ones_like(s[..., :1]))[..., 2] - free  # ẍ = a₀ + b₀ u: b₀
        return torch.clamp((accel - free) / per_unit, -self.u_max, self.u_max)[..., None]

    def near(self, x: Tensor) -> Tensor:
        """Where the LQR takes over: xᵀ P x ≤ ``switch`` (N,)."""
        return (x.unsqueeze(-2) @ self.cost @ x.unsqueeze(-1))[..., 0, 0] <= self.settings.switch

    def __call__(self, s: Tensor) -> Tensor:
        with torch.no_grad():
            x = self.plant.error(s)
            u_lqr = torch.clamp(-x @ self.gain.T, -self.u_max, self.u_max)
            return torch.where(self.near(x)[..., None], u_lqr, self.pump(s))


def closed_loop(
    system: ControlledMechanical,
    controller: Callable[[Tensor], Tensor],
    starts: Tensor,
    h: float,
    steps: int,
    substeps: int = 10,
) -> tuple[Tensor, Tensor]:
    """States (N, steps + 1, 2n) and held inputs (N, steps, m) of the true system under ``controller``
    sampled every ``h``; each period integrated by torchdiffeq RK4 with ``substeps`` steps, float64."""
    states, inputs = [starts.to(torch.float64)], []
    span = torch.tensor([0.0, h], dtype=torch.float64)
    for _ in range(steps):
        u = controller(states[-1])
        inputs.append(u)
        nxt = odeint(
            lambda t, s: system.vector_field(s, "angle", u),
            states[-1],
            span,
            method="rk4",
            options={"step_size": h / substeps},
        )[-1]
        states.append(nxt)
    return torch.stack(states, 1), torch.stack(inputs, 1)


def score(
    plant: Plant, states: Tensor, inputs: Tensor, settings: ControllerSettings, h: float
) -> tuple[dict[str, float], Tensor]:
    """Success rate, mean time to upright (successful starts; nan if none), mean effort ∫ u² dt and the
    largest |u| of one closed-loop set (the settings' tolerance and hold), and each start's time to
    upright (N,) (inf where it failed)."""
    tol = torch.tensor(settings.tolerance, dtype=torch.float64)
    inside = (plant.error(states).abs() <= tol).all(-1)  # (N, K + 1)
    stays = inside.flip(-1).cumprod(-1).flip(-1).bool()  # inside from here to the end
    first = torch.where(stays.any(-1), stays.int().argmax(-1), stays.shape[-1])  # first index that stays
    t_up = first.double() * h
    success = t_up <= (states.shape[1] - 1) * h - settings.hold + 1e-9
    effort = (inputs.square().sum(-1) * h).sum(-1)
    metrics = {
        "success_rate": success.double().mean().item(),
        "time_to_upright_s": t_up[success].mean().item() if success.any() else math.nan,
        "effort": effort.mean().item(),
        "max_abs_u": inputs.abs().max().item(),
    }
    return metrics, torch.where(success, t_up, math.inf)


def prediction_error(run, plant: Plant, states: Tensor, inputs: Tensor, h: float) -> float:
    """RMS one-step error of the run's model along a closed loop (its own step: the training integrator
    or the discrete model's Newton step), every start and step in one batch."""
    from encons.numerics.integrators import rollout

    model = copy.deepcopy(run.model).double().eval().requires_grad_(False)
    m = inputs.shape[-1]
    if model.discrete:  # from (s_{k−1}, s_k) under (u_{k−1}, u_k) to s_{k+1}
        start = torch.stack([states[:, :-2], states[:, 1:-1]], -2).reshape(-1, 2, states.shape[-1])
        u = torch.stack([inputs[:, :-1], inputs[:, 1:], inputs[:, 1:]], -2).reshape(-1, 3, m)
        pred, true = rollout(model, start, torch.tensor([0.0, h, 2 * h]), u=u)[:, 2], states[:, 2:]
    else:
        start = states[:, :-1].reshape(-1, states.shape[-1])
        u = inputs.reshape(-1, 1, m).expand(-1, 2, m)
        with torch.enable_grad():
            pred = rollout(model, start, torch.tensor([0.0, h]), run.module.integrator, u)[:, 1]
        true = states[:, 1:]
    err = plant.error(pred.detach().reshape(true.shape) - true)
    return err.square().sum(-1).mean().sqrt().item()


@dataclass
class Outcome:
    """The closed loops (states, inputs) of the learned-model controller and of the oracle on the same
    starts, each start's time to upright (inf: failed), and the metrics."""

    t: Tensor
    learned: tuple[Tensor, Tensor]
    oracle: tuple[Tensor, Tensor]
    t_up: tuple[Tensor, Tensor]
    metrics: dict[str, float]


def compare(run, starts: int = 100, seed: int = 0, duration: float | None = None) -> Outcome:
    """The controller built from ``run``'s model and the one built from the true system (the oracle),
    both scored on the true system from the same ``starts`` seeded initial states over ``duration``
    seconds (default: the ``duration`` of the controller settings the system's class declares)."""
    if starts < 1:
        raise ConfigError(f"starts={starts}; allowed: >= 1")
    system, h = run.module.system, float(run.module.dt)
    plant = learned_plant(run.model, system, run.config.model._target_)
    declared = controller_settings(system)
    duration = declared.duration if duration is None else duration
    if not duration >= declared.hold + h:
        raise ConfigError(f"duration={duration}; allowed: >= {declared.hold + h} (the hold time plus one step)")
    steps = round(duration / h)
    init = declared.starts(starts, seed)
    oracle_plant = true_plant(system)
    controllers = SwingUp(plant, system, h), SwingUp(oracle_plant, system, h)
    learned = closed_loop(system, controllers[0], init, h, steps)
    oracle = closed_loop(system, controllers[1], init, h, steps)
    learned_metrics, learned_up = score(oracle_plant, *learned, declared, h)
    oracle_metrics, oracle_up = score(oracle_plant, *oracle, declared, h)
    metrics = {f"control/{k}": v for k, v in learned_metrics.items()}
    metrics["control/pred_rmse"] = prediction_error(run, oracle_plant, *learned, h)
    for name, part, truth in zip(("a_rel_err", "b_rel_err"), controllers[0].linear, controllers[1].linear):
        metrics[f"control/{name}"] = (torch.linalg.norm(part - truth) / torch.linalg.norm(truth)).item()
    metrics.update({f"oracle/{k}": v for k, v in oracle_metrics.items()})
    return Outcome(torch.arange(steps + 1) * h, learned, oracle, (learned_up, oracle_up), metrics)


def settings_record(declared: ControllerSettings) -> dict:
    """``declared`` as plain JSON values (an unbounded tolerance as null)."""
    return {**asdict(declared), "tolerance": [None if math.isinf(v) else v for v in declared.tolerance]}


def score_control(
    run, starts: int = 100, seed: int = 0, duration: float | None = None, ckpt: str = "best"
) -> dict[str, float]:
    """Score the controller built from a trained run (a ``Run``, a run folder or a ``.ckpt``) beside the
    true-model oracle on the true system; returns ``control/...`` and ``oracle/...`` metrics and writes
    them (``control_metrics.json``) and the figures to ``<run>/control``."""
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from encons.evaluators import figures
    from encons.training.runs import Run, load

    if not isinstance(run, Run):
        run = load(run, ckpt=ckpt)
    outcome = compare(run, starts, seed, duration)
    out = run.run_dir / "control"
    system = run.module.system
    write_json(
        out / "control_metrics.json",
        {
            **outcome.metrics,
            "starts": starts,
            "seed": seed,
            "duration_s": float(outcome.t[-1]),
            "control_period_s": float(run.module.dt),
            "settings": settings_record(controller_settings(system)),
        },
    )
    oracle = true_plant(system)
    figures.control_figures(
        outcome.t,
        outcome.learned,
        outcome.oracle,
        outcome.t_up,
        oracle.energy,
        oracle.error,
        system,
        out,
        f"{system.name}: controller from {run.config.name}",
    )
    learned = learned_plant(run.model, system, run.config.model._target_)
    free = torch.zeros(1, system.n_controls, dtype=torch.float64)
    figures.phase_portrait_figure(
        (lambda s: learned.field(s, free.expand(len(s), -1)), lambda s: oracle.field(s, free.expand(len(s), -1))),
        system,
        out,
        f"{system.name}: {run.config.name}",
    )
    table = Table(
        title=f"control: {run.config.name}, {starts} starts (seed {seed}), {float(outcome.t[-1]):g} s, "
        f"control period {run.module.dt} s"
    )
    for column in ("metric", "from the learned model", "from the true model (oracle)"):
        table.add_column(column, justify="left" if column == "metric" else "right", no_wrap=column == "metric")
    for label, cells in printed_rows(outcome.metrics, system):
        table.add_row(escape(label), *cells)  # "[N m]" is a unit, not rich markup
    console = Console()
    console.print(table)
    console.print(
        f"outputs: {out}  (control_metrics.json, control_*.png: closed loops, success, learned vs true portrait)"
    )
    return outcome.metrics
