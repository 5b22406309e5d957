"""Speed of one training step per model, against the bare floor of its derivative order and
against a straightforward implementation of the same model (``make bench``).

A step is what ``TrainingModule`` does per batch: roll out 200 windows of 5 states with RK4
(4 steps, 16 field evaluations), L1 loss, backward, AdamW step, 3 × 256 Softplus networks
(DESIGN.md "Speed targets"). The floors are the same step with the simplest field of each
derivative order, through one 3 × 256 network V(q) and batched ``autograd.grad``
(``create_graph=True``): order 1 is q̈ = −∇V(q); order 2 is q̈ = −∇²V(q) q̇ (one
Hessian-vector product). The straightforward ("naive") implementations share the model's
parameters and compute the same field the way one writes it first: CHNN by the dense 2K × 2K
solve of eq. (20) with DΨ from one ``autograd.grad`` per constraint row and M⁻¹ assembled and
inverted per evaluation; CLNN by eq. (15) likewise; LNN and LNN-structure by a Python loop over
samples, each with its full Hessian (``torch.autograd.functional.hessian``), timed on the first
``--naive-samples`` windows and scaled to the batch (the loop is linear in it). Timed: the fastest of
a few steps, as wall time and as process CPU time, the floor and each model alternately over
``--repeats`` rounds, the fastest of each (the pair sees the same load); ratios use CPU time, which
other people's load on a shared machine disturbs least (run with ``--threads 1`` there). Peak memory: the high-water
mark of the tensors torch allocates during one step (profiler memory events, in order). Also times
dataset generation (1,000 trajectories × 100 steps; target ≤ 2 s for pendulum2) and, for the
``--compile`` models, the same step with the field through ``torch.compile`` (``compile=true``): its
compile time (the first step, from an empty inductor cache only on a fresh machine) and speed-up
(eager and compiled timed alternately, like the floor).
Writes CSV and Markdown (with the machine) to ``benchmarks/results/``.
Usage: ``python benchmarks/speed.py [--systems ...] [--models ...] [--threads 1] [--out CSV]``.
"""

from __future__ import annotations

import argparse
import copy
import csv
import os
import platform
import tempfile
import time
import warnings
from pathlib import Path
from typing import Callable

import torch
from torch import Tensor

from encons.config.check import validate
from encons.data.simulate import sample_trajectories, simulate
from encons.entry.api import catalogue, compose
from encons.infra import threads
from encons.infra.errors import ConfigError
from encons.models.base import DynamicsModel
from encons.models.constrained import CHNN, CLNN
from encons.models.lnn import LNN, LNNStructure, guarded_solve
from encons.models.networks import mlp
from encons.numerics.integrators import Integrator
from encons.systems.base import System, point_mass_matrix, split_state
from encons.training.build import build_model, build_system
from encons.training.module import TrainingModule

FIELDS = [
    "system",
    "model",
    "order",
    "wall_ms",
    "cpu_ms",
    "steps_per_s",
    "peak_mb",
    "ratio_floor",
    "naive_cpu_ms",
    "speedup_vs_naive",
    "compile_s",
    "speedup_compiled",
]


class BareFloor(DynamicsModel):
    """ṡ = (q̇, −∇V) (order 1) or (q̇, −∇²V q̇) (order 2) by batched ``autograd.grad``."""

    def __init__(self, system: System, chart: str, order: int, hidden: int, depth: int):
        super().__init__(system, chart)
        self.order = order
        self.net = mlp(self.n, 1, hidden, depth)

    def forward(self, t: Tensor, s: Tensor, u: Tensor | None = None) -> Tensor:
        q, qd = split_state(s)
        with torch.enable_grad():
            q = q if q.requires_grad else q.requires_grad_()
            (dv,) = torch.autograd.grad(self.net(q).sum(), q, create_graph=True)
            if self.order == 2:
                (dv,) = torch.autograd.grad((dv * qd).sum(), q, create_graph=True)
        return torch.cat([qd, -dv], -1)


