"""What one stacked product saves against the members' separate products on this CPU (issue 47).

``cells.md``, section "The stacked product against separate ones", quotes its output.

    PYTHONPATH=. python benchmarks/reports/ensemble_speed/bmm_vs_mm.py

Times, one thread, fastest of 15 interleaved rounds of 200 calls of process CPU time (``ensemble_speed.fastest``):
the forward product of K = 8 members' activations (30 rows of 200, one 30-state window) by their 200 × 200
weights as one ``bmm`` and as 8 ``mm``; the weight-gradient product xᵀ ḡ ((8, 200, 30) by (8, 30, 200), the
transposed view autograd passes) the same two ways, and ``bmm`` into a preallocated output (the cost of a fresh
1.28 MB result). Writes ``bmm_vs_mm.json`` beside
this script (milliseconds per call).
"""

from __future__ import annotations

import json
from pathlib import Path

import torch

from benchmarks.ensemble_speed import fastest

K, ROWS, WIDTH = 8, 30, 200


def main() -> None:
    torch.set_num_threads(1)
    torch.manual_seed(0)
    a, b = torch.randn(K, ROWS, WIDTH), torch.randn(K, ROWS, WIDTH)
    w = torch.randn(K, WIDTH, WIDTH)
    out = torch.empty(K, WIDTH, WIDTH)
    seconds = fastest(
        {
            "forward, one bmm": lambda: torch.bmm(a, w),
            "forward, 8 mm": lambda: [torch.mm(a[k], w[k]) for k in range(K)],
            "weight gradient, one bmm": lambda: torch.bmm(a.transpose(1, 2), b),
            "weight gradient, 8 mm": lambda: [torch.mm(a[k].T, b[k]) for k in range(K)],
            "weight gradient, one bmm into a preallocated output": lambda: torch.bmm(a.transpose(1, 2), b, out=out),
        },
        steps=200,
        rounds=15,
    )
    times = {name: value * 1e3 for name, value in seconds.items()}
    for name, ms in times.items():
        print(f"{name}: {ms:.3f} ms")
    result = {"what": __doc__.split("\n")[0], "torch": torch.__version__, "threads": 1, "ms_per_call": times}
    Path(__file__).with_name("bmm_vs_mm.json").write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
