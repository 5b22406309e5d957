"""Santos et al.'s one-step MSEs on the train and the test split are computed on two different sets of
trajectories (a summary table at 4 digits once showed them equal)."""

from __future__ import annotations

import torch

from encons.entry import api
from tests.helpers import SANTOS_TINY


def test_lnode_mse_train_and_mse_test_come_from_disjoint_splits(tmp_path):
    cfg = api.compose(
        "debug=fast",
        "model=lnode",
        "system=pendulum_control",
        "figures=false",
        *SANTOS_TINY,
        output_dir=tmp_path / "run",
        cache_dir=tmp_path / "cache",
    )
    run = api.train(cfg, summary=False)
    train, test = (run.data.arrays[k]["states"] for k in ("train", "test"))
    starts = torch.cdist(train[:, 0].double(), test[:, 0])  # test states are served in float64
    assert float(starts.min()) > 1e-3  # no test trajectory is a training one
    assert not torch.equal(run.data.arrays["train"]["u"][: len(test)], run.data.arrays["test"]["u"])
    assert run.metrics["test/mse_train"] != run.metrics["test/mse_test"]
