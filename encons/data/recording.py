"""One long measured recording, cut into train / validation / test trajectories (``system=from_file``).

A recording file is an ``.npz`` with

    t       (T,)     increasing times, one step dt apart except where samples were dropped
    states  (T, 2n)  states (q, q̇) at those times
    chart   string   optional, e.g. "angle" (default)
    u       (T, m)   optional inputs per sample (``u[k]`` acts from t_k to t_{k+1})

How it is cut (``load_recording``):

1. dt is the median step. A step longer than ``gap`` × dt (dropped samples) is a gap: it splits
   the recording into unbroken stretches; any other step must equal dt to 1e-6 (else refused).
2. Coordinates marked in ``angles`` are unwrapped inside each stretch (``numpy.unwrap``: each
   step taken as the one of least magnitude, so |Δq| < π per sample is assumed), so that wrapped
   recordings (angles in [−π, π)) and unwrapped ones give continuous trajectories.
3. By time: the last ``test_fraction`` of the span [t_0, t_end] is the test set, the
   ``val_fraction`` before it validation, the rest training; a boundary splits a stretch too.
4. Each piece is cut into consecutive trajectories of ``n_steps + 1`` samples (``test_steps + 1``
   for test), neighbours sharing their boundary sample, so every step (k, k+1) inside a piece is
   in exactly one trajectory; the samples after a piece's last whole trajectory are unused
   (logged). Training windows of ``data.chunk_len`` are drawn inside these trajectories, never
   across a gap or a split boundary.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from encons.errors import ConfigError, DataError
from encons.io import save_npz

log = logging.getLogger(__name__)


def is_recording(path: str | Path) -> bool:
    """Whether ``path`` is an ``.npz`` holding a recording (a ``states`` key) rather than split trajectories."""
    try:
        with np.load(path, allow_pickle=False) as f:
            return "states" in f.files and "train" not in f.files
    except Exception:  # noqa: BLE001 - not a readable archive: the split-file loader reports it
        return False


def wrap(states: Tensor, angles: list[bool]) -> Tensor:
    """States with the marked coordinates wrapped into [−π, π)."""
    mask = _angle_mask(angles, states.shape[-1])
    return torch.where(mask, torch.remainder(states + math.pi, 2 * math.pi) - math.pi, states)


def unwrap(states: Tensor, angles: list[bool]) -> Tensor:
    """States (T, 2n) of one unbroken stretch with the marked coordinates made continuous in time."""
    mask = _angle_mask(angles, states.shape[-1])
    return torch.where(mask, torch.from_numpy(np.unwrap(states.numpy(), axis=0)).to(states), states)


def _angle_mask(angles: list[bool], width: int) -> Tensor:
    return torch.tensor(list(angles) + [False] * (width - len(angles)))


def _angles(angles: bool | list[bool] | None, n: int) -> list[bool]:
    if angles is None or isinstance(angles, bool):
        return [bool(angles)] * n
    if not isinstance(angles, (list, tuple)) or len(angles) != n or not all(isinstance(a, bool) for a in angles):
        raise ConfigError(f"data.recording.angles={angles!r}; allowed: null, true, false or {n} booleans "
                          f"(one per coordinate q)")
    return list(angles)


def describe(path: str | Path) -> tuple[int, str | None, int]:
    """The coordinate count n, the chart (or None) and the input width m of a recording file."""
    t, states, chart, u = _read(Path(path))
    return states.shape[1] // 2, chart, 0 if u is None else u.shape[1]


def _read(path: Path) -> tuple[np.ndarray, np.ndarray, str | None, np.ndarray | None]:
    with np.load(path, allow_pickle=False) as f:
        arrays = {k: f[k] for k in f.files}
    missing = [k for k in ("t", "states") if k not in arrays]
    if missing:
        raise DataError(f"recording {str(path)!r} lacks {missing}; allowed: t (T,) and states (T, 2n)")
    t, states, u = (np.asarray(arrays[k], dtype=np.float64) if k in arrays else None for k in ("t", "states", "u"))
    if t.ndim != 1 or len(t) < 3 or states.shape[:1] != t.shape or states.ndim != 2 or states.shape[1] % 2:
        raise DataError(f"recording {str(path)!r}: t has shape {t.shape}, states {states.shape}; allowed: "
                        f"t (T,) with T >= 3 and states (T, 2n) states (q, q̇)")
    if u is not None and (u.ndim != 2 or len(u) != len(t)):
        raise DataError(f"recording {str(path)!r}: u has shape {u.shape}; allowed: ({len(t)}, m) inputs per sample")
    for name, arr in (("t", t), ("states", states), ("u", u)):
        if arr is not None and not np.isfinite(arr).all():
            raise DataError(f"recording {str(path)!r}: '{name}' contains NaN or inf; allowed: finite values "
                            f"(drop a bad sample with its time: the gap is handled)")
    if not (np.diff(t) > 0).all():
        raise DataError(f"recording {str(path)!r}: 't' is not increasing; allowed: increasing times")
    return t, states, (str(arrays["chart"]) if "chart" in arrays else None), u


OPTIONS = {"test_fraction": 0.2, "val_fraction": 0.1, "angles": None, "gap": 1.5}


def load_recording(path: str | Path, n_steps: int, test_steps: int, options: dict | None = None,
                   n_controls: int = 0) -> tuple[Tensor, dict[str, Tensor], str | None, dict[str, Tensor]]:
    """Cut a recording as the module docstring says, with ``options`` (keys and defaults: ``OPTIONS``);
    returns the times of a training trajectory (n_steps + 1,), the splits {train, val, test}
    (N, L, 2n), the chart and the inputs per split (N, L, m) (empty when ``n_controls`` is 0)."""
    path = Path(path)
    unknown = sorted(set(options or {}) - set(OPTIONS))
    if unknown:
        raise ConfigError(f"data.recording.{unknown[0]} is not an option; allowed: {', '.join(OPTIONS)}")
    opts = {**OPTIONS, **(options or {})}
    test_fraction, val_fraction, angles, gap = (opts[k] for k in OPTIONS)
    if not (0 < test_fraction < 1 and 0 < val_fraction < 1 and test_fraction + val_fraction < 1):
        raise ConfigError(f"data.recording.test_fraction={test_fraction}, val_fraction={val_fraction}; allowed: "
                          f"both in (0, 1) with a sum < 1")
    if not gap > 1:
        raise ConfigError(f"data.recording.gap={gap}; allowed: > 1 (steps longer than gap × dt split the recording)")
    t, states, chart, u = _read(path)
    if n_controls and (u is None or u.shape[1] != n_controls):
        raise DataError(f"recording {str(path)!r} holds no inputs u of width {n_controls}; allowed: u ({len(t)}, {n_controls})")
    steps = np.diff(t)
    dt = float(np.median(steps))
    broken = steps > gap * dt
    if not np.allclose(steps[~broken], dt, rtol=1e-6, atol=0):
        worst = steps[~broken][np.argmax(np.abs(steps[~broken] - dt))]
        raise DataError(f"recording {str(path)!r}: a step of {worst:.6g} beside dt = {dt:.6g} (the median); allowed: "
                        f"steps of dt, or gaps longer than data.recording.gap={gap} × dt")
    mask = _angles(angles, states.shape[1] // 2)
    cuts = np.concatenate([[0], np.flatnonzero(broken) + 1, [len(t)]])
    states_t = torch.from_numpy(states)
    stretches = [unwrap(states_t[a:b], mask) for a, b in zip(cuts[:-1], cuts[1:])]
    unwrapped = torch.cat(stretches)  # row k: sample k
    span = t[-1] - t[0]
    bounds = {"train": (-np.inf, t[0] + (1 - test_fraction - val_fraction) * span),
              "val": (t[0] + (1 - test_fraction - val_fraction) * span, t[0] + (1 - test_fraction) * span),
              "test": (t[0] + (1 - test_fraction) * span, np.inf)}
    splits, inputs, unused = {}, {}, {}
    for name, (lo, hi) in bounds.items():
        length = (test_steps if name == "test" else n_steps) + 1
        index, unused[name] = [], 0
        for a, b in zip(cuts[:-1], cuts[1:]):
            inside = np.flatnonzero((t[a:b] >= lo) & (t[a:b] < hi)) + a
            count = (len(inside) - 1) // (length - 1) if len(inside) else 0
            index += [inside[0] + i * (length - 1) + np.arange(length) for i in range(count)]
            unused[name] += len(inside) - (count * (length - 1) + 1 if count else 0)
        if not index:
            raise DataError(f"recording {str(path)!r}: its {name} part holds no unbroken stretch of {length} samples; "
                            f"allowed: a smaller data.{'test_steps' if name == 'test' else 'n_steps'} or a larger "
                            f"share of it (data.recording.test_fraction, val_fraction) or a longer recording")
        rows = torch.from_numpy(np.stack(index))
        splits[name] = unwrapped[rows]
        if n_controls:
            inputs[name] = torch.from_numpy(u)[rows]
    log.info("recording %s: %d samples, dt %.6g, %d gap(s) -> %d stretch(es); trajectories train/val/test %d/%d/%d "
             "of %d/%d/%d samples; %d/%d/%d samples unused (stretch ends)", path.name, len(t), dt, int(broken.sum()),
             len(stretches), *(splits[k].shape[0] for k in bounds), n_steps + 1, n_steps + 1, test_steps + 1,
             *unused.values())
    return torch.arange(n_steps + 1, dtype=torch.float64) * dt, splits, chart, inputs


def write_example(path: str | Path, duration: float = 60.0, dt: float = 0.02,
                  dropped: tuple[tuple[int, int], ...] = ((700, 3), (1500, 1), (2200, 10))) -> Path:
    """Write the README's worked example: one ``duration``-second recording of the compound pendulum
    (Xiao et al. eq. (12)) with light axle friction (γ₁ = γ₂ = 0.05, so it winds over the top for
    about 30 s, then swings), sampled every ``dt``, with the samples ``dropped`` ((first, count) pairs)
    missing and both angles wrapped into [−π, π), as a measurement would give them. Simulated by RK4
    at dt / 2 (one long trajectory is sequential; finer steps only cost time for a stand-in measurement)."""
    from encons.data.simulate import simulate
    from encons.systems.dissipative import CompoundPendulum

    t = torch.arange(round(duration / dt) + 1, dtype=torch.float64) * dt
    states = simulate(CompoundPendulum(gamma1=0.05, gamma2=0.05),
                      torch.tensor([[0.5, -0.5, 2.0, 12.0]], dtype=torch.float64), t, substeps=2)[0]
    keep = torch.ones(len(t), dtype=torch.bool)
    for first, count in dropped:
        keep[first:first + count] = False
    return save_npz(path, t=t[keep].numpy(), states=wrap(states[keep], [True, True]).numpy(), chart="angle")


if __name__ == "__main__":
    import sys

    if len(sys.argv) != 2:
        sys.exit("usage: python -m encons.data.recording OUT.npz   (writes the README's example recording)")
    print(f"wrote {write_example(sys.argv[1])}")
