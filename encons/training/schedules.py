"""Learning-rate schedules that torch does not ship, for ``conf/scheduler`` (``_partial_`` configs)."""

from __future__ import annotations

import math
from typing import Annotated

from torch.optim import Optimizer
from torch.optim.lr_scheduler import LambdaLR

from encons.infra.bounds import Declared, Range


class WarmupCosine(LambdaLR, Declared):
    """Linear warm-up from 0 over the first ``warmup`` fraction of ``total_steps``, then cosine decay to
    0 at ``total_steps``; stepped once per optimiser step. ``total_steps`` is given by the module
    (Lightning's estimate for ``max_epochs``): a run stopped by ``max_time`` ends before the decay does."""

    config_key = "scheduler"

    def __init__(self, optimizer: Optimizer, total_steps: int, warmup: Annotated[float, Range(ge=0, lt=1)] = 0.0):
        warm = int(warmup * total_steps)
        decay = max(1, total_steps - warm)
        super().__init__(
            optimizer,
            lambda step: (step + 1) / warm if step < warm else 0.5 * (1 + math.cos(math.pi * (step - warm) / decay)),
        )
