"""Speed of an E2E-SyMo training step against a SyMo step at the same sizes (Santos et al. §5–6).

One step is what ``TrainingModule`` does per batch: windows of 3 states (q_{k−1}, q_k, q_{k+1})
with constant controls; SyMo: the squared DEL residual (eq. (15)); E2E-SyMo: Newton root-find of
q_{k+1} (training tolerance 1e-5, at most 10 iterations, batched: one linear solve per iteration
for the whole batch) and the L1 rollout loss, backward by the implicit gradient (eq. (16)); then
backward and an Adam step. Networks: tanh 2 × 128 (pendulum) / 2 × 256 (cart-pole), as in §7;
batch 512 windows (4 × N_train at N_train = 128). Reports the fastest wall and process-CPU time of
a few steps, their ratio (target ≤ 3) and E2E-SyMo's Newton iteration counts.
Usage: ``python benchmarks/symo_speed.py [--steps 5] [--batch 512] [--threads 1]``.
"""

from __future__ import annotations

import argparse
import time

import torch

from encons.data.simulate import simulate
from encons.infra import threads
from encons.models.symo import E2ESyMo, SyMo
from encons.systems.controlled import CartPole, ControlledPendulum
from encons.training.module import TrainingModule

SYSTEMS = {"pendulum_control": (ControlledPendulum, 0.1, 128), "cartpole": (CartPole, 0.05, 256)}


def batch(system, dt: float, size: int) -> dict[str, torch.Tensor]:
    gen = torch.Generator().manual_seed(0)
    s0, u = system.sample_initial(size, gen), system.sample_controls(size, gen)
    u = u[:, None].expand(-1, 3, -1)
    t = torch.arange(3, dtype=torch.float64) * dt
    return {"states": simulate(system, s0, t, 10, u).float(), "u": u.float()}


def time_step(module: TrainingModule, data: dict, steps: int) -> tuple[float, float, list[int]]:
    """Fastest wall and CPU time (ms) of ``steps`` steps after a warm-up, and Newton iterations per step."""
    opt = torch.optim.Adam(module.parameters(), lr=1e-4)
    wall, cpu, iters = [], [], []
    for i in range(steps + 1):
        start, start_cpu = time.perf_counter(), time.process_time()
        opt.zero_grad(set_to_none=True)
        module.loss(data).backward()
        opt.step()
        if i:
            wall.append(time.perf_counter() - start)
            cpu.append(time.process_time() - start_cpu)
            iters += module.model.newton_iterations if module.objective == "rollout" else []
    return 1e3 * min(wall), 1e3 * min(cpu), iters


def main() -> None:
    parser = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    parser.add_argument("--steps", type=int, default=5)
    parser.add_argument("--batch", type=int, default=512)
    parser.add_argument(
        "--threads", type=int, default=None, help="torch threads (default: encons.infra.threads' policy)"
    )
    args = parser.parse_args()
    threads.apply(args.threads)
    print(f"{'system':<18}{'model':<10}{'wall ms':>9}{'cpu ms':>9}{'ratio':>7}  Newton iterations")
    for name, (cls, dt, hidden) in SYSTEMS.items():
        system = cls()
        data = batch(system, dt, args.batch)
        times = {}
        for model_cls in (SyMo, E2ESyMo):
            torch.manual_seed(0)
            model = model_cls(system, hidden=hidden, depth=2).train()
            module = TrainingModule(model, system, dt, None, objective=model_cls.objectives[0])
            wall, cpu, iters = time_step(module, data, args.steps)
            times[model_cls] = cpu
            ratio = cpu / times[SyMo]
            its = f"{min(iters)}–{max(iters)} (mean {sum(iters) / len(iters):.1f})" if iters else "—"
            print(f"{name:<18}{model_cls.__name__:<10}{wall:9.1f}{cpu:9.1f}{ratio:7.2f}  {its}")


if __name__ == "__main__":
    main()
