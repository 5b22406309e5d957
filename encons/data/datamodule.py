"""LightningDataModule: simulate or load trajectories, serve them in the model's chart.

Training yields windows of ``chunk_len`` states, drawn from ``(seed, epoch)`` so a resumed run sees the
same windows as an uninterrupted one: ``windows="random"``, one per trajectory per epoch at a random
start; ``"all"``, every window of every trajectory once per epoch, shuffled (a pass over all states, as a
dataset of samples would make it; n_steps + 2 − chunk_len times the steps per epoch).
Validation yields fixed windows, ``val_batch_size`` per batch (null: all of them in one batch; the validation loss is
their mean either way, so it only sets how many rollouts run side by side); test yields whole trajectories. Noise (σ =
``noise``) is added to training states only: validation and test compare rollouts with the clean simulated trajectories
(for a loaded file, with what the file holds), so the validation error that sweeps, pruners and the best checkpoint
steer by sees the model, not the noise floor. Batches are dicts: ``states`` (B, T, 2n); ``u`` (B, T, m), the inputs of
each step, when the system takes inputs; ``obs`` (B, T, H, W), frames of the same times, when the system renders frames
(``System.frame_shape``; rendered once and cached beside the states) or the file holds them; and for
``objective="derivative"`` (Lim & Kasim eq. (2)) or ``"acceleration"`` (Xiao et al. §3) ``rates``: ds/dt, the true field
at the clean simulated states (the authors' protocol), or central differences of the observed states for loaded data
(second order, one-sided at trajectory ends; so q̈ comes from the recorded q̇). A loaded recording (``.npz`` or
delimited text, one or several trials) is cut by time as ``encons.data.recording`` says (options ``recording``:
``encons.data.recording.OPTIONS``). An epoch is ceil(n_train / batch_size) optimiser steps with ``windows="random"``,
ceil(n_train × windows per trajectory / batch_size) with ``"all"`` (logged at setup): with a small file and ``"random"``
that may be one step, so budget such runs with ``trainer.max_steps`` or use ``"all"``.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any

import lightning.pytorch as pl
import torch
from torch import Tensor
from torch.func import jvp
from torch.utils.data import DataLoader, Dataset, Sampler

from encons.data import store
from encons.data.recording import checked_options, is_recording, load_recording
from encons.data.simulate import sample_trajectories
from encons.infra.bounds import Declared, NonNegative, Positive, Range, Seed
from encons.infra.errors import ConfigError, DataError
from encons.infra.progress import Progress
from encons.systems.base import System

log = logging.getLogger(__name__)
Size = Annotated[int, Range(ge=1)]


class Windows(Dataset):
    """Windows ``array[i, start : start + length]`` of every array (states, inputs, rates), addressed
    by ``(i, start)`` pairs; a batch is a dict of (B, length, ...) tensors."""

    def __init__(self, arrays: dict[str, Tensor], length: int):
        self.arrays, self.length = arrays, length
        self.offsets = torch.arange(length)

    def __len__(self) -> int:
        return self.arrays["states"].shape[0]

    def __getitems__(self, index: list[tuple[int, int]]) -> dict[str, Tensor]:
        traj, start = torch.tensor(index).T
        at = (traj[:, None], start[:, None] + self.offsets)
        return {key: array[at] for key, array in self.arrays.items()}


WINDOWS = ("random", "all")


class WindowSampler(Sampler):
    """``(trajectory, start)`` pairs drawn from ``(seed, epoch)``: a pass over trajectories (shuffled unless
    ``shuffle`` is false) with random window starts, or with ``every``, every (trajectory, start) pair once."""

    def __init__(self, n_traj: int, n_starts: int, seed: int, shuffle: bool = True, every: bool = False):
        self.n_traj, self.n_starts, self.seed, self.shuffle, self.every = n_traj, n_starts, seed, shuffle, every
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        return self.n_traj * (self.n_starts if self.every else 1)

    def __iter__(self):
        gen = torch.Generator().manual_seed(self.seed * 1_000_003 + (self.epoch if self.shuffle else 0))
        n = len(self)
        order = torch.randperm(n, generator=gen) if self.shuffle else torch.arange(n)
        if self.every:
            return iter(zip((order // self.n_starts).tolist(), (order % self.n_starts).tolist()))
        starts = torch.randint(self.n_starts, (self.n_traj,), generator=gen)
        return iter(zip(order.tolist(), starts[order].tolist()))


def _identity(batch: Any) -> Any:  # Windows.__getitems__ makes the batch (dict[str, Tensor]); DataLoader types it list
    return batch


def _known_windows(values: Mapping[str, Any], key: str) -> None:
    if values["windows"] not in WINDOWS:
        raise ConfigError(f"{key}.windows={values['windows']!r}; allowed: {', '.join(WINDOWS)}")


def _test_steps_cover_n_steps(values: Mapping[str, Any], key: str) -> None:
    test_steps, n_steps = values["test_steps"], values["n_steps"]
    if test_steps is not None and test_steps < n_steps:
        raise ConfigError(
            f"{key}.test_steps={test_steps} is shorter than {key}.n_steps={n_steps}; allowed: "
            f"null (= n_steps) or an integer >= {n_steps}"
        )


def _chunk_len_fits(values: Mapping[str, Any], key: str) -> None:
    n_steps = values["n_steps"]
    chunk_len = n_steps + 1 if values["chunk_len"] is None else values["chunk_len"]  # null: a whole trajectory
    if not 2 <= chunk_len <= n_steps + 1:
        raise ConfigError(f"{key}.chunk_len={chunk_len}; allowed: [2, n_steps + 1 = {n_steps + 1}]")


def _recording_options(values: Mapping[str, Any], key: str) -> None:
    """A recording's options (``encons.data.recording.checked_options``), before any data: one line, e.g.
    resample=maybe."""
    if values["path"] is not None:
        checked_options(dict(values["recording"] or {}), values["test_steps"] or values["n_steps"])


class TrajectoryDataModule(pl.LightningDataModule, Declared):
    """Trajectories of ``system`` served in ``chart``; simulated and cached, or read from ``path``."""

    config_key = "data"
    rules = (_known_windows, _test_steps_cover_n_steps, _chunk_len_fits, _recording_options)

    def __init__(
        self,
        system: System,
        chart: str,
        system_config: dict | None = None,
        path: str | None = None,
        n_train: Size = 800,
        n_val: Annotated[int, Range(ge=0)] = 100,
        n_test: Size = 100,
        n_steps: Size = 100,
        test_steps: int | None = None,
        dt: Positive = 0.03,
        noise: NonNegative = 0.01,
        substeps: Size = 10,
        chunk_len: int | None = 5,
        batch_size: Size = 200,
        val_batch_size: Size | None = None,
        seed: Seed = 0,
        cache_dir: str = ".cache/encons",
        objective: str | None = "rollout",
        recording: dict | None = None,
        windows: str = "random",
    ):
        super().__init__()  # the values were checked against the ranges and ``rules`` (encons.infra.bounds.Declared)
        chunk_len = n_steps + 1 if chunk_len is None else chunk_len  # null: a window is a whole trajectory
        system.check_chart(chart)
        self.system, self.chart, self.path = system, chart, path
        self.sizes = {"train": n_train, "val": n_val, "test": n_test}
        self.n_steps, self.dt, self.noise, self.substeps = n_steps, dt, noise, substeps
        self.test_steps = test_steps or n_steps
        self.chunk_len, self.batch_size, self.seed = chunk_len, batch_size, seed
        self.val_batch_size = val_batch_size  # None: every validation window in one batch
        self.windows = windows
        self.objective, self.recording = objective, dict(recording or {})
        gen_config = dict(
            system=system_config or {"name": system.name},
            sizes=self.sizes,
            n_steps=n_steps,
            test_steps=self.test_steps,
            dt=dt,
            substeps=substeps,
            seed=seed,
        )
        self.cache_file = Path(cache_dir) / f"{system.name}-{store.config_hash(gen_config)}.npz"

    def prepare_data(self) -> None:
        if self.path is None and not self.cache_file.exists():
            gen = torch.Generator().manual_seed(self.seed)
            splits, inputs = {}, {}
            steps_of = {name: self.test_steps if name == "test" else self.n_steps for name in self.sizes}
            progress = Progress(
                sum(1 for n in self.sizes.values() if n),
                f"simulating {self.system.name}: split",
                log,
                work=sum(n * steps_of[k] for k, n in self.sizes.items()),
            )
            for name, n in self.sizes.items():
                if n:
                    steps = steps_of[name]
                    progress.start(f"{name}, {n} trajectories × {steps} steps", n * steps)
                    t = torch.arange(steps + 1, dtype=torch.float64) * self.dt
                    splits[name], u, rejected = sample_trajectories(self.system, n, t, gen, self.substeps)
                    if u is not None:
                        inputs[name] = u
                    if rejected:
                        log.info(
                            "%s: redrew %d of %d %s trajectories (%s)",
                            self.system.name,
                            rejected,
                            n,
                            name,
                            getattr(self.system, "rejection_reason", "invalid"),
                        )
            frames = (
                {name: self.system.render(traj, self.system.base_chart) for name, traj in splits.items()}
                if self.system.frame_shape
                else None
            )
            store.save(self.cache_file, t[: self.n_steps + 1], splits, self.system.base_chart, inputs, frames)
            progress.done()
            log.info("simulated %s into %s", self.system.name, self.cache_file)

    def setup(self, stage: str | None = None) -> None:
        if hasattr(self, "t"):
            return
        source = Path(self.path) if self.path is not None else self.cache_file
        inputs = None
        try:
            if self.path is not None and is_recording(source):
                t, splits, chart, inputs = load_recording(
                    source, self.n_steps, self.test_steps, self.recording, self.system.n_controls, checked=True
                )
            else:
                t, splits, chart = store.load(source)
        except DataError as err:
            if self.path is not None:
                raise
            log.warning("encons: the cache file is damaged, rebuilding it (%s)", err)
            self.cache_file.unlink(missing_ok=True)
            self.prepare_data()
            t, splits, chart = store.load(source)
        chart = chart or self.system.base_chart
        if chart not in self.system.charts:
            raise DataError(
                f"data file {str(source)!r} holds chart {chart!r}; allowed: the charts of system "
                f"'{self.system.name}', {', '.join(self.system.charts)}"
            )
        width = 2 * self.system.coord_dim(chart)
        for name, arr in splits.items():
            if arr.shape[-1] != width:
                raise DataError(
                    f"data file {str(source)!r}: '{name}' has {arr.shape[-1]} state entries; "
                    f"allowed: {width}, the {chart} chart of '{self.system.name}'"
                )
        frames = {}
        if inputs is None:
            inputs = store.load_inputs(source, splits, self.system.n_controls)
            frames = store.load_observations(source, splits)
        if "val" not in splits:
            n_val = max(1, splits["train"].shape[0] // 10)
            for arrays in (splits, inputs, frames):
                if "train" in arrays:
                    arrays["val"], arrays["train"] = arrays["train"][:n_val], arrays["train"][n_val:]
        self.t = t
        self.dt = float(t[1] - t[0])
        gen = torch.Generator().manual_seed(self.seed + 1)
        served = {k: self.system.to_chart(v, chart, self.chart) for k, v in splits.items()}
        served["train"] = served["train"] + self.noise * torch.randn(
            served["train"].shape, generator=gen, dtype=torch.float64
        )
        # test states stay float64: the evaluation (encons.numerics.evaluation) scores errors down to ~1e-8
        self.arrays = {k: {"states": v if k == "test" else v.float()} for k, v in served.items()}
        for name, u in inputs.items():
            self.arrays[name]["u"] = u.float()
        for name, obs in frames.items():
            self.arrays[name]["obs"] = obs
        if self.objective in ("derivative", "acceleration"):  # validation too: validation.criterion=objective
            for name in ("train", "val"):
                self.arrays[name]["rates"] = self._rates(splits[name], chart, served[name], inputs.get(name)).float()
        if self.chunk_len > len(t):
            raise DataError(
                f"data.chunk_len={self.chunk_len} exceeds the {len(t)} states per trajectory; allowed: 2..{len(t)}"
            )
        for name in ("train", "val"):
            if self.arrays[name]["states"].shape[0] == 0:
                raise DataError(
                    f"data file {str(source)!r} leaves no {name} trajectories (train holds "
                    f"{splits['train'].shape[0] + splits['val'].shape[0]} in all, 1 in 10 held out for "
                    f"validation); allowed: >= 2 train trajectories, or a 'val' array"
                )

        n_train = self.arrays["train"]["states"].shape[0]
        every = self.windows == "all"
        n_windows = len(self._sampler("train", True))
        log.info(
            "train: %s in batches of %d: %d optimiser step(s) per epoch%s",
            f"every window of {n_train} trajectories ({n_windows})" if every else f"{n_train} trajectories",
            self.batch_size,
            -(-n_windows // self.batch_size),
            " (a file: budget training with trainer.max_steps, or data.windows=all)"
            if self.path is not None and not every
            else "",
        )

    @property
    def states(self) -> dict[str, Tensor]:
        """The served states of each split (float32, test float64; noisy where noise applies)."""
        return {name: arrays["states"] for name, arrays in self.arrays.items()}

    def _rates(self, clean: Tensor, chart: str, observed: Tensor, u: Tensor | None) -> Tensor:
        """ds/dt of the training states in the served chart, float64 (see the module docstring)."""
        if self.path is None and self.system.known_physics:
            field = self.system.field(clean, chart, u)
            return jvp(lambda s: self.system.to_chart(s, chart, self.chart), (clean,), (field,))[1]
        return torch.gradient(observed, spacing=self.dt, dim=1, edge_order=2)[0]

    def _sampler(self, split: str, shuffle: bool) -> WindowSampler:
        n, steps = self.arrays[split]["states"].shape[:2]
        every = shuffle and self.windows == "all"  # validation keeps its fixed windows
        return WindowSampler(n, steps - self.chunk_len + 1, self.seed, shuffle, every)

    def _windows(self, split: str, shuffle: bool, batch_size: int) -> DataLoader:
        return DataLoader(
            Windows(self.arrays[split], self.chunk_len),
            sampler=self._sampler(split, shuffle),
            batch_size=batch_size,
            collate_fn=_identity,
        )

    def train_dataloader(self) -> DataLoader:
        return self._windows("train", True, self.batch_size)

    def val_dataloader(self) -> DataLoader:
        return self._windows("val", False, self.val_batch_size or len(self._sampler("val", False)))

    def test_dataloader(self) -> DataLoader:
        arrays = self.arrays["test"]
        n, steps = arrays["states"].shape[:2]
        return DataLoader(
            Windows(arrays, steps), sampler=[(i, 0) for i in range(n)], batch_size=n, collate_fn=_identity
        )
