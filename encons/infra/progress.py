"""Progress lines for long loops (simulation splits, epochs, benchmark runs), and lines for the log files only."""

from __future__ import annotations

import logging
import time


class Progress:
    """``<what> k of n (label), elapsed, ETA`` lines for a loop over items of known relative cost.

    Lines go to ``log`` at INFO if given (the run's console and log file), else to stdout, the stream a
    training run's log lines and progress bar use.
    """

    def __init__(self, items: int, what: str, log: logging.Logger | None = None, work: float | None = None):
        self.items, self.what, self.log = items, what, log
        self.total = float(items if work is None else work)  # the ETA assumes work proceeds at one rate
        self.done_work, self.count, self.started = 0.0, 0, time.perf_counter()

    def start(self, label: str, work: float = 1.0, items: int = 1) -> None:
        """Item ``label`` begins (``items`` items at once, e.g. an ensemble's seeds); ``work`` is its cost in the
        units of ``work`` (one item by default)."""
        elapsed = time.perf_counter() - self.started
        eta = f", ETA {duration(elapsed / self.done_work * (self.total - self.done_work))}" if self.done_work else ""
        self.count += items
        self.done_work += work
        self._say(f"{self.what} {self.count} of {self.items} ({label}), elapsed {duration(elapsed)}{eta}")

    def done(self) -> None:
        self._say(f"{self.what} {self.count} of {self.items} done in {duration(time.perf_counter() - self.started)}")

    def _say(self, line: str) -> None:
        if self.log is not None:
            self.log.info(line)
        else:
            print(line, flush=True)


def duration(seconds: float) -> str:
    """``1m05s``, or ``2h03m`` from an hour on."""
    minutes, secs = divmod(int(seconds), 60)
    return f"{minutes // 60}h{minutes % 60:02d}m" if minutes >= 60 else f"{minutes}m{secs:02d}s"


def to_log_files(text: str, level: int = logging.INFO) -> None:
    """Write ``text`` to the file handlers of the root logger only (Hydra's ``<job>.log``), not the console."""
    record = logging.LogRecord("encons", level, __file__, 0, "%s", (text.rstrip(),), None)
    for handler in logging.getLogger().handlers:
        if isinstance(handler, logging.FileHandler) and record.levelno >= handler.level:
            handler.handle(record)
