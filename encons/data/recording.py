"""Measured recordings, cut into train / validation / test trajectories (``system=from_file``).

A recording is an ``.npz`` with

    t       (T,)     increasing times (per trial), one step dt apart except where samples were dropped
    states  (T, 2n)  states (q, q̇) at those times
    chart   string   optional, e.g. "angle" (default)
    u       (T, m)   optional inputs per sample (``u[k]`` acts from t_k to t_{k+1})
    trial   (T,)     optional trial label per sample (several recordings in one file)

or a delimited text file (``.csv``: commas, ``.tsv``: tabs, else whitespace, or ``delimiter``;
``comment``, default ``#``, starts a comment: ``%`` for MATLAB-style files) read through ``columns``, a
mapping {t: COL, q: [COL, ...], qdot: [COL, ...], trial: COL (optional), u: [COL, ...] (optional)}; COL
is a header name or a 0-based column index (every row is then data). The header is the first comment
line when it holds one name per column and the first row holds numbers (``% time theta omega``), else
the first row. Cells are numbers, except the trial column, whose labels may be any text.

How it is cut (``load_recording``), for each trial on its own (a file without trials is one trial):

1. A step longer than ``gap`` × the median step (dropped samples) is a gap: it splits the trial
   into unbroken stretches; dt is the mean of the steps within ``jitter`` of the median. Any other step must lie within
   dt · (1 ± ``jitter``) (default 1e-3 relative: float32 time stamps of a long recording jitter by ~1e-4..1e-3); its
   samples are then taken as dt apart. A step beyond that is refused in one line, or with ``resample`` each stretch is
   linearly interpolated onto the grid t_0 + k dt (inputs held).
2. Coordinates marked in ``angles`` are unwrapped inside each stretch (``numpy.unwrap``: each
   step taken as the one of least magnitude, so |Δq| < π per sample is assumed), so that wrapped
   recordings (angles in [−π, π)) and unwrapped ones give continuous trajectories.
3. By time, per trial: the last ``test_fraction`` of the trial's span is its test part, the
   ``val_fraction`` before it validation, the rest training; a boundary splits a stretch too. So
   every trial contributes to every split, and no trial's test part is seen in training.
4. Each piece is cut into consecutive trajectories of ``n_steps + 1`` samples, neighbours sharing
   their boundary sample, so every step (k, k+1) inside a piece is in exactly one trajectory. Test
   windows of ``test_steps + 1`` samples start every ``test_stride`` samples (default ``test_steps``:
   consecutive; a smaller stride gives more, overlapping, hence correlated windows). Samples after
   a piece's last whole trajectory are unused. The log says, per trial, where each split begins and
   how many trajectories it gave. Training windows of ``data.chunk_len`` are drawn inside these
   trajectories, never across a gap, a split boundary or a trial.
"""

from __future__ import annotations

import csv
import logging
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from encons.infra import bounds
from encons.infra.errors import ConfigError, DataError
from encons.infra.io import save_npz
from encons.infra.progress import to_log_files

log = logging.getLogger(__name__)

#: The options' types, checked by ``encons.infra.bounds.check`` (``resample=maybe`` is refused, not taken as true).
TYPES = {
    "test_fraction": float,
    "val_fraction": float,
    "angles": bool | list[bool] | None,
    "gap": float,
    "jitter": float,
    "resample": bool,
    "test_stride": int | None,
    "columns": dict | None,
    "delimiter": str | None,
    "comment": str | None,
}
OPTIONS = {
    "test_fraction": 0.2,
    "val_fraction": 0.1,
    "angles": None,
    "gap": 1.5,
    "jitter": 1e-3,
    "resample": False,
    "test_stride": None,
    "columns": None,
    "delimiter": None,
    "comment": "#",
}
COLUMN_KEYS = ("t", "q", "qdot", "trial", "u")
SPLITS = ("train", "val", "test")


def is_recording(path: str | Path) -> bool:
    """Whether ``path`` is a recording: a text file, or an ``.npz`` with ``states`` (not split trajectories)."""
    if Path(path).suffix != ".npz":
        return True
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


def recording_angles(angles: bool | list[bool] | None, n: int) -> list[bool]:
    """Which of ``n`` coordinates q are angles, from ``data.recording.angles`` (null/false, true, or n booleans)."""
    if angles is None or isinstance(angles, bool):
        return [bool(angles)] * n
    if not isinstance(angles, (list, tuple)) or len(angles) != n or not all(isinstance(a, bool) for a in angles):
        raise ConfigError(
            f"data.recording.angles={angles!r}; allowed: null, true, false or {n} booleans (one per coordinate q)"
        )
    return list(angles)


