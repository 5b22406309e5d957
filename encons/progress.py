"""Progress lines for long loops (simulation splits, benchmark runs)."""

from __future__ import annotations

import logging
import sys
import time


class Progress:
    """``<what> k of n (label), elapsed, ETA`` lines for a loop over items of known relative cost.

    Lines go to ``log`` at INFO if given (the run's console and log file), else to stderr.
    """

    def __init__(self, items: int, what: str, log: logging.Logger | None = None, work: float | None = None):
        self.items, self.what, self.log = items, what, log
        self.total = float(items if work is None else work)  # the ETA assumes work proceeds at one rate
        self.done_work, self.count, self.started = 0.0, 0, time.perf_counter()

    def start(self, label: str, work: float = 1.0) -> None:
        """Item ``label`` begins; ``work`` is its cost in the units of ``work`` (one item by default)."""
        elapsed = time.perf_counter() - self.started
        eta = (f", ETA {_duration(elapsed / self.done_work * (self.total - self.done_work))}"
               if self.done_work else "")
        self.count += 1
        self.done_work += work
        self._say(f"{self.what} {self.count} of {self.items} ({label}), elapsed {_duration(elapsed)}{eta}")

    def done(self) -> None:
        self._say(f"{self.what} {self.count} of {self.items} done in {_duration(time.perf_counter() - self.started)}")

    def _say(self, line: str) -> None:
        if self.log is not None:
            self.log.info(line)
        else:
            print(line, file=sys.stderr, flush=True)


def _duration(seconds: float) -> str:
    minutes, secs = divmod(int(seconds), 60)
    return f"{minutes // 60}h{minutes % 60:02d}m" if minutes >= 60 else f"{minutes}m{secs:02d}s"
