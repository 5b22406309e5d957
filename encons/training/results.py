"""What training returns: a :class:`Run` (one model, its weights and metrics) and an :class:`Ensemble` (one Run
per seed, with the members' mean and spread), the ensemble folder's member list, and the spread line."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from omegaconf import DictConfig

if TYPE_CHECKING:
    from encons.config.check import Checked
    from encons.data.datamodule import TrajectoryDataModule
    from encons.training.module import TrainingModule


@dataclass
class Run:
    """A trained or loaded run: the module (holding the weights of ``checkpoint``), its data and config."""

    module: TrainingModule
    data: TrajectoryDataModule
    config: DictConfig
    run_dir: Path
    checkpoint: Path | None = None  # None: the in-memory weights (no checkpoint was kept)
    metrics: dict[str, float] = field(default_factory=dict)
    checked: Checked | None = field(default=None, repr=False)  # its validated config (train, load)

    @property
    def model(self):
        """The trained ``DynamicsModel`` (roll it out with ``encons.rollout``)."""
        return self.module.model


MEMBERS_FILE = "members.json"  # in an ensemble's folder: its seeds and member folders (relative), for load/evaluate


@dataclass
class Ensemble:
    """A trained ensemble: one :class:`encons.training.runs.Run` per member (in ``seeds`` order; a diverged member's
    ``checkpoint`` is None and its ``metrics`` empty), the seeds that ``diverged`` (seed -> why), the
    ``metrics`` over members (mean, ``_sd``, ``_min``, ``_max``) and the run folder; ``path`` says how the
    members were stepped (``stacked`` or ``loop``, and why not stacked); ``wall_time_s`` is the whole ensemble's
    (training, every member's test, and the segments before the checkpoint it resumed from)."""

    members: list[Run]
    seeds: list[int]
    diverged: dict[int, str]
    metrics: dict[str, float]
    run_dir: Path
    path: str = "loop"
    member_metrics: dict[int, dict[str, float]] = field(default_factory=dict)
    wall_time_s: float = 0.0


def member_folders(path: Path) -> tuple[list[int], list[Path]] | None:
    """The seeds and member folders of the ensemble folder ``path`` (its ``members.json``); None: not one."""
    file = path / MEMBERS_FILE
    if not file.is_file():
        return None
    listed = json.loads(file.read_text())
    return [int(s) for s in listed["seeds"]], [path / p for p in listed["members"]]


#: The headline metrics of an ensemble's spread line, the first present
HEADLINE = ("test/traj_rel_err", "test/geom_rel_err", "test/accel_mse", "test/state_mse", "val/loss")


def spread_line(metrics: dict[str, float], members: int) -> str:
    """The headline metric as mean ± sample std over the members (mean alone where one member remains or the
    spread is below float rounding of the mean)."""
    key = next((k for k in HEADLINE if k in metrics), None)
    if key is None:
        return f"mean over {members} members"
    mean, sd = metrics[key], metrics.get(f"{key}_sd", 0.0)
    if members < 2 or sd <= 1e-12 * abs(mean):
        return f"{key.removeprefix('test/')} {mean:.4g} (mean over {members} member{'s' * (members != 1)}, no spread)"
    return (
        f"{key.removeprefix('test/')} {mean:.4g} ± {sd:.2g} (mean ± sample std over {members} members, "
        f"min {metrics[key + '_min']:.4g}, max {metrics[key + '_max']:.4g})"
    )


def mean_and_sd(values: list[float]) -> tuple[float, float]:
    """The mean and sample standard deviation (0 for one value) of ``values`` (at least one); inf, not an error,
    where a value is past the float range's square root (a diverged rollout's metric, ~1e164 and beyond)."""
    mean = sum(values) / len(values)
    # (v − mean)·(v − mean), not ** 2: a float's square past its range is inf, its power an OverflowError
    return mean, math.sqrt(sum((v - mean) * (v - mean) for v in values) / max(1, len(values) - 1))


def summarise(per_member: dict[int, dict[str, float]]) -> dict[str, float]:
    """Mean, sample std (``_sd``), ``_min`` and ``_max`` over members of every metric they share."""
    out: dict[str, float] = {}
    keys = dict.fromkeys(k for m in per_member.values() for k in m)
    for key in keys:
        values = [m[key] for m in per_member.values() if key in m]
        if not values:
            continue
        out[key], out[f"{key}_sd"] = mean_and_sd(values)
        out[f"{key}_min"], out[f"{key}_max"] = min(values), max(values)
    return out