def describe(
    path: str | Path, columns: dict | None = None, delimiter: str | None = None, comment: str | None = "#"
) -> tuple[int, str | None, int]:
    """The coordinate count n, the chart (or None) and the input width m of a recording file."""
    t, states, chart, u, _ = _read(Path(path), columns, delimiter, comment)
    return states.shape[1] // 2, chart, 0 if u is None else u.shape[1]


def _read(
    path: Path, columns: dict | None, delimiter: str | None, comment: str | None = "#"
) -> tuple[np.ndarray, np.ndarray, str | None, np.ndarray | None, np.ndarray | None]:
    """Times, states, chart, inputs and trial labels (or None) of a recording, checked."""
    if not path.is_file():
        what = "is a folder" if path.is_dir() else "does not exist"
        raise DataError(f"system.path={str(path)!r} {what}; allowed: an .npz or delimited text file (docs/data.md)")
    if path.suffix == ".npz":
        with np.load(path, allow_pickle=False) as f:
            arrays = {k: f[k] for k in f.files}
        chart = str(arrays["chart"]) if "chart" in arrays else None
        trial = arrays.get("trial")
    else:
        arrays, trial = _read_text(path, columns, delimiter, comment)
        chart = None
    missing = [k for k in ("t", "states") if k not in arrays]
    if missing:
        raise DataError(f"recording {str(path)!r} lacks {missing}; allowed: t (T,) and states (T, 2n)")
    t, states = (np.asarray(arrays[k], dtype=np.float64) for k in ("t", "states"))  # both present (checked above)
    u = np.asarray(arrays["u"], dtype=np.float64) if "u" in arrays else None
    if t.ndim != 1 or len(t) < 3 or states.shape[:1] != t.shape or states.ndim != 2 or states.shape[1] % 2:
        raise DataError(
            f"recording {str(path)!r}: t has shape {t.shape}, states {states.shape}; allowed: "
            f"t (T,) with T >= 3 and states (T, 2n) states (q, q̇)"
        )
    if u is not None and (u.ndim != 2 or len(u) != len(t)):
        raise DataError(f"recording {str(path)!r}: u has shape {u.shape}; allowed: ({len(t)}, m) inputs per sample")
    if trial is not None and np.shape(trial) != t.shape:
        raise DataError(
            f"recording {str(path)!r}: trial has shape {np.shape(trial)}; allowed: ({len(t)},), a label per sample"
        )
    for name, arr in (("t", t), ("states", states), ("u", u)):
        if arr is not None and not np.isfinite(arr).all():
            raise DataError(
                f"recording {str(path)!r}: '{name}' contains NaN or inf; allowed: finite values "
                f"(drop a bad sample with its time: the gap is handled)"
            )
    return t, states, chart, u, trial


