"""Which committed reports the angle-honest metrics change, measured without training: the two trivial
baselines (constant, linear ODE) scored with and without ``angles`` on each angle-marked system's test set.

    python benchmarks/reports/recording-angles/affected.py [system ...]

A model's score changes exactly where these do — a true angle outside [−π, π) (the scale) — and, in
addition, where its prediction is more than π from the truth in an angle (the error); the first is a
property of the data, printed here as the share of test states with an angle outside [−π, π).
"""

from __future__ import annotations

import math
import sys
import tempfile

import torch

from encons import api, metrics

SYSTEMS = ("compound_pendulum", "pendulum_control", "cartpole")


def main(systems: tuple[str, ...] = SYSTEMS) -> None:
    print(f"{'system':<20}{'states |q|>π':>14}{'metric':>42}{'plain':>12}{'on circle':>12}{'change':>10}")
    for name in systems:
        cfg = api.compose(f"system={name}", "model=node", output_dir=f"{tempfile.gettempdir()}/encons-affected",
                          cache_dir=f"{tempfile.gettempdir()}/encons-affected-cache")
        data, module = api.build(cfg)
        data.prepare_data()
        data.setup()
        true = data.states["test"].double()
        train = data.states["train"].double()
        angles = module.system.angle_entries(module.system.common_chart)
        outside = ((true[..., : true.shape[-1] // 2].abs() > math.pi) & angles[: true.shape[-1] // 2]).any(-1)
        baselines = metrics.baseline_rollouts(true, train, data.dt)
        for mask, label in ((None, "plain"), (angles, "circle")):
            scalars, _ = metrics.long_rollout_errors(true, baselines["baseline_constant"], baselines, energy=None,
                                                     angles=mask)
            if mask is None:
                plain = scalars
        for key in [k for k in scalars if k.startswith("baseline_") and not k.endswith("_final")]:
            change = scalars[key] / plain[key] - 1
            print(f"{name:<20}{outside.double().mean().item():>14.3%}{key:>42}{plain[key]:>12.5g}"
                  f"{scalars[key]:>12.5g}{change:>+10.2%}")


if __name__ == "__main__":
    main(tuple(sys.argv[1:]) or SYSTEMS)