def rows_jacobian(out: Tensor, x: Tensor) -> Tensor:
    """d out / d x (B, K, D) by one ``autograd.grad`` per output row (create_graph)."""
    return torch.stack(
        [torch.autograd.grad(out[..., k].sum(), x, create_graph=True)[0] for k in range(out.shape[-1])], -2
    )


class NaiveCartesian(DynamicsModel):
    """A model's Cartesian field the straightforward way (same parameters, no structure used)."""

    def __init__(self, model: CHNN | CLNN, system: System):
        super().__init__(system, model.chart)
        self.model, self.system = model, system
        self.hamiltonian = isinstance(model, CHNN)

    def to_internal(self, s: Tensor) -> Tensor:
        return self.model.to_internal(s)

    def from_internal(self, z: Tensor) -> Tensor:
        return self.model.from_internal(z)

    def forward(self, t: Tensor, z: Tensor, u: Tensor | None = None) -> Tensor:
        layout, phi = self.system.layout, self.model.constraints
        mass = torch.kron(
            point_mass_matrix(layout, [p.exp() for p in self.model.masses.log_params]),
            torch.eye(layout.dim, dtype=z.dtype),
        )
        minv = torch.linalg.inv(mass)
        with torch.enable_grad():
            z = z if z.requires_grad else z.requires_grad_()
            x, w = split_state(z)
            jac = rows_jacobian(phi(x), z)[..., : x.shape[-1]]  # DΦ (B, K, D)
            if not self.hamiltonian:  # eq. (15): ẍ = M⁻¹(Aᵀλ − ∇V), (A M⁻¹ Aᵀ) λ = A M⁻¹ ∇V − C v
                grad_v = torch.autograd.grad(self.model.potential(x).sum(), x, create_graph=True)[0]
                d_rate = rows_jacobian((jac @ w.unsqueeze(-1)).squeeze(-1), z)[..., : x.shape[-1]]
                rhs = (jac @ minv @ grad_v.unsqueeze(-1)).squeeze(-1) - (d_rate @ w.unsqueeze(-1)).squeeze(-1)
                lam = torch.linalg.solve(jac @ minv @ jac.transpose(-1, -2), rhs)
                acc = ((lam.unsqueeze(-2) @ jac).squeeze(-2) - grad_v) @ minv
                return torch.cat([w, acc], -1)
            # eq. (20), dense: ż = J∇H − J DΨᵀ (DΨ J DΨᵀ)⁻¹ DΨ J∇H, Ψ = (Φ, DΦ M⁻¹ p)
            energy = self.model.potential(x) + 0.5 * ((w @ minv) * w).sum(-1)
            j_grad = torch.autograd.grad(energy.sum(), z, create_graph=True)[0]
            d = x.shape[-1]
            j_grad = torch.cat([j_grad[..., d:], -j_grad[..., :d]], -1)
            psi = torch.cat([phi(x), (jac @ (w @ minv).unsqueeze(-1)).squeeze(-1)], -1)
            dpsi = rows_jacobian(psi, z)  # (B, 2K, 2D)
            j_dpsi_t = torch.cat([dpsi[..., d:], -dpsi[..., :d]], -1).transpose(-1, -2)  # J DΨᵀ
            lam = torch.linalg.solve(dpsi @ j_dpsi_t, (dpsi @ j_grad.unsqueeze(-1)))
            return j_grad - (j_dpsi_t @ lam).squeeze(-1)