def _read_text(
    path: Path, columns: dict | None, delimiter: str | None, comment: str | None
) -> tuple[dict[str, np.ndarray], np.ndarray | None]:
    """The arrays t, states (q then q̇) and u of a delimited text recording, and its trial column."""
    allowed = (
        "a mapping {t: COL, q: [COL, ...], qdot: [COL, ...], trial: COL, u: [COL, ...]} "
        "(trial and u optional), COL a header name or a 0-based column index"
    )
    if not isinstance(columns, Mapping) or not all(k in columns for k in ("t", "q", "qdot")):
        raise ConfigError(
            f"data.recording.columns={columns!r} for the text recording {str(path)!r}; allowed: {allowed}"
        )
    unknown = sorted(set(columns) - set(COLUMN_KEYS))
    if unknown:
        raise ConfigError(f"data.recording.columns.{unknown[0]} is not a column key; allowed: {', '.join(COLUMN_KEYS)}")
    as_list = {k: ([] if v is None else [v] if isinstance(v, (str, int)) else list(v)) for k, v in columns.items()}
    if (
        len(as_list["q"]) != len(as_list["qdot"])
        or not as_list["q"]
        or len(as_list["t"]) != 1
        or len(as_list.get("trial", [])) > 1
    ):
        raise ConfigError(
            f"data.recording.columns={columns!r}; allowed: one t column, as many qdot as q columns "
            f"(at least one), at most one trial column"
        )
    cols: list[Any] = [c for v in as_list.values() for c in v]  # names or indices, as the config gives them
    by_name = all(isinstance(c, str) for c in cols)
    if not by_name and not all(isinstance(c, int) and not isinstance(c, bool) and c >= 0 for c in cols):
        raise ConfigError(
            f"data.recording.columns={columns!r}: mixes names and indices; allowed: all header "
            f"names, or all 0-based indices"
        )
    header, rows = _table(path, delimiter, comment)
    if by_name:
        if header is None or not any(_is_number(c) for c in rows[0]):  # the first row names the columns
            header, rows = list(rows[0]), rows[1:]
            if all(_is_number(c) for c in header):
                raise DataError(
                    f"recording {str(path)!r}: its first row ({' '.join(header)}) holds numbers, not "
                    f"column names; allowed: a header row of names, a first comment line "
                    f"'{comment} NAME NAME ...' with one name per column (data.recording.comment), or "
                    f"0-based column indices in data.recording.columns"
                )
        absent = [c for c in cols if c not in header]
        if absent:
            raise DataError(
                f"recording {str(path)!r} has no column {absent[0]!r}; allowed: its header, {', '.join(header)}"
            )
        index = {c: header.index(c) for c in cols}
    else:
        if max(cols) >= rows.shape[1]:
            raise DataError(
                f"recording {str(path)!r} has {rows.shape[1]} columns, not {max(cols) + 1}; allowed: "
                f"indices 0..{rows.shape[1] - 1}"
            )
        index = {c: c for c in cols}

    def numbers(names: list) -> np.ndarray:
        cells = rows[:, [index[c] for c in names]]
        try:
            return cells.astype(np.float64)
        except ValueError:
            bad = next((r, c) for r in range(len(cells)) for c in range(len(names)) if not _is_number(cells[r, c]))
            raise DataError(
                f"recording {str(path)!r}: column {names[bad[1]]!r}, data row {bad[0] + 1} holds "
                f"{str(cells[bad])!r}; allowed: a number"
            ) from None

    arrays = {"t": numbers(as_list["t"])[:, 0], "states": numbers(as_list["q"] + as_list["qdot"])}
    if as_list.get("u"):
        arrays["u"] = numbers(as_list["u"])
    trial = rows[:, index[as_list["trial"][0]]] if as_list.get("trial") else None
    if trial is not None and all(_is_number(c) for c in trial):  # 0, 0.0 and 0.0000e+000 name one trial
        trial = trial.astype(np.float64)
    return arrays, trial


def trial_name(label: object) -> str:
    """A trial label as a reader writes it: a whole number without its decimals (``0``, not
    ``0.0000000000000000e+000``), any other label as it is."""
    if isinstance(label, (float, np.floating)) and float(label).is_integer():
        return str(int(label))
    return str(label)


