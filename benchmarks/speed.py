"""Speed of one training step per model, against the bare floor of its derivative order.

A step is what ``DynamicsModule`` does per batch: roll out 200 windows of 5 states with RK4
(4 steps, 16 field evaluations), L1 loss, backward, AdamW step, 3 × 256 Softplus networks
(DESIGN.md "Speed targets"). The floors are the same step with the simplest field of each
derivative order, through one 3 × 256 network V(q) and batched ``autograd.grad``
(``create_graph=True``): order 1 is q̈ = −∇V(q); order 2 is q̈ = −∇²V(q) q̇ (one
Hessian-vector product). The fastest of a few steps is reported, as wall time and as process
CPU time; ratios to the floor use CPU time, which other people's load on a shared machine
disturbs least (run with ``--threads 1`` there). Also times paper-size dataset generation (900 trajectories × 100
steps). Usage: ``python benchmarks/speed.py [--systems ...] [--models ...] [--out CSV]``.
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import torch
from hydra import compose, initialize_config_dir
from torch import Tensor

from encons.config import build_model, build_system
from encons.data.simulate import sample_trajectories, simulate
from encons.integrators import Integrator
from encons.models.base import DynamicsModel
from encons.models.networks import mlp
from encons.module import DynamicsModule
from encons.paths import config_dir
from encons.systems.base import System, split_state

MODELS = ("node", "hnn", "hnn_angle", "hnn_structure", "hnn_structure_angle", "lnn", "lnn_angle",
          "lnn_structure", "lnn_structure_angle", "chnn", "clnn")
ORDER = {"lnn": 2, "lnn_angle": 2}  # derivative order of the networks in the field; 1 for the rest


class BareFloor(DynamicsModel):
    """ṡ = (q̇, −∇V) (order 1) or (q̇, −∇²V q̇) (order 2) by batched ``autograd.grad``."""

    def __init__(self, system: System, chart: str, order: int, hidden: int, depth: int):
        super().__init__(system, chart)
        self.order = order
        self.net = mlp(self.n, 1, hidden, depth)

    def forward(self, t: Tensor, s: Tensor) -> Tensor:
        q, qd = split_state(s)
        with torch.enable_grad():
            q = q if q.requires_grad else q.requires_grad_()
            (dv,) = torch.autograd.grad(self.net(q).sum(), q, create_graph=True)
            if self.order == 2:
                (dv,) = torch.autograd.grad((dv * qd).sum(), q, create_graph=True)
        return torch.cat([qd, -dv], -1)


def compose_cfg(system: str, model: str, hidden: int, depth: int):
    with initialize_config_dir(config_dir=config_dir(), job_name="bench", version_base=None):
        return compose("train", overrides=[f"system={system}", f"model={model}", f"model.hidden={hidden}",
                                           f"model.depth={depth}", "logger=none"])


def windows(system: System, chart: str, dt: float, batch: int, chunk: int) -> Tensor:
    """``batch`` true windows of ``chunk`` states in ``chart``, float32."""
    s0 = system.sample_initial(batch, torch.Generator().manual_seed(0))
    t = torch.arange(chunk, dtype=torch.float64) * dt
    return system.to_chart(simulate(system, s0, t), system.base_chart, chart).float()


def time_step(model: DynamicsModel, system: System, batch: Tensor, dt: float, steps: int) -> tuple[float, float]:
    """Fastest wall and process-CPU time (ms) of ``steps`` training steps after one warm-up step."""
    module = DynamicsModule(model, system, dt, Integrator("rk4"))
    opt = torch.optim.AdamW(model.parameters(), lr=1e-3)
    wall, cpu = [], []
    for i in range(steps + 1):
        start, start_cpu = time.perf_counter(), time.process_time()
        opt.zero_grad(set_to_none=True)
        module.loss({"states": batch}).backward()  # a data-module batch (the seam's dict)
        opt.step()
        if i:
            wall.append(1e3 * (time.perf_counter() - start))
            cpu.append(1e3 * (time.process_time() - start_cpu))
    return min(wall), min(cpu)


def time_generation(system: System, dt: float, n: int = 900, n_steps: int = 100) -> tuple[float, float]:
    """Wall and process-CPU time (ms) to simulate ``n`` paper-size trajectories (float64 RK4, 10 substeps)."""
    t = torch.arange(n_steps + 1, dtype=torch.float64) * dt
    start, start_cpu = time.perf_counter(), time.process_time()
    sample_trajectories(system, n, t, torch.Generator().manual_seed(0))
    return 1e3 * (time.perf_counter() - start), 1e3 * (time.process_time() - start_cpu)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--systems", nargs="+", default=["pendulum2", "gyroscope"])
    parser.add_argument("--models", nargs="+", default=list(MODELS), choices=MODELS)
    parser.add_argument("--steps", type=int, default=5, help="timed steps per model (fastest reported)")
    parser.add_argument("--batch", type=int, default=200)
    parser.add_argument("--chunk", type=int, default=5)
    parser.add_argument("--hidden", type=int, default=256)
    parser.add_argument("--depth", type=int, default=3)
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/speed.csv"))
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    rows = []
    for system_name in args.systems:
        cfg = compose_cfg(system_name, "node", args.hidden, args.depth)
        system, dt = build_system(cfg), float(cfg.data.dt)
        wall, cpu = time_generation(system, dt)
        rows.append(dict(system=system_name, model="dataset generation (900 × 100 steps)", order="",
                         wall_ms=wall, cpu_ms=cpu, ratio=""))
        print(f"{system_name}: dataset generation {wall:.0f} ms", flush=True)
        floors = {}
        for order in (1, 2):
            model = BareFloor(system, system.base_chart, order, args.hidden, args.depth)
            batch = windows(system, system.base_chart, dt, args.batch, args.chunk)
            wall, floors[order] = time_step(model, system, batch, dt, args.steps)
            rows.append(dict(system=system_name, model=f"floor (order {order})", order=order, wall_ms=wall,
                             cpu_ms=floors[order], ratio=1.0))
            print(f"{system_name}: floor order {order}: {wall:.1f} ms", flush=True)
        for model_name in args.models:
            model = build_model(compose_cfg(system_name, model_name, args.hidden, args.depth), system)
            batch = windows(system, model.chart, dt, args.batch, args.chunk)
            wall, cpu = time_step(model, system, batch, dt, args.steps)
            order = ORDER.get(model_name, 1)
            rows.append(dict(system=system_name, model=model_name, order=order, wall_ms=wall, cpu_ms=cpu,
                             ratio=cpu / floors[order]))
            print(f"{system_name}: {model_name}: {wall:.1f} ms", flush=True)
    print(f"\n{'system':<10} {'model':<38} {'order':>5} {'wall ms':>9} {'CPU ms':>9} {'× floor':>8}")
    for r in rows:
        ratio = f"{r['ratio']:.2f}" if r["ratio"] != "" else ""
        print(f"{r['system']:<10} {r['model']:<38} {r['order']!s:>5} {r['wall_ms']:>9.1f} {r['cpu_ms']:>9.1f} "
              f"{ratio:>8}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with args.out.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=["system", "model", "order", "wall_ms", "cpu_ms", "ratio"])
        writer.writeheader()
        writer.writerows(rows)
    markdown = args.out.with_suffix(".md")
    lines = ["| system | model | order | wall ms | CPU ms | × floor |", "|---|---|---|---|---|---|"]
    lines += [f"| {r['system']} | {r['model']} | {r['order']} | {r['wall_ms']:.1f} | {r['cpu_ms']:.1f} | "
              f"{r['ratio'] if r['ratio'] == '' else format(r['ratio'], '.2f')} |" for r in rows]
    markdown.write_text("\n".join(lines) + "\n")
    print(f"\nwritten: {args.out}, {markdown}")


if __name__ == "__main__":
    main()
