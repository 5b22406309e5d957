"""Santos et al.'s one-step MSEs on the train and the test split are computed on two different sets of
trajectories (a summary table at 4 digits once showed them equal)."""

from __future__ import annotations

import torch

from encons import api


def test_lnode_mse_train_and_mse_test_come_from_disjoint_splits(tmp_path):
    cfg = api.compose("debug=fast", "model=lnode", "system=pendulum_control", output_dir=tmp_path / "run",
                      cache_dir=tmp_path / "cache")
    run = api.train(cfg, summary=False)
    train, test = (run.data.arrays[k]["states"].double() for k in ("train", "test"))
    starts = torch.cdist(train[:, 0], test[:, 0])
    assert float(starts.min()) > 1e-3                                 # no test trajectory is a training one
    u_train, u_test = (run.data.arrays[k]["u"].double() for k in ("train", "test"))
    assert not torch.equal(u_train[: len(u_test)], u_test[: len(u_train)])
    assert run.metrics["test/mse_train"] != run.metrics["test/mse_test"]
