"""The on-disk trajectory format (``.npz``), shared by the simulation cache and user data.

Keys: ``t`` (T,) times, equally spaced; ``train``, ``val`` (optional), ``test`` arrays of
shape (N, T, 2n) holding states ``(q, q̇)`` sampled at ``t`` (``test`` may run longer, at the
same spacing); ``chart`` a string naming their chart. Controlled systems add ``u_train``,
``u_val``, ``u_test``: the inputs of each trajectory, (N, m) constant over the trajectory or
(N, T, m) per step (``u[:, k]`` acts from ``t_k`` to ``t_{k+1}``; the last entry is unused).
Systems observed by pixels add ``obs_train``, ``obs_val``, ``obs_test``: grey-scale frames (N, T, H, W)
of the same trajectories at the same times (any real dtype, e.g. float in [0, 1]; uint8 is read as
/255), the states beside them holding the truth the metrics compare with.
Files are written to a temporary name and renamed, so a half-written file is never read.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from encons.infra.errors import DataError
from encons.infra.io import save_npz

SPLITS = ("train", "val", "test")


def config_hash(config: dict) -> str:
    """A short stable hash of a JSON-serialisable generating config."""
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).hexdigest()[:16]


def save(
    path: Path,
    t: Tensor,
    splits: dict[str, Tensor],
    chart: str,
    inputs: dict[str, Tensor] | None = None,
    observations: dict[str, Tensor] | None = None,
) -> None:
    """Write trajectories (and their inputs and frames per split, if any) atomically (``encons.infra.io``)."""
    arrays = {k: v.numpy() for k, v in splits.items()}
    arrays.update({f"u_{k}": v.numpy() for k, v in (inputs or {}).items()})
    arrays.update({f"obs_{k}": v.numpy() for k, v in (observations or {}).items()})
    save_npz(path, t=t.numpy(), chart=np.array(chart), **arrays)


def load(path: str | Path) -> tuple[Tensor, dict[str, Tensor], str | None]:
    """Read and check a trajectory file; raise ``DataError`` naming what is wrong and how to fix it.

    Returns the times, the state splits and the chart; ``load_inputs`` reads the inputs."""
    path = Path(path)
    if not path.is_file():
        what = "is a folder" if path.is_dir() else "does not exist"
        raise DataError(f"system.path={str(path)!r} {what}; allowed: an .npz file (docs/data.md)")
    try:
        with np.load(path, allow_pickle=False) as f:
            arrays = {k: f[k] for k in f.files}
    except Exception as err:  # numpy raises several types for a corrupt archive
        raise DataError(
            f"data file {str(path)!r} is not a readable .npz archive ({err}); allowed: an .npz written by numpy.savez"
        ) from None
    missing = [k for k in ("t", "train", "test") if k not in arrays]
    if missing:
        raise DataError(
            f"data file {str(path)!r} lacks key(s) {missing}; allowed: a file with t, train, test (val optional)"
        )
    t = torch.from_numpy(np.asarray(arrays["t"], dtype=np.float64))
    if t.ndim != 1 or len(t) < 2 or not bool((t.diff() > 0).all()):
        raise DataError(
            f"data file {str(path)!r}: 't' has shape {tuple(t.shape)} or is not increasing; "
            f"allowed: 1-D, increasing, >= 2 times"
        )
    if not torch.allclose(t.diff(), t.diff()[0].expand(len(t) - 1), rtol=1e-6, atol=1e-9):
        raise DataError(f"data file {str(path)!r}: 't' is not equally spaced; allowed: equally spaced times")
    splits = {}
    for name in SPLITS:
        if name not in arrays:
            continue
        arr = arrays[name]
        too_short = arr.ndim == 3 and (arr.shape[1] < len(t) if name == "test" else arr.shape[1] != len(t))
        if arr.ndim != 3 or too_short or arr.shape[2] % 2:
            raise DataError(
                f"data file {str(path)!r}: '{name}' has shape {arr.shape}; allowed: (N, {len(t)}, 2n) states (q, q̇)"
            )
        if not np.isfinite(arr).all():
            raise DataError(f"data file {str(path)!r}: '{name}' contains NaN or inf; allowed: finite states")
        splits[name] = torch.from_numpy(np.asarray(arr, dtype=np.float64))
    chart = str(arrays["chart"]) if "chart" in arrays else None
    return t, splits, chart


def load_inputs(path: str | Path, splits: dict[str, Tensor], n_controls: int) -> dict[str, Tensor]:
    """The inputs ``u_<split>`` of a file whose states ``splits`` were read by ``load``, each as
    (N, T, m) per step (constant inputs expanded); empty when ``n_controls`` is 0."""
    if n_controls == 0:
        return {}
    with np.load(path, allow_pickle=False) as f:
        arrays = {k: f[k] for k in f.files if k.startswith("u_")}
    inputs = {}
    for name, states in splits.items():
        key, (n, steps) = f"u_{name}", states.shape[:2]
        if key not in arrays:
            raise DataError(
                f"data file {str(path)!r} lacks '{key}': the system takes {n_controls} input(s); "
                f"allowed: an array (N, {n_controls}) constant per trajectory or (N, T, {n_controls})"
            )
        u = torch.from_numpy(np.asarray(arrays[key], dtype=np.float64))
        if u.ndim == 2 and u.shape == (n, n_controls):
            u = u[:, None].expand(n, steps, n_controls)
        elif not (u.ndim == 3 and u.shape == (n, steps, n_controls)):
            raise DataError(
                f"data file {str(path)!r}: '{key}' has shape {tuple(u.shape)}; allowed: "
                f"({n}, {n_controls}) constant per trajectory or ({n}, {steps}, {n_controls}) per step"
            )
        if not bool(torch.isfinite(u).all()):
            raise DataError(f"data file {str(path)!r}: '{key}' contains NaN or inf; allowed: finite inputs")
        inputs[name] = u
    return inputs


def load_observations(path: str | Path, splits: dict[str, Tensor]) -> dict[str, Tensor]:
    """The frames ``obs_<split>`` of a file whose states ``splits`` were read by ``load``, float32
    (N, T, H, W), one (H, W) for all splits; empty when the file holds none. A file with frames for
    some splits must hold them for every split it has."""
    with np.load(path, allow_pickle=False) as f:
        arrays = {k: f[k] for k in f.files if k.startswith("obs_")}
    if not arrays:
        return {}
    frames, shape = {}, None
    for name, states in splits.items():
        key, (n, steps) = f"obs_{name}", states.shape[:2]
        arr = arrays.get(key)
        if arr is None:
            raise DataError(
                f"data file {str(path)!r} lacks '{key}' beside {sorted(arrays)}; allowed: frames "
                f"(N, T, H, W) for every split it holds"
            )
        if arr.ndim != 4 or arr.shape[:2] != (n, steps) or (shape is not None and arr.shape[2:] != shape):
            raise DataError(
                f"data file {str(path)!r}: '{key}' has shape {arr.shape}; allowed: ({n}, {steps}, H, W) "
                f"frames of the {n} '{name}' trajectories × {steps} times"
                + (f", H × W = {shape[0]} × {shape[1]} as the other splits" if shape else "")
            )
        shape = arr.shape[2:]
        if not np.issubdtype(arr.dtype, np.number) or np.issubdtype(arr.dtype, np.complexfloating):
            raise DataError(f"data file {str(path)!r}: '{key}' has dtype {arr.dtype}; allowed: real numbers")
        values = torch.from_numpy(np.asarray(arr, dtype=np.float32))
        if arr.dtype == np.uint8:
            values = values / 255
        if not bool(torch.isfinite(values).all()):
            raise DataError(f"data file {str(path)!r}: '{key}' contains NaN or inf; allowed: finite frames")
        frames[name] = values
    return frames
