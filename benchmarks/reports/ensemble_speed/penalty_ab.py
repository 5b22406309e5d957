"""A/B of the stacked Jacobian penalty in one process (issue 47; ``cells.md``, section "The stacked Jacobian
penalty without vmap"): a regularised cell's stacked training step with ``StackedModel.penalty`` as encons has it
(the rows repeated once per field dimension, one pullback) against the version before (``vmap`` of the pullback
over the basis e_j), the same module and weights, fastest of 5 interleaved rounds of process CPU time, one thread.
Usage: ``PYTHONPATH=. python benchmarks/reports/ensemble_speed/penalty_ab.py CELL [CELL ...]`` (cells of
``benchmarks/ensemble_speed.py``)."""

from __future__ import annotations

import sys
import tempfile
from collections.abc import Callable
from typing import Any

import torch
from torch import Tensor
from torch.func import vjp, vmap

from benchmarks import ensemble_speed as es
from encons.training import stacked

NOW = stacked.StackedModel.penalty


def before(self: stacked.StackedModel, regulariser: Any, points: Tensor, u: Tensor | None) -> Tensor:
    """``StackedModel.penalty`` before: ``vmap`` of the pullback over the basis e_j."""
    if self.dimension is None:
        return self.per_member(regulariser, (points, u), (True, u is not None))
    z = self.to_internal(points)
    t = torch.zeros((), dtype=points.dtype, device=points.device)
    _, pullback = vjp(lambda z: self(t, z) if u is None else self(t, z, u), z)
    basis = torch.eye(z.shape[-1], dtype=z.dtype, device=z.device).unsqueeze(1).expand(-1, *z.shape)
    jac = vmap(pullback)(basis)[0].movedim(0, 1)
    return regulariser.weight * regulariser.violation(jac).reshape(self.k, -1).mean(1)


def main(cells: list[str], cache: str) -> None:
    for name, cell, pool, batch in es.pools(cells, cache):
        for k in (3, 8):
            module, opt = es.stacked_ensemble(cell, pool, batch, k, cache)

            def step(way: Any) -> Callable[[], None]:
                def run() -> None:
                    stacked.StackedModel.penalty = way  # type: ignore[method-assign]
                    es.ensemble_step(module, opt, batch)

                return run

            t = es.fastest({"before": step(before), "now": step(NOW)}, 30)
            stacked.StackedModel.penalty = NOW  # type: ignore[method-assign]
            es.ab_line(name, k, "vmap over e_j", "rows repeated", t)


if __name__ == "__main__":
    main(sys.argv[1:], tempfile.mkdtemp())
