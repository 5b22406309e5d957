"""A lab's recordings: delimited text read through a column mapping, float32 time-stamp jitter up to
``data.recording.jitter`` (refused or resampled beyond it), several trials in one file kept apart
and each split by time, a stride for test windows, and the log lines that say how splits were formed."""

from __future__ import annotations

import logging
import math
import warnings

import numpy as np
import pytest
import torch

from encons.data.datamodule import TrajectoryDataModule
from encons.data.from_file import FileSystem
from encons.data.recording import load_recording
from encons.infra.errors import ConfigError, DataError

DT = 0.01
COLUMNS = {"t": "time", "q": ["theta"], "qdot": ["omega"], "trial": "run"}


def two_trial_csv(path, seconds=4.0, start=100.0, trials=("A", "B")):
    """A CSV of two trials on one clock, stamps stored as float32 (jitter ~1e-4..8e-4 relative at
    t ≈ 100 s); theta is the exact float64 time plus 1000 per trial index, so a window shows where it came from."""
    lines = ["# bench rig 3, 100 Hz", "time,theta,omega,run"]
    for k, label in enumerate(trials):
        t = start + k * (seconds + 1.0) + DT * np.arange(round(seconds / DT) + 1)
        stamps = t.astype(np.float32)
        lines += [f"{s!r},{1000 * k + x!r},0.5,{label}" for s, x in zip(stamps.tolist(), t.tolist())]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_two_trial_csv_with_jittered_stamps_keeps_trials_apart_and_splits_each_by_time(tmp_path, caplog):
    path = two_trial_csv(tmp_path / "rig.csv")
    stamps = np.loadtxt(path, delimiter=",", skiprows=2, usecols=0)
    steps = np.diff(stamps[:401])
    assert 1e-6 < np.abs(steps / DT - 1).max() < 1e-3  # jitter beyond float64 rounding, inside the default
    with caplog.at_level(logging.INFO, logger="encons"):
        t, splits, chart, _ = load_recording(path, n_steps=10, test_steps=20, options={"columns": COLUMNS})
    torch.testing.assert_close(t, torch.arange(11, dtype=torch.float64) * DT)
    theta = {k: v[..., 0] for k, v in splits.items()}
    for name, q in theta.items():
        trial = (q >= 500).long()
        assert bool((trial == trial[:, :1]).all()), f"a {name} window crosses trials"
        assert set(trial[:, 0].tolist()) == {0, 1}, f"{name} lacks a trial"  # each trial in each split
        torch.testing.assert_close(q.diff(dim=-1), torch.full_like(q[:, 1:], DT))  # consecutive samples
    for k in (0, 1):  # per trial: train before val before test
        of = {name: q[(q[:, 0] >= 500) == bool(k)] for name, q in theta.items()}
        begin = 100.0 + k * 5.0 + 1000 * k
        assert of["train"].min() == pytest.approx(begin) and of["train"].max() <= begin + 0.7 * 4.0
        assert begin + 0.7 * 4.0 - DT < of["val"].min() and of["val"].max() <= begin + 0.8 * 4.0
        assert begin + 0.8 * 4.0 - DT < of["test"].min() and of["test"].max() <= begin + 4.0 + 1e-9
    assert "2 trial(s)" in caplog.text and "trial A: t 100..104" in caplog.text and "trial B: t 105..109" in caplog.text
    assert (
        "rig.csv, trial A: t 100..104, 401 samples, 0 gap(s); train t 100..102.8: 27, val t 102.8..103.2: 4, "
        "test t 103.2..104: 3 trajectories" in caplog.text
    )


def test_the_cli_trains_on_a_csv_recording_for_a_budget_in_steps(tmp_path, caplog):
    from encons.entry import api

    path = two_trial_csv(tmp_path / "rig.csv")
    cfg = api.compose(
        "debug=fast",
        "system=from_file",
        f"system.path={path}",
        "model=node",
        "data.n_steps=10",
        "data.test_steps=20",
        "data.recording.columns={t: time, q: [theta], qdot: [omega], trial: run}",
        "trainer.max_epochs=null",
        "trainer.max_steps=9",
        output_dir=tmp_path / "run",
    )
    with caplog.at_level(logging.INFO, logger="encons"):
        run = api.train(cfg)
    assert math.isfinite(run.metrics["test/traj_rel_err"])
    assert (
        "54 trajectories in batches of 8: 7 optimiser step(s) per epoch (a file: budget training with "
        "trainer.max_steps, or data.windows=all)" in caplog.text
    )
    last = torch.load(run.run_dir / "checkpoints" / "last.ckpt", weights_only=True, map_location="cpu")
    assert last["global_step"] == 9 and last["epoch"] == 1  # 9 steps: epoch 0 whole, 2 of epoch 1


