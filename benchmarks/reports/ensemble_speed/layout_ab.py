"""A/B of ``EnsembleLinear``'s weight layout in one process (issue 47; ``cells.md``, section "EnsembleLinear holds
Wᵀ"): a cell's stacked training step as encons builds it (the parameter Wᵀ, (K, in, out)) against the same step
with every ``EnsembleLinear`` swapped for the layout before ``bfb2362`` (the parameter W, (K, out, in), the product
x Wᵀ on its transposed view), the same weights, fastest of 5 interleaved rounds of process CPU time, one thread.
Usage: ``PYTHONPATH=. python benchmarks/reports/ensemble_speed/layout_ab.py CELL [CELL ...]`` (cells of
``benchmarks/ensemble_speed.py``)."""

from __future__ import annotations

import copy
import sys
import tempfile

import torch
from torch import Tensor, nn

from benchmarks import ensemble_speed as es
from encons.models.networks import EnsembleLinear
from encons.training import ensemble, stacked


class Before(EnsembleLinear):
    """``EnsembleLinear`` as it was: a (K, out, in) parameter, the product on its transposed view."""

    def __init__(self, now: EnsembleLinear):
        nn.Module.__init__(self)
        self.w = nn.Parameter(now.weight.detach().contiguous().clone())
        self.bias = None if now.bias is None else nn.Parameter(now.bias.detach().clone())

    @property
    def weight(self) -> Tensor:
        return self.w

    def forward(self, x: Tensor) -> Tensor:
        rows = x.reshape(self.w.shape[0], -1, x.shape[-1])
        w = self.w.transpose(1, 2)
        out = torch.bmm(rows, w) if self.bias is None else torch.baddbmm(self.bias.unsqueeze(1), rows, w)
        return out.reshape(*x.shape[:-1], out.shape[-1])


def swap(module: nn.Module) -> int:
    """Replace every ``EnsembleLinear`` under ``module`` by ``Before``; how many."""
    count = 0
    for name, child in list(module.named_children()):
        if isinstance(child, EnsembleLinear):
            setattr(module, name, Before(child))
            count += 1
        else:
            count += swap(child)
    return count


def losses64(module: ensemble.StackedEnsemble, batch: dict) -> torch.Tensor:
    """The stacked losses on ``batch`` of a float64 copy: the two layouts compute the same function, which float32
    rounds apart by more than 1e-5 where a loss is ill-conditioned (NSF's, ``stacked.probe``)."""
    return copy.deepcopy(module.stacked).double().training_loss(stacked.float64_batch(batch)).detach()


def main(cells: list[str], cache: str) -> None:
    for name, cell, pool, batch in es.pools(cells, cache):
        for k in (3, 8):
            now, opt_now = es.stacked_ensemble(cell, pool, batch, k, cache)
            before = copy.deepcopy(now)
            if not isinstance(now, ensemble.StackedEnsemble) or not swap(before.stacked):
                print(f"{name}: no EnsembleLinear on its stacked path", flush=True)
                break
            assert torch.allclose(losses64(now, batch), losses64(before, batch), rtol=1e-9)
            opt_before = stacked.optimizer(pool[0].optimizer, list(before.stacked.parameters()))
            steps = 10 if name.startswith(es.SLOW + ("pixels",)) else 50
            t = es.fastest(
                {
                    "before": lambda: es.ensemble_step(before, opt_before, batch),
                    "now": lambda: es.ensemble_step(now, opt_now, batch),
                },
                steps,
            )
            es.ab_line(name, k, "(K, out, in)", "Wᵀ", t)


if __name__ == "__main__":
    main(sys.argv[1:], tempfile.mkdtemp())
