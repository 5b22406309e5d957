"""Per-sample functions over any leading batch shape: ``torch.func.vmap`` and batched gradients."""

from __future__ import annotations

from typing import Callable

from torch import Tensor
from torch.func import grad, vmap


def batched(fn: Callable[..., Tensor], *args: Tensor) -> Tensor:
    """``fn`` maps single samples (last axis only); apply it to every sample of ``args``."""
    lead = args[0].shape[:-1]
    flat = [a.reshape(-1, a.shape[-1]) for a in args]
    out = vmap(fn)(*flat)
    return out.reshape(*lead, *out.shape[1:])


def batched_grad(fn: Callable[[Tensor], Tensor], x: Tensor) -> Tensor:
    """∇fn at every sample of ``x`` for a batch-aware scalar ``fn``: (..., d) -> (...).

    One ``torch.func.grad`` of the sum, exact because samples do not interact; unlike ``vmap``
    over samples it leaves the outer backward unbatched.
    """
    return grad(lambda y: fn(y).sum())(x)
