"""The evaluation's own floor: the true field of each system, rolled out from simulated test starts by
candidate test integrators (``encons.numerics.evaluation.Evaluation``), scored by geom_rel_err in the common chart.

    python benchmarks/evaluation_floor.py gyroscope,pendulum2 [N_TRAJECTORIES] [--long] [--threads 1]

Prints one line per system × chart × integrator: RK4 at the data dt (the training integrator, what test
rollouts used before), RK4 with 16 steps per dt, and the default (dopri5 at rtol 1e-10, atol 1e-12), all
in float64, over the training horizon (``data.n_steps``; ``--long``: the test horizon ``data.test_steps``).
"""

from __future__ import annotations

import argparse
import time

import torch

from encons.config.check import validate
from encons.data.simulate import sample_trajectories
from encons.entry import api
from encons.infra import threads
from encons.numerics import metrics
from encons.numerics.evaluation import Evaluation
from encons.training.build import build_system

CANDIDATES = {
    "rk4 x1": Evaluation(method="rk4"),
    "rk4 x16": Evaluation(method="rk4", substeps=16),
    "dopri5 1e-10 (default)": Evaluation(),
}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("systems", help="comma-separated system names, e.g. gyroscope,pendulum2")
    parser.add_argument("n", nargs="?", type=int, default=100, help="test starts per system")
    parser.add_argument("--long", action="store_true", help="the test horizon instead of the training one")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    threads.apply(args.threads)
    for name in args.systems.split(","):
        cfg = api.compose(f"system={name}", output_dir=".")
        system = build_system(validate(cfg))
        steps = (cfg.data.test_steps or cfg.data.n_steps) if args.long else cfg.data.n_steps
        t = torch.arange(steps + 1, dtype=torch.float64) * cfg.data.dt
        true, u, _ = sample_trajectories(system, args.n, t, torch.Generator().manual_seed(123), cfg.data.substeps)
        reference = system.to_chart(true, system.base_chart, system.common_chart)
        for chart in system.charts:
            start = system.to_chart(true[:, 0], system.base_chart, chart)
            for label, evaluation in CANDIDATES.items():
                began = time.perf_counter()
                pred = evaluation.oracle(system, chart, start, t, u)
                took = time.perf_counter() - began
                geom = (
                    metrics.geometric_mean_relative_error(system.to_chart(pred, chart, system.common_chart), reference)
                    .mean()
                    .item()
                )
                print(
                    f"{name:18s} {chart:9s} {steps:5d} steps  {label:24s} geom_rel_err {geom:.2e}  {took:6.1f} s",
                    flush=True,
                )


if __name__ == "__main__":
    main()
