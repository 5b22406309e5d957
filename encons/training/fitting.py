"""``trainer.fit`` as a batch job expects it, for a single run and a seed ensemble alike.

SIGTERM (what a scheduler sends before it kills a job) and Ctrl-C (SIGINT) both take Lightning's SIGTERM path:
training stops at the next batch, the checkpoints written so far stay (``last.ckpt`` holds the last whole epoch),
and the stop is raised as :class:`encons.infra.errors.Interrupted` with the command that resumes the run in the same
folder; the CLI exits 143 (SIGTERM) or 130 (SIGINT). Lightning's own Ctrl-C path would exit 1 with no resume line;
a second Ctrl-C still interrupts at once.
"""

from __future__ import annotations

import os
import shlex
import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from omegaconf import DictConfig

from encons.config.check import Request
from encons.infra.errors import ConfigError, Interrupted


@contextmanager
def sigint_as_sigterm() -> Iterator[list[int]]:
    """While inside, a first Ctrl-C is sent on as SIGTERM (Lightning's graceful stop); the signals received are
    listed in the yielded list. Outside the main thread (no signal handlers there) it does nothing."""
    received: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield received
        return
    previous = signal.getsignal(signal.SIGINT)

    def handler(signum: int, frame: Any) -> None:
        received.append(signum)
        signal.signal(signal.SIGINT, previous)  # a second Ctrl-C: the usual KeyboardInterrupt
        os.kill(os.getpid(), signal.SIGTERM)

    signal.signal(signal.SIGINT, handler)
    try:
        yield received
    finally:
        signal.signal(signal.SIGINT, previous)


def fit(cfg: DictConfig, trainer: Any, module: Any, data: Any, resume: str | None, request: Request) -> None:
    """``trainer.fit`` (a resume read with ``weights_only=True``), with a monitored metric the module never logs
    named as the user's key, and SIGTERM or Ctrl-C as :class:`Interrupted` carrying the resume line."""
    from lightning.fabric.utilities.exceptions import MisconfigurationException
    from lightning.pytorch.utilities.exceptions import SIGTERMException

    from encons.infra.compat import logged_metric_names

    with sigint_as_sigterm() as received:
        try:
            trainer.fit(module, datamodule=data, ckpt_path=resume, weights_only=True)
        except SIGTERMException:
            name = "SIGINT" if received else "SIGTERM"
            raise Interrupted(
                resume_line(cfg, request, trainer.current_epoch, name), status=130 if received else 143
            ) from None
        except MisconfigurationException as err:
            names = logged_metric_names(err)
            if names is None:
                raise
            raise ConfigError(
                f"optimized_metric={cfg.optimized_metric!r} is not a metric this run logs; allowed: {', '.join(names)}"
            ) from None


def resume_line(cfg: DictConfig, request: Request, epoch: int, name: str = "SIGTERM") -> str:
    """What an interrupted fit says: where it stopped and the command that continues it in the same folder."""
    run_dir = Path(cfg.paths.output_dir)
    last = run_dir / "checkpoints" / "last.ckpt"
    given = list(request.overrides)
    kept = [o for o in given if not o.lstrip("+~").startswith(("ckpt_path=", "hydra.run.dir="))]
    if not last.is_file():
        return f"{name} during fit, epoch {epoch + 1}, before the first checkpoint; start again: " + shlex.join(
            ["python", "-m", "encons.train", *given]
        )
    return (
        f"{name} during fit, epoch {epoch + 1} (checkpoints/last.ckpt holds the last whole epoch); resume: "
        + shlex.join(["python", "-m", "encons.train", *kept, f"ckpt_path={last}", f"hydra.run.dir={run_dir}"])
    )
