"""How many intra-op threads torch uses in a run: one policy for ``encons.train``, the Python API,
sweeps and ``encons.tools.benchmark``.

The zoo's work is small (3×256 networks at batch 200, float64 simulation of a few hundred
trajectories): each op is too short to share, and every extra thread waits at the op's barrier for
a core that another process may hold. So a run takes, in this order:

1. ``threads=N`` (a positive integer) from its config;
2. else ``OMP_NUM_THREADS`` (or ``MKL_NUM_THREADS``) from the environment;
3. else ``threads=auto``: this process's cores ÷ the runs launched in parallel with it;
4. else (``threads=null``, the default) :data:`DEFAULT`, measured fastest for the zoo (docs/speed.md).

Data are simulated in the run's process after the threads are set, so under the same number.
A parallel sweep (``hydra/launcher=parallel``) resolves the policy once, in the launching process,
and its workers receive the number as ``OMP_NUM_THREADS`` (the launcher's ``inner_max_num_threads``).
"""

from __future__ import annotations

import os

from omegaconf import OmegaConf

from encons.infra.errors import ConfigError

DEFAULT = 1
ENV_KEYS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS")
ALLOWED = "null (1, or OMP_NUM_THREADS when set), a positive integer, auto (cores ÷ parallel runs)"


def cores() -> int:
    """The cores this process may run on (its affinity mask, as ``taskset`` or a batch system sets it)."""
    return len(os.sched_getaffinity(0))


def choose(threads: int | str | None = None, parallel: int = 1) -> int:
    """The thread count of a run whose ``threads`` key is ``threads``, one of ``parallel`` runs at once."""
    if (
        threads is not None
        and threads != "auto"
        and (isinstance(threads, bool) or not isinstance(threads, int) or threads < 1)
    ):
        raise ConfigError(f"threads={threads!r}; allowed: {ALLOWED}")
    if isinstance(threads, int):
        return threads
    for key in ENV_KEYS:
        if os.environ.get(key, "").strip():
            value = os.environ[key].strip()
            if not value.isdigit() or int(value) < 1:
                raise ConfigError(f"{key}={value!r} (environment); allowed: a positive integer, or unset")
            return int(value)
    return max(1, cores() // parallel) if threads == "auto" else DEFAULT


def apply(threads: int | str | None = None) -> int:
    """Set torch's intra-op threads by the policy (see :func:`choose`); returns the number set."""
    import torch

    n = choose(threads)
    if torch.get_num_threads() != n:
        torch.set_num_threads(n)
    return n


def register() -> None:
    """Make ``${encons_threads:${threads},${.n_jobs}}`` (the parallel launcher's number for its workers,
    ``conf/hydra/launcher/parallel.yaml``) resolve; the entries call it before Hydra composes anything
    (``encons.entry.cli``, ``encons.training.build.compose``)."""
    OmegaConf.register_resolver("encons_threads", choose, replace=True)