def _table(path: Path, delimiter: str | None, comment: str | None) -> tuple[list[str] | None, np.ndarray]:
    """The header of a text recording — its first comment line, when that holds one name per column —
    or None, and its rows of cells (stripped strings, (rows, columns)). Text after ``comment`` on a line
    is left out; blank lines are skipped; cells are split at ``delimiter`` (quotes ``"`` allowed), else at
    whitespace. A row whose cell count differs from the table's is refused, naming its line."""
    if comment is not None and (not isinstance(comment, str) or not comment.strip() or comment != comment.strip()):
        raise ConfigError(
            f"data.recording.comment={comment!r}; allowed: a character (or string) that starts a "
            f"comment, e.g. '#' or '%', without spaces; null for none"
        )
    if delimiter is None:
        delimiter = {".csv": ",", ".tsv": "\t"}.get(path.suffix)

    def cells(text: str) -> list[str]:
        if delimiter is None:
            return text.split()
        return [c.strip() for c in next(csv.reader([text], delimiter=delimiter, quotechar='"'))]

    try:
        lines = path.read_text().splitlines()
    except UnicodeDecodeError as err:
        raise DataError(
            f"recording {str(path)!r} is not text ({err.reason} at byte {err.start}); allowed: a "
            f"UTF-8 delimited text file, or an .npz"
        ) from None
    named: list[str] | None = None  # the first comment line's cells
    numbered: list[tuple[int, list[str]]] = []  # (line number, cells) of rows
    for number, line in enumerate(lines, 1):
        body, hit, rest = line.partition(comment) if comment else (line, "", "")
        if hit and named is None and not numbered and not body.strip():
            named = cells(rest.strip())
        if body.strip():
            numbered.append((number, cells(body)))
    if not numbered:
        raise DataError(
            f"recording {str(path)!r} holds no rows; allowed: a delimited text table "
            f"(lines starting with data.recording.comment={comment!r} are skipped)"
        )
    widths = np.array([len(c) for _, c in numbered])
    width = int(np.bincount(widths).argmax())  # the table's width: that of most rows
    if (widths != width).any():
        bad = int(np.flatnonzero(widths != width)[0])
        number, row = numbered[bad]
        text = lines[number - 1].strip()
        lead = text[:1]
        hint = (
            f"; is it a header? a comment line starting with {lead!r} needs data.recording.comment={lead!r}"
            if bad == 0 and lead and not (lead.isalnum() or lead in "+-._\"'")
            else "; a header row of names needs as many names as the table has columns"
            if bad == 0
            else ""
        )
        raise DataError(
            f"recording {str(path)!r}: line {number} ({text[:60]!r}) has {len(row)} cell(s) where the "
            f"table's other rows have {width}{hint}; allowed: rows of {width} cells split at "
            f"{'whitespace' if delimiter is None else repr(delimiter)} (data.recording.delimiter), "
            f"comments after data.recording.comment={comment!r}"
        )
    header = named if named is not None and len(named) == width else None
    return header, np.array([c for _, c in numbered], dtype=str).reshape(len(numbered), width)


def _is_number(cell: str) -> bool:
    try:
        float(cell)
        return True
    except ValueError:
        return False


def checked_options(options: dict | None, test_steps: int = 1) -> dict:
    """``options`` over the defaults (``OPTIONS``), each of its type (``TYPES``) and range, else one
    ``ConfigError`` line naming the ``data.recording`` key."""
    unknown = sorted(set(options or {}) - set(OPTIONS))
    if unknown:
        raise ConfigError(f"data.recording.{unknown[0]} is not an option; allowed: {', '.join(OPTIONS)}")
    opts = {**OPTIONS, **(options or {})}
    bounds.check({k: v for k, v in opts.items() if k != "columns"}, TYPES, "data.recording")
    test_fraction, val_fraction, gap, jitter = (opts[k] for k in ("test_fraction", "val_fraction", "gap", "jitter"))
    if not (0 < test_fraction < 1 and 0 < val_fraction < 1 and test_fraction + val_fraction < 1):
        raise ConfigError(
            f"data.recording.test_fraction={test_fraction}, val_fraction={val_fraction}; allowed: "
            f"both in (0, 1) with a sum < 1"
        )
    if not gap > 1:
        raise ConfigError(f"data.recording.gap={gap}; allowed: > 1 (steps longer than gap × dt split the recording)")
    if not 0 <= jitter < gap - 1:
        raise ConfigError(
            f"data.recording.jitter={jitter}; allowed: [0, gap - 1 = {gap - 1:g}) (a relative "
            f"deviation of a step from dt)"
        )
    stride = opts["test_stride"] if opts["test_stride"] is not None else test_steps
    if not (isinstance(stride, int) and stride >= 1):
        raise ConfigError(f"data.recording.test_stride={stride}; allowed: null (= data.test_steps) or an integer >= 1")
    return opts