def test_steps_beyond_the_jitter_tolerance_are_refused_or_resampled(tmp_path):
    t = np.arange(60) * 0.1
    t[30:] += 0.003  # one step 3 % long
    states = np.stack([t, np.ones_like(t)], -1)  # q = t: linear, so interpolation is exact
    np.savez(tmp_path / "rec.npz", t=t, states=states)
    with pytest.raises(
        DataError,
        match=r"a step of 0.103 beside dt = 0.1 is 0.03 off; allowed: steps "
        r"within data.recording.jitter=0.001 of dt.*data.recording.resample=true",
    ):
        load_recording(tmp_path / "rec.npz", 4, 4, {})
    load_recording(tmp_path / "rec.npz", 4, 4, {"jitter": 0.05})  # a looser tolerance accepts it
    _, splits, _, _ = load_recording(tmp_path / "rec.npz", 4, 4, {"resample": True})
    q = torch.cat([splits[k][..., 0].flatten() for k in splits])
    assert float((q / 0.1 - torch.round(q / 0.1)).abs().max()) < 1e-9  # on the grid t_0 + k dt
    with pytest.raises(ConfigError, match=r"data.recording.jitter=0.6; allowed: \[0, gap - 1 = 0.5\)"):
        load_recording(tmp_path / "rec.npz", 4, 4, {"jitter": 0.6})


def test_a_test_stride_gives_overlapping_test_windows(tmp_path):
    t = np.arange(200) * DT
    np.savez(tmp_path / "rec.npz", t=t, states=np.stack([np.arange(200.0), np.zeros(200)], -1))
    _, plain, _, _ = load_recording(tmp_path / "rec.npz", 5, 10, {})
    _, strided, _, _ = load_recording(tmp_path / "rec.npz", 5, 10, {"test_stride": 2})
    assert plain["test"][:, 0, 0].tolist() == [160.0, 170.0, 180.0]  # t >= 0.8 · 1.99: samples 160..199
    assert strided["test"][:, 0, 0].tolist() == [160.0 + 2 * k for k in range(15)]
    with pytest.raises(ConfigError, match=r"data.recording.test_stride=0; allowed: null"):
        load_recording(tmp_path / "rec.npz", 5, 10, {"test_stride": 0})


def test_text_recording_errors_are_one_line(tmp_path):
    path = two_trial_csv(tmp_path / "rig.csv")
    with pytest.raises(ConfigError, match=r"data.recording.columns=None for the text recording .*; allowed: a mapping"):
        load_recording(path, 4, 4, {})
    with pytest.raises(DataError, match=r"has no column 'angle'; allowed: its header, time, theta, omega, run"):
        load_recording(path, 4, 4, {"columns": {**COLUMNS, "q": ["angle"]}})
    with pytest.raises(DataError, match=r"column 'run', data row 1 holds 'A'; allowed: a number"):
        load_recording(path, 4, 4, {"columns": {**COLUMNS, "q": ["run"]}})
    with pytest.raises(ConfigError, match=r"mixes names and indices"):
        load_recording(path, 4, 4, {"columns": {**COLUMNS, "q": [1]}})
    (tmp_path / "plain.txt").write_text("\n".join(f"{k * DT} {k} 0" for k in range(50)))
    _, splits, _, _ = load_recording(tmp_path / "plain.txt", 4, 4, {"columns": {"t": 0, "q": [1], "qdot": [2]}})
    assert splits["train"][0, :, 0].tolist() == [0.0, 1.0, 2.0, 3.0, 4.0]
    assert FileSystem(str(tmp_path / "plain.txt"), columns={"t": 0, "q": [1], "qdot": [2]}).n == 1


def test_a_recording_data_module_logs_the_steps_per_epoch(tmp_path, caplog):
    path = two_trial_csv(tmp_path / "rig.csv")
    data = TrajectoryDataModule(
        FileSystem(str(path), columns=COLUMNS),
        "angle",
        path=str(path),
        n_steps=10,
        test_steps=20,
        chunk_len=3,
        batch_size=8,
        recording={"columns": COLUMNS},
    )
    with caplog.at_level(logging.INFO, logger="encons"):
        data.setup()
    assert "train: 54 trajectories in batches of 8: 7 optimiser step(s) per epoch" in caplog.text


def matlab_style(path, shift=0.0, samples=400):
    """A whitespace recording whose first line is ``% time theta omega``: a pendulum q = 2.8 cos(2t) (+ shift)."""
    t = DT * np.arange(samples)
    q = 2.8 * np.cos(2 * t) + shift
    rows = [f"{a:.6f} {b:.12f} {c:.12f}" for a, b, c in zip(t, q, -5.6 * np.sin(2 * t))]
    path.write_text("% time theta omega\n" + "\n".join(rows) + "\n")
    return path


MATLAB = ["data.recording.comment='%'", "data.recording.columns={t: time, q: [theta], qdot: [omega]}"]


