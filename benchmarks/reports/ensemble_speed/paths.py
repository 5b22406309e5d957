"""Which path each model takes in a 2-seed ensemble (debug=fast, its usual system): the table of paths.md.

Usage: ``PYTHONPATH=. python benchmarks/reports/ensemble_speed/paths.py [MODEL ...]`` (all rows, or those of the
models named); one thread.
"""

import sys
import tempfile

import torch

from encons.entry import api
from encons.training import ensemble

CASES = [
    ("node", "pendulum2", []),
    ("hnn", "pendulum2", []),
    ("hnn_angle", "pendulum2", []),
    ("hnn_structure", "pendulum2", []),
    ("hnn_structure_angle", "pendulum2", []),
    ("lnn", "pendulum2", []),
    ("lnn_angle", "pendulum2", []),
    ("lnn_structure", "pendulum2", []),
    ("lnn_structure_angle", "pendulum2", []),
    ("chnn", "gyroscope", []),
    ("clnn", "gyroscope", []),
    ("nsf", "mass_spring", []),
    ("inn_node", "mass_spring", ["regulariser=hamiltonian"]),
    ("node", "mass_spring", ["regulariser=hamiltonian"]),
    ("lnode", "pendulum_control", []),
    ("symo", "pendulum_control", ["objective=residual"]),
    ("e2e_symo", "pendulum_control", []),
    ("glnn", "damped_oscillator", []),
    ("second_order", "damped_oscillator", []),
    ("node", "pixel_pendulum", []),
]


def main() -> None:
    torch.set_num_threads(1)
    cache = tempfile.mkdtemp()
    only = set(sys.argv[1:])
    for model, system, extra in CASES:
        if only and model not in only:
            continue
        mods, data = [], None
        for seed in (0, 1):
            cfg = api.compose(
                f"model={model}",
                f"system={system}",
                "debug=fast",
                "logger=none",
                *extra,
                f"seed={seed}",
                output_dir=tempfile.mkdtemp(),
                cache_dir=cache,
            )
            built, module = api.build(cfg)
            mods.append(module)
            data = data or built
        path = ensemble._module(cfg, mods, [0, 1], data, None).path
        print(f"| {model} {' '.join(extra)} | {system} | {path} |", flush=True)


if __name__ == "__main__":
    main()
