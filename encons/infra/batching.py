"""Per-sample functions over any leading batch shape: ``torch.func.vmap`` and batched gradients; products per member
of a seed ensemble (a leading member axis: ``member_view``, ``product``)."""

from __future__ import annotations

from typing import Callable

import torch
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


def member_view(t: Tensor, dim: int) -> Tensor:
    """A member-stacked tensor (K, *rest) viewed as (K, 1, ..., 1, *rest) of ``dim`` axes: broadcastable against
    activations (K, ..., ·) whose leading axis is the member axis."""
    return t.reshape(t.shape[0], *[1] * (dim - t.dim()), *t.shape[1:])


def product(x: Tensor, w: Tensor) -> Tensor:
    """x @ w for a matrix w (a, b), or per member for member-stacked matrices w (K, a, b) and x (K, ..., a) whose
    leading axis is the member axis (a seed ensemble's networks, ``encons.models.networks.EnsembleLinear``, or its
    learned masses, ``encons.systems.constrained``): one batched product for all members."""
    if w.dim() == 2:
        return x @ w
    return torch.bmm(x.reshape(w.shape[0], -1, x.shape[-1]), w).reshape(*x.shape[:-1], w.shape[-1])