def test_a_matlab_style_file_with_a_percent_header_trains(tmp_path, capsys):
    from encons.entry import api

    path = matlab_style(tmp_path / "lab.txt")
    with pytest.raises(
        DataError,
        match=r"line 1 \('% time theta omega'\) has 4 cell\(s\) where the table's other "
        r"rows have 3; is it a header\? .* needs data.recording.comment='%'",
    ):
        load_recording(path, 4, 4, {"columns": {"t": "time", "q": ["theta"], "qdot": ["omega"]}})
    cfg = api.compose(
        "debug=fast",
        "system=from_file",
        f"system.path={path}",
        "model=node",
        "data.n_steps=10",
        *MATLAB,
        "trainer.max_epochs=null",
        "trainer.max_steps=3",
        output_dir=tmp_path / "run",
    )
    run = api.train(cfg)
    assert math.isfinite(run.metrics["test/traj_rel_err"]) and math.isfinite(run.metrics["test/traj_rel_err_window"])
    assert (
        "traj_rel_err sums the first 4 of 10 steps of each test window (horizon=4, the papers' protocol); "
        "traj_rel_err_window sums all 10"
    ) in " ".join(capsys.readouterr().out.split())  # the summary's note
    theta = run.data.states["test"][0, :, 0]  # the named column, not the first data row as header
    torch.testing.assert_close(theta, torch.from_numpy(2.8 * np.cos(2 * DT * (320 + np.arange(11)))), atol=1e-9, rtol=0)


def test_a_commented_header_names_columns_and_numpy_warns_nothing(tmp_path):
    path = matlab_style(tmp_path / "lab.txt")
    path.write_text(path.read_text().replace("% time", "# time", 1))
    columns = {"t": "time", "q": ["theta"], "qdot": ["omega"]}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _, splits, _, _ = load_recording(path, 10, 10, {"columns": columns})
    assert splits["train"][0, 0, 0].item() == pytest.approx(2.8)
    path.write_text("\n".join(path.read_text().splitlines()[1:]))  # no header at all: names cannot be found
    with pytest.raises(
        DataError,
        match=r"its first row \(0.000000 2.800000000000 -0.000000000000\) holds numbers, "
        r"not column names; allowed: a header row of names, a first comment line",
    ):
        load_recording(path, 10, 10, {"columns": columns})


def test_a_boolean_option_refuses_a_word(tmp_path, monkeypatch):
    from tests.helpers import in_process

    path = matlab_style(tmp_path / "lab.txt")
    done = in_process(
        "encons.train",
        [
            "system=from_file",
            f"system.path={path}",
            *MATLAB,
            "data.recording.resample=maybe",
            f"hydra.run.dir={tmp_path / 'run'}",
        ],
        monkeypatch,
    )
    assert done.returncode != 0
    assert (
        done.stderr.strip()
        == "encons: error: data.recording.resample='maybe' has type str; allowed: true or false (a bool)"
    )


def test_an_angle_shifted_by_2pi_gives_the_same_constant_baseline_metrics(tmp_path):
    from encons.entry import api
    from encons.training.runs import evaluate

    plain, shifted = matlab_style(tmp_path / "plain.txt"), matlab_style(tmp_path / "shifted.txt", shift=2 * math.pi)
    common = [
        "debug=fast",
        "system=from_file",
        "model=node",
        "data.n_steps=10",
        "data.test_steps=20",
        *MATLAB,
        "data.recording.angles=true",
        "trainer.max_epochs=null",
        "trainer.max_steps=1",
    ]
    run = api.train(api.compose(*common, f"system.path={plain}", output_dir=tmp_path / "run"), summary=False)
    moved = evaluate(run.run_dir, [f"system.path={shifted}", f"data.path={shifted}"], ckpt="last")
    keys = [k for k in run.metrics if k.startswith("test/baseline_constant/")]
    assert len(keys) == 10  # every metric the model gets (summarise) and the state MSEs
    for key in keys:
        assert moved[key] == pytest.approx(run.metrics[key], rel=1e-9), key
    assert moved["test/baseline_linear_ode/traj_rel_err"] == pytest.approx(
        run.metrics["test/baseline_linear_ode/traj_rel_err"], rel=1e-3
    )  # fitted with an intercept to float32 states


def test_a_short_recording_names_its_longest_stretch_gap_count_and_the_keys_that_change_them(tmp_path):
    t = np.delete(np.arange(300) * DT, [50, 51, 120, 200])  # 3 gaps: stretches of 50, 68, 79, 99 samples
    np.savez(tmp_path / "rec.npz", t=t, states=np.stack([np.sin(t), np.cos(t)], -1))
    with pytest.raises(
        DataError,
        match=r"its train part holds no unbroken stretch of 101 samples \(its longest holds "
        r"79; 3 gap\(s\) longer than data.recording.gap=1.5 × the median step split the "
        r"recording\); allowed: data.n_steps <= 78, a larger share \(data.recording."
        r"test_fraction, val_fraction\), a larger data.recording.gap with data.recording."
        r"resample=true",
    ):
        load_recording(tmp_path / "rec.npz", 100, 10, {})
    with pytest.raises(
        DataError,
        match=r"its val part holds .* \(its longest holds 30;.*allowed: data.n_steps <= 29, "
        r"a larger share \(data.recording.val_fraction\)",
    ):
        load_recording(tmp_path / "rec.npz", 78, 10, {})  # the train bound it named was enough: val is next
