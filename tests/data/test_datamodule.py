"""Data: cache written atomically and reused, windows, user files and their errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from encons.data import store
from encons.data.datamodule import TrajectoryDataModule, WindowSampler
from encons.data.simulate import simulate
from encons.infra.errors import ConfigError, DataError
from encons.systems.pendulum import NPendulum

SMALL = dict(n_train=12, n_val=3, n_test=4, n_steps=20, batch_size=5)


def make(tmp_path, chart="angle", **kw):
    return TrajectoryDataModule(NPendulum(2), chart, {"n_links": 2}, cache_dir=str(tmp_path), **{**SMALL, **kw})


def test_cache_is_written_once_and_reused(tmp_path):
    dm = make(tmp_path)
    dm.prepare_data()
    stamp = dm.cache_file.stat().st_mtime_ns
    make(tmp_path).prepare_data()
    assert dm.cache_file.stat().st_mtime_ns == stamp
    assert list(tmp_path.iterdir()) == [dm.cache_file]  # no temporary file left behind


def test_a_different_config_gets_a_different_cache(tmp_path):
    assert make(tmp_path).cache_file != make(tmp_path, dt=0.01).cache_file


def test_interrupted_write_leaves_no_file(tmp_path, monkeypatch):
    def explode(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "savez", explode)
    with pytest.raises(KeyboardInterrupt):
        store.save(tmp_path / "x.npz", torch.zeros(3), {"train": torch.zeros(1, 3, 2)}, "angle")
    assert list(tmp_path.iterdir()) == []


def test_served_chart_is_the_mapped_base_chart(tmp_path):
    angle, cart = make(tmp_path, noise=0.0), make(tmp_path, chart="cartesian", noise=0.0)
    for dm in (angle, cart):
        dm.prepare_data()
        dm.setup()
    mapped = NPendulum(2).to_chart(angle.states["test"].double(), "angle", "cartesian")
    assert torch.allclose(mapped, cart.states["test"], atol=1e-5)  # test states are served in float64


def test_noise_only_on_train_validation_sees_clean_truth(tmp_path):
    clean, noisy = make(tmp_path, noise=0.0), make(tmp_path, noise=0.5)
    for dm in (clean, noisy):
        dm.prepare_data()
        dm.setup()
    assert torch.equal(clean.states["test"], noisy.states["test"])
    assert torch.equal(clean.states["val"], noisy.states["val"])
    spread = (noisy.states["train"] - clean.states["train"]).std().item()
    assert 0.45 < spread < 0.55


def test_lightning_advances_the_window_sampler_epoch(tmp_path):
    from lightning.fabric.utilities.data import _set_sampler_epoch

    dm = make(tmp_path)
    dm.prepare_data()
    dm.setup()
    loader = dm.train_dataloader()
    _set_sampler_epoch(loader, 5)
    assert loader.sampler.epoch == 5


def test_windows_are_deterministic_per_epoch_and_cover_every_trajectory():
    sampler = WindowSampler(10, 7, seed=1)
    sampler.set_epoch(3)
    first = list(sampler)
    sampler.set_epoch(4)
    other = list(sampler)
    sampler.set_epoch(3)
    assert first == list(sampler) and first != other
    assert sorted(i for i, _ in first) == list(range(10)) and all(0 <= s < 7 for _, s in first)


def test_random_windows_are_unchanged_and_all_windows_visit_every_window_once_per_epoch():
    random = WindowSampler(5, 3, seed=2)
    random.set_epoch(1)
    assert list(random) == [(1, 1), (0, 0), (4, 1), (2, 1), (3, 1)]  # drawn before windows="all" existed
    every = WindowSampler(5, 3, seed=2, every=True)
    every.set_epoch(1)
    first = list(every)
    every.set_epoch(2)
    assert len(every) == 15 and sorted(first) == [(i, s) for i in range(5) for s in range(3)]
    assert sorted(every) == sorted(first) and list(every) != first
    assert len({i for i, _ in first[:5]}) > 1  # shuffled across trajectories, not trajectory by trajectory


def test_all_windows_make_an_epoch_a_pass_over_every_window(tmp_path):
    dm = make(tmp_path, chunk_len=5, windows="all")
    dm.prepare_data()
    dm.setup()
    n_train, states = dm.states["train"].shape[:2]
    batches = list(dm.train_dataloader())
    assert sum(b["states"].shape[0] for b in batches) == n_train * (states - 4)
    assert len(batches) == -(-n_train * (states - 4) // dm.batch_size)
    one = make(tmp_path, chunk_len=5)
    one.prepare_data()
    one.setup()
    assert len(list(one.train_dataloader())) == -(-n_train // dm.batch_size)
    val = [b["states"] for b in dm.val_dataloader()]
    assert all(torch.equal(a, b["states"]) for a, b in zip(val, one.val_dataloader(), strict=True))  # training only


def test_an_unknown_windows_value_is_refused(tmp_path):
    with pytest.raises(ConfigError, match=r"^data.windows='some'; allowed: random, all$"):
        make(tmp_path, windows="some")


def test_train_batches_are_windows_of_chunk_len(tmp_path):
    dm = make(tmp_path, chunk_len=5)
    dm.prepare_data()
    dm.setup()
    batch = next(iter(dm.train_dataloader()))
    assert set(batch) == {"states"} and batch["states"].shape == (5, 5, 4)
    i, start = next(iter(dm.train_dataloader().sampler))
    assert torch.equal(batch["states"][0], dm.states["train"][i, start : start + 5])


def write(path, **arrays):
    np.savez(path, **arrays)
    return path


@pytest.mark.parametrize(
    "arrays, message",
    [
        ({"t": np.arange(5.0)}, "lacks key"),
        ({"t": np.arange(5.0), "train": np.zeros((2, 4, 4)), "test": np.zeros((2, 5, 4))}, "has shape"),
        ({"t": np.array([0, 1, 3.0]), "train": np.zeros((2, 3, 2)), "test": np.zeros((2, 3, 2))}, "equally spaced"),
        ({"t": np.arange(3.0), "train": np.full((2, 3, 2), np.nan), "test": np.zeros((2, 3, 2))}, "NaN"),
    ],
)
def test_malformed_files_are_named(tmp_path, arrays, message):
    with pytest.raises(DataError, match=message):
        store.load(write(tmp_path / "bad.npz", **arrays))


def test_missing_and_corrupt_files(tmp_path):
    with pytest.raises(DataError, match="does not exist"):
        store.load(tmp_path / "nope.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(DataError, match="not a readable"):
        store.load(tmp_path / "junk.npz")


def test_user_file_trains_end_to_end(tmp_path, train_run):
    system = NPendulum(1)
    t = torch.arange(21, dtype=torch.float64) * 0.03
    traj = simulate(system, system.sample_initial(20, torch.Generator().manual_seed(0)), t)
    path = write(
        tmp_path / "mine.npz", t=t.numpy(), train=traj[:16].numpy(), test=traj[16:].numpy(), chart=np.array("angle")
    )
    results = train_run(["system=from_file", f"system.path={path}", "model=node"])
    assert np.isfinite(results["test/traj_rel_err"]) and "test/energy_abs_err" not in results


def test_val_batch_size_batches_the_same_validation_windows(tmp_path):
    """``val_batch_size`` regroups the validation windows (null: all in one batch); training batches
    and the windows themselves do not change."""
    default, whole = (
        make(tmp_path, chunk_len=21, batch_size=1, val_batch_size=1),
        make(tmp_path, chunk_len=21, batch_size=1),
    )
    for dm in (default, whole):
        dm.prepare_data()
        dm.setup()
    small, one = list(default.val_dataloader()), list(whole.val_dataloader())
    assert [len(b["states"]) for b in small] == [1, 1, 1] and [len(b["states"]) for b in one] == [3]
    assert torch.equal(torch.cat([b["states"] for b in small]), one[0]["states"])
    assert all(
        torch.equal(a["states"], b["states"]) for a, b in zip(default.train_dataloader(), whole.train_dataloader())
    )
