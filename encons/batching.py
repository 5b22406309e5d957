"""Run a per-sample function over any leading batch shape with ``torch.func.vmap``."""

from __future__ import annotations

from typing import Callable

from torch import Tensor
from torch.func import vmap


def batched(fn: Callable[..., Tensor], *args: Tensor) -> Tensor:
    """``fn`` maps single samples (last axis only); apply it to every sample of ``args``."""
    lead = args[0].shape[:-1]
    flat = [a.reshape(-1, a.shape[-1]) for a in args]
    out = vmap(fn)(*flat)
    return out.reshape(*lead, *out.shape[1:])