class NaiveLagrangian(DynamicsModel):
    """Euler–Lagrange q̈ = (∇²_q̇ L)⁻¹ (∇_q L − ∇_q̇∇_qᵀ L q̇), a Python loop over samples, each
    with its full Hessian of L (same parameters as the model; LNN's guarded solve with its λ)."""

    def __init__(self, model: LNN | LNNStructure, system: System):
        super().__init__(system, model.chart)
        self.model = model

    def lagrangian(self, s: Tensor) -> Tensor:
        if isinstance(self.model, LNN):
            return self.model.lagrangian(s)
        q, qd = split_state(s)
        return 0.5 * qd @ self.model.mass(q) @ qd - self.model.potential(q)

    def forward(self, t: Tensor, s: Tensor, u: Tensor | None = None) -> Tensor:
        n, out = self.n, []
        for si in s.reshape(-1, 2 * n):
            with torch.enable_grad():
                si = si if si.requires_grad else si.requires_grad_()
                dl = torch.autograd.grad(self.lagrangian(si), si, create_graph=True)[0]
                hess = torch.autograd.functional.hessian(self.lagrangian, si, create_graph=True)
            h, r = hess[n:, n:], dl[:n] - hess[n:, :n] @ si[n:]
            out.append(
                guarded_solve(h, r, self.model.guard)
                if isinstance(self.model, LNN)  # the model's solve
                else torch.linalg.solve(h, r)
            )
        return torch.cat([s[..., n:], torch.stack(out).reshape(s[..., n:].shape)], -1)


def naive_of(model: DynamicsModel, system: System) -> DynamicsModel | None:
    if isinstance(model, (CHNN, CLNN)):
        return NaiveCartesian(model, system)
    if isinstance(model, (LNN, LNNStructure)):
        return NaiveLagrangian(model, system)
    return None


def compose_cfg(system: str, model: str, hidden: int, depth: int):
    return compose(
        f"system={system}", f"model={model}", f"model.hidden={hidden}", f"model.depth={depth}", "logger=none"
    )


def windows(system: System, chart: str, dt: float, batch: int, chunk: int) -> Tensor:
    """``batch`` true windows of ``chunk`` states in ``chart``, float32."""
    s0 = system.sample_initial(batch, torch.Generator().manual_seed(0))
    t = torch.arange(chunk, dtype=torch.float64) * dt
    return system.to_chart(simulate(system, s0, t), system.base_chart, chart).float()


def stepper(model: DynamicsModel, params: list, system: System, batch: Tensor, dt: float) -> Callable[[], None]:
    module = TrainingModule(model, system, dt, Integrator("rk4"))
    opt = torch.optim.AdamW(params, lr=1e-3)

    def step() -> None:
        opt.zero_grad(set_to_none=True)
        module.loss({"states": batch}).backward()  # a data-module batch (the seam's dict)
        opt.step()

    return step


def time_step(step: Callable[[], None], steps: int, warm_up: bool = True) -> tuple[float, float]:
    """Fastest wall and process-CPU time (ms) of ``steps`` calls, after one warm-up call if ``warm_up``."""
    wall, cpu = [], []
    for i in range(steps + warm_up):
        start, start_cpu = time.perf_counter(), time.process_time()
        step()
        if i or not warm_up:
            wall.append(1e3 * (time.perf_counter() - start))
            cpu.append(1e3 * (time.process_time() - start_cpu))
    return min(wall), min(cpu)


def alternated(
    first: Callable[[], None], second: Callable[[], None], steps: int, repeats: int
) -> tuple[tuple[float, float], tuple[float, float]]:
    """The fastest (wall, CPU) ms of each of two steps timed in turn over ``repeats`` rounds of
    ``time_step``, so that the pair shares the machine's load of the moment (a burst while one was
    timed alone would skew their ratio)."""
    rounds = [(time_step(first, steps), time_step(second, steps)) for _ in range(repeats)]
    return tuple(min((r[i] for r in rounds), key=lambda timing: timing[1]) for i in (0, 1))


def peak_memory(step: Callable[[], None]) -> float:
    """MiB: the high-water mark of torch's allocations during one call, from the profiler's memory
    events in order (tensors alive before the call, e.g. parameters, not counted)."""
    from torch.profiler import ProfilerActivity, profile

    saved, devnull = os.dup(2), os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 2)  # the profiler's C++ start/stop lines
    os.close(devnull)
    try:
        with profile(activities=[ProfilerActivity.CPU], profile_memory=True) as prof:
            step()
    finally:
        os.dup2(saved, 2)
        os.close(saved)
    level = peak = 0
    for event in sorted(prof.events(), key=lambda e: e.time_range.start):
        level += event.self_cpu_memory_usage
        peak = max(peak, level)
    return peak / 2**20


