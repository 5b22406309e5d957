"""A system known only through a user's trajectory file: one chart, no true physics.

The file holds split trajectories (``encons.data.store``) or a recording (``.npz`` or delimited
text), which the data module cuts by time (``encons.data.recording``). Energy metrics and
physics-structured models that need constraints are unavailable; the error metrics are computed in
the file's chart.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from encons.data import store
from encons.data.recording import describe, is_recording, recording_angles
from encons.systems.base import DataOnlySystem


class FileSystem(DataOnlySystem):
    """Dimensions and chart read from a file: split trajectories (``encons.data.store``) or a
    recording (``encons.data.recording``; a text one read through ``columns``, ``delimiter`` and ``comment``).
    ``angles`` marks the coordinates q that are angles (``data.recording.angles``: null/false none, true
    all, or one boolean per coordinate): metrics compare them on the circle (``encons.numerics.metrics``)."""

    def __init__(
        self,
        path: str,
        chart: str | None = None,
        columns: dict | None = None,
        delimiter: str | None = None,
        comment: str | None = "#",
        angles: bool | list[bool] | None = None,
    ):
        self.name = "from_file"
        if is_recording(path):
            self.n, file_chart, self.n_controls = describe(path, columns, delimiter, comment)
        else:
            t, splits, file_chart = store.load(path)
            self.n = splits["train"].shape[-1] // 2
            with np.load(path, allow_pickle=False) as f:  # inputs, if any: checked in full by the data module
                self.n_controls = int(f["u_train"].shape[-1]) if "u_train" in f.files else 0
        self.charts = (chart or file_chart or "angle",)
        self.common_chart = self.charts[0]
        marked = recording_angles(angles, self.n)
        self.angles = tuple(marked) if any(marked) else None

    def angle_entries(self, chart: str) -> Tensor | None:
        """The ``angles`` of the file's one chart, whatever its name."""
        return None if self.angles is None else torch.tensor([*self.angles, *(False,) * self.n])

    def units(self, chart: str) -> tuple[str, ...]:
        """rad for the coordinates marked as angles, else the file's own unit (a rate's: per time unit)."""
        return tuple("rad" if a else "file unit" for a in (self.angles or (False,) * self.n))