def load_recording(
    path: str | Path,
    n_steps: int,
    test_steps: int,
    options: dict | None = None,
    n_controls: int = 0,
    checked: bool = False,
) -> tuple[Tensor, dict[str, Tensor], str | None, dict[str, Tensor]]:
    """Cut a recording as the module docstring says, with ``options`` (keys and defaults: ``OPTIONS``;
    checked by :func:`checked_options` unless ``checked``: the data module's rules did it);
    returns the times of a training trajectory (n_steps + 1,), the splits {train, val, test}
    (N, L, 2n), the chart and the inputs per split (N, L, m) (empty when ``n_controls`` is 0)."""
    path = Path(path)
    opts = {**OPTIONS, **(options or {})} if checked else checked_options(options, test_steps)
    test_fraction, val_fraction, gap, jitter = (opts[k] for k in ("test_fraction", "val_fraction", "gap", "jitter"))
    stride = opts["test_stride"] if opts["test_stride"] is not None else test_steps
    t, states, chart, u, trial = _read(path, opts["columns"], opts["delimiter"], opts["comment"])
    if n_controls and (u is None or u.shape[1] != n_controls):
        raise DataError(
            f"recording {str(path)!r} holds no inputs u of width {n_controls}; allowed: u ({len(t)}, {n_controls})"
        )
    labels, first, code, sizes = np.unique(
        trial if trial is not None else np.zeros(len(t), int),
        return_index=True,
        return_inverse=True,
        return_counts=True,
    )
    rows_of = np.split(np.argsort(code, kind="stable"), np.cumsum(sizes)[:-1])  # each trial's rows, in file order
    appearance = np.argsort(first)  # trials in order of appearance
    labels, rows_of = labels[appearance], [rows_of[k] for k in appearance]
    for label, rows in zip(labels, rows_of):
        if len(rows) < 2 or not (np.diff(t[rows]) > 0).all():
            where = f" in trial {trial_name(label)}" if trial is not None else ""
            raise DataError(
                f"recording {str(path)!r}: 't' is not increasing{where}; allowed: increasing times "
                f"(per trial), at least 2 samples each"
            )
    steps_of = [np.diff(t[rows]) for rows in rows_of]
    steps = np.concatenate(steps_of)
    median = float(np.median(steps))
    regular = steps <= gap * median
    dt = float(steps[np.abs(steps / median - 1) <= jitter].mean())  # unbiased by rounded stamps, unlike the median
    deviation = np.abs(steps[regular] / dt - 1)
    worst = float(deviation.max())
    if worst > jitter and not opts["resample"]:
        step = steps[regular][np.argmax(deviation)]
        raise DataError(
            f"recording {str(path)!r}: a step of {step:.6g} beside dt = {dt:.6g} is "
            f"{worst:.2g} off; allowed: steps within data.recording.jitter={jitter:g} of dt, gaps longer "
            f"than data.recording.gap={gap} × the median step, or data.recording.resample=true (interpolate onto dt)"
        )
    mask = recording_angles(opts["angles"], states.shape[1] // 2)
    pieces: dict[str, list[tuple[np.ndarray, np.ndarray | None]]] = {name: [] for name in SPLITS}  # (states, inputs)
    lines, longest, gaps = [], dict.fromkeys(SPLITS, 0), 0  # longest: samples of a split's longest unbroken piece
    for label, rows, trial_steps in zip(labels, rows_of, steps_of):
        cuts = np.concatenate([[0], np.flatnonzero(trial_steps > gap * median) + 1, [len(rows)]])
        t0, span = t[rows[0]], t[rows[-1]] - t[rows[0]]
        edges = [t0 + (1 - test_fraction - val_fraction) * span, t0 + (1 - test_fraction) * span]
        counts = dict.fromkeys(SPLITS, 0)
        for a, b in zip(cuts[:-1], cuts[1:]):
            times, s, stretch_u = _stretch(
                t[rows[a:b]], states[rows[a:b]], None if u is None else u[rows[a:b]], mask, dt, bool(opts["resample"])
            )
            part = np.searchsorted(edges, times, side="right")  # 0 train, 1 val, 2 test
            for k, name in enumerate(SPLITS):
                inside = np.flatnonzero(part == k)
                longest[name] = max(longest[name], len(inside))
                length = (test_steps if name == "test" else n_steps) + 1
                every = stride if name == "test" else length - 1
                count = (len(inside) - length) // every + 1 if len(inside) >= length else 0
                if count:
                    index = inside[0] + every * np.arange(count)[:, None] + np.arange(length)
                    pieces[name].append((s[index], None if stretch_u is None else stretch_u[index]))
                counts[name] += count
        gaps += len(cuts) - 2
        end = t[rows[-1]]
        lines.append(
            f"{'trial ' + trial_name(label) + ': ' if trial is not None else ''}t {t0:.6g}..{end:.6g}, "
            f"{len(rows)} samples, {len(cuts) - 2} gap(s); train t {t0:.6g}..{edges[0]:.6g}: "
            f"{counts['train']}, val t {edges[0]:.6g}..{edges[1]:.6g}: {counts['val']}, test t "
            f"{edges[1]:.6g}..{end:.6g}: {counts['test']} trajectories"
        )
    for name in SPLITS:
        if not pieces[name]:
            key, need = ("test_steps", test_steps + 1) if name == "test" else ("n_steps", n_steps + 1)
            share = (
                "test_fraction"
                if name == "test"
                else "val_fraction"
                if name == "val"
                else "test_fraction, val_fraction"
            )
            raise DataError(
                f"recording {str(path)!r}: its {name} part holds no unbroken stretch of {need} samples (its longest "
                f"holds {longest[name]}; {gaps} gap(s) longer than data.recording.gap={gap:g} × the median step split "
                f"the recording); allowed: data.{key} <= {max(longest[name] - 1, 0)}, a larger share (data.recording."
                f"{share}), a larger data.recording.gap with data.recording.resample=true (interpolates over dropped "
                f"samples), or a longer recording"
            )
    splits = {name: torch.from_numpy(np.concatenate([p[0] for p in pieces[name]])) for name in SPLITS}
    inputs = (
        {name: torch.from_numpy(np.concatenate([p[1] for p in pieces[name]])) for name in SPLITS} if n_controls else {}
    )
    log.info(
        "recording %s: %d sample(s) in %d trial(s), dt %.6g (steps off dt by up to %.2g relative%s; "
        "data.recording.jitter=%g); split by time within each trial into trajectories of %d samples "
        "(test: %d, starting every %d samples)",
        path.name,
        len(t),
        len(labels),
        dt,
        worst,
        ", resampled" if worst > jitter else "",
        jitter,
        n_steps + 1,
        test_steps + 1,
        stride,
    )
    for k, line in enumerate(
        lines
    ):  # where each split begins, per trial: the first 10 on the console, all in the log files
        if k < 10:
            log.info("recording %s, %s", path.name, line)
        else:
            to_log_files(f"recording {path.name}, {line}")
    if len(lines) > 10:
        log.info("recording %s: %d more trial(s) in the log files", path.name, len(lines) - 10)
    log.info("recording %s: trajectories train/val/test %d/%d/%d", path.name, *(len(splits[k]) for k in SPLITS))
    return torch.arange(n_steps + 1, dtype=torch.float64) * dt, splits, chart, inputs


def _stretch(
    times: np.ndarray, states: np.ndarray, u: np.ndarray | None, mask: list[bool], dt: float, resample: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """One unbroken stretch with angles unwrapped; with ``resample``, interpolated onto t_0 + k dt
    (states linearly, inputs held from the last sample at or before each grid time)."""
    states = unwrap(torch.from_numpy(states), mask).numpy()
    if not resample:
        return times, states, u
    grid = times[0] + dt * np.arange(int(math.floor((times[-1] - times[0]) / dt * (1 + 1e-9))) + 1)
    states = np.stack([np.interp(grid, times, column) for column in states.T], -1)
    if u is not None:
        u = u[np.clip(np.searchsorted(times, grid, side="right") - 1, 0, len(times) - 1)]
    return grid, states, u


def write_example(
    path: str | Path,
    duration: float = 60.0,
    dt: float = 0.02,
    dropped: tuple[tuple[int, int], ...] = ((700, 3), (1500, 1), (2200, 10)),
) -> Path:
    """Write docs/data.md's worked example: one ``duration``-second recording of the compound pendulum
    (Xiao et al. eq. (12)) with light axle friction (γ₁ = γ₂ = 0.05, so it winds over the top for
    about 30 s, then swings), sampled every ``dt``, with the samples ``dropped`` ((first, count) pairs)
    missing and both angles wrapped into [−π, π), as a measurement would give them. Simulated by RK4
    at dt / 2 (one long trajectory is sequential; finer steps only cost time for a stand-in measurement)."""
    from encons.data.simulate import simulate
    from encons.systems.dissipative import CompoundPendulum

    t = torch.arange(round(duration / dt) + 1, dtype=torch.float64) * dt
    states = simulate(
        CompoundPendulum(gamma1=0.05, gamma2=0.05),
        torch.tensor([[0.5, -0.5, 2.0, 12.0]], dtype=torch.float64),
        t,
        substeps=2,
    )[0]
    keep = torch.ones(len(t), dtype=torch.bool)
    for first, count in dropped:
        keep[first : first + count] = False
    return save_npz(path, t=t[keep].numpy(), states=wrap(states[keep], [True, True]).numpy(), chart="angle")


if __name__ == "__main__":
    import sys

    if len(sys.argv) != 2:
        sys.exit("usage: python -m encons.data.recording OUT.npz   (writes docs/data.md's example recording)")
    print(f"wrote {write_example(sys.argv[1])}")