def time_generation(system: System, dt: float, n: int = 1000, n_steps: int = 100) -> tuple[float, float]:
    """Wall and process-CPU time (ms) to simulate ``n`` trajectories (float64 RK4, 10 substeps)."""
    t = torch.arange(n_steps + 1, dtype=torch.float64) * dt
    start, start_cpu = time.perf_counter(), time.process_time()
    sample_trajectories(system, n, t, torch.Generator().manual_seed(0))
    return 1e3 * (time.perf_counter() - start), 1e3 * (time.process_time() - start_cpu)


def fmt(value, spec: str) -> str:
    return "" if value == "" else format(value, spec)


def main() -> None:
    models = catalogue("model")
    parser = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    parser.add_argument("--systems", nargs="+", default=["pendulum2", "gyroscope"])
    parser.add_argument("--models", nargs="+", default=models, choices=models)
    parser.add_argument("--steps", type=int, default=3, help="timed steps per model and round (fastest reported)")
    parser.add_argument("--repeats", type=int, default=3, help="rounds of (floor, model), alternated; fastest of each")
    parser.add_argument("--naive-steps", type=int, default=1, help="timed steps per naive implementation (0: skip)")
    parser.add_argument("--naive-samples", type=int, default=20, help="windows the per-sample loops are timed on")
    parser.add_argument(
        "--compile",
        nargs="*",
        default=["chnn", "clnn", "lnn"],
        choices=models,
        help="models also timed with compile=true (none: skip)",
    )
    parser.add_argument("--batch", type=int, default=200)
    parser.add_argument("--chunk", type=int, default=5)
    parser.add_argument("--hidden", type=int, default=256)
    parser.add_argument("--depth", type=int, default=3)
    parser.add_argument(
        "--threads", type=int, default=None, help="torch threads (default: encons.infra.threads' policy)"
    )
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/speed.csv"))
    args = parser.parse_args()
    threads.apply(args.threads)
    if args.compile:  # an empty inductor cache: the compile time a fresh machine pays
        os.environ["TORCHINDUCTOR_CACHE_DIR"] = tempfile.mkdtemp(prefix="encons-inductor-")
    warnings.filterwarnings("ignore", message=r"hydra\.utils\.instantiate\(\) resolved")  # Hydra's, on every build
    torch.manual_seed(0)
    rows = []

    def add(**row) -> None:
        rows.append({key: row.get(key, "") for key in FIELDS})

    total = len(args.systems) * len(args.models)
    for i_system, system_name in enumerate(args.systems):
        cfg = compose_cfg(system_name, "node", args.hidden, args.depth)
        system, dt = build_system(validate(cfg)), float(cfg.data.dt)
        wall, cpu = time_generation(system, dt)
        add(system=system_name, model="dataset generation (1000 × 100 steps)", wall_ms=wall, cpu_ms=cpu)
        print(f"{system_name}: dataset generation {wall:.0f} ms", flush=True)
        floor_steps, floor_rows = {}, {}
        for order in (1, 2):
            model = BareFloor(system, system.base_chart, order, args.hidden, args.depth)
            floor_steps[order] = stepper(
                model,
                list(model.parameters()),
                system,
                windows(system, system.base_chart, dt, args.batch, args.chunk),
                dt,
            )
            wall, cpu = time_step(floor_steps[order], args.steps)
            add(
                system=system_name,
                model=f"floor (order {order})",
                order=order,
                wall_ms=wall,
                cpu_ms=cpu,
                steps_per_s=1e3 / wall,
                peak_mb=peak_memory(floor_steps[order]),
                ratio_floor=1.0,
            )
            floor_rows[order] = rows[-1]
            print(f"{system_name}: floor order {order}: {wall:.1f} ms", flush=True)

        for i_model, model_name in enumerate(args.models):
            progress = f"[{i_system * len(args.models) + i_model + 1}/{total}] {system_name}: {model_name}"
            try:
                model = build_model(validate(compose_cfg(system_name, model_name, args.hidden, args.depth)), system)
            except ConfigError as err:
                print(f"{progress}: skipped ({err})", flush=True)
                continue
            batch = windows(system, model.chart, dt, args.batch, args.chunk)
            step = stepper(model, list(model.parameters()), system, batch, dt)
            order = 2 if isinstance(model, LNN) else 1  # LNN, GLNN: Hessians of the network; the rest gradients
            (floor_wall, floor_cpu), (wall, cpu) = alternated(floor_steps[order], step, args.steps, args.repeats)
            floor_row = floor_rows[order]  # keeps the floor's fastest over every pairing
            floor_row.update(wall_ms=min(floor_row["wall_ms"], floor_wall), cpu_ms=min(floor_row["cpu_ms"], floor_cpu))
            floor_row["steps_per_s"] = 1e3 / floor_row["wall_ms"]
            row = dict(
                system=system_name,
                model=model_name,
                order=order,
                wall_ms=wall,
                cpu_ms=cpu,
                steps_per_s=1e3 / wall,
                peak_mb=peak_memory(step),
                ratio_floor=cpu / floor_cpu,
            )
            naive = naive_of(model, system) if args.naive_steps else None
            if naive is not None:
                part = batch[: args.naive_samples] if isinstance(naive, NaiveLagrangian) else batch
                _, naive_cpu = time_step(
                    stepper(naive, list(model.parameters()), system, part, dt), args.naive_steps, warm_up=False
                )  # seconds per step: no warm-up needed
                naive_cpu *= len(batch) / len(part)
                row.update(naive_cpu_ms=naive_cpu, speedup_vs_naive=naive_cpu / cpu)
            if model_name in args.compile:
                compiled = copy.deepcopy(model)
                compiled.compile()  # what compile=true does (encons.training.build.build_model)
                compiled_step = stepper(compiled, list(compiled.parameters()), system, batch, dt)
                start = time.perf_counter()
                compiled_step()  # compiles
                row["compile_s"] = time.perf_counter() - start
                (_, eager_cpu), (_, compiled_cpu) = alternated(step, compiled_step, args.steps, args.repeats)
                row["speedup_compiled"] = eager_cpu / compiled_cpu
            add(**row)
            print(
                f"{progress}: {wall:.1f} ms"
                + (f", naive {row['naive_cpu_ms']:.0f} ms" if naive else "")
                + (f", compiled ×{row['speedup_compiled']:.2f}" if "compile_s" in row else ""),
                flush=True,
            )

    header = [
        "system",
        "model",
        "order",
        "wall ms",
        "CPU ms",
        "steps/s",
        "peak MiB",
        "× floor",
        "naive CPU ms",
        "speed-up vs naive",
        "compile s",
        "speed-up compiled",
    ]
    specs = ["", "", "", ".1f", ".1f", ".2f", ".0f", ".2f", ".0f", ".1f", ".0f", ".2f"]
    lines = [[fmt(r[k], s) if s else str(r[k]) for k, s in zip(FIELDS, specs)] for r in rows]
    widths = [max(len(h), *(len(line[i]) for line in lines)) for i, h in enumerate(header)]
    print()
    for line in [header] + lines:
        print("  ".join(cell.ljust(w) if i < 2 else cell.rjust(w) for i, (cell, w) in enumerate(zip(line, widths))))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with args.out.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=FIELDS)
        writer.writeheader()
        writer.writerows(rows)
    machine = (
        f"{platform.machine()} {platform.processor() or platform.platform()}, "
        f"{torch.get_num_threads()} torch thread(s), torch {torch.__version__}, "
        f"batch {args.batch} × chunk {args.chunk}, {args.depth} × {args.hidden}, "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}"
    )
    markdown = args.out.with_suffix(".md")
    table = [f"Machine: {machine}.", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    table += ["| " + " | ".join(line) + " |" for line in lines]
    markdown.write_text("\n".join(table) + "\n")
    print(f"\nwritten: {args.out}, {markdown}")


if __name__ == "__main__":
    main()
