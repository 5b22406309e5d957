"""The notebook workflow of the README: compose, train, load from a checkpoint alone, evaluate, roll out."""

from __future__ import annotations

import math
import shutil
import subprocess
import sys

import torch

import encons


def test_import_is_light_and_versioned():
    probe = (
        "import sys, encons; print(encons.__version__, sorted(encons.__all__));"
        "print('lightning.pytorch' in sys.modules, 'torch' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout
    version, names = out.splitlines()[0].split(" ", 1)
    assert version.count(".") >= 2
    assert eval(names) == sorted(encons.__all__) and "train" in names and "load" in names
    assert out.splitlines()[1] == "False False"  # no Lightning, not even torch, at import


def test_notebook_workflow_round_trips_a_run(tmp_path):
    cfg = encons.compose(
        "model=hnn_angle",
        "system=pendulum1",
        "debug=fast",
        "trainer.max_epochs=3",
        output_dir=tmp_path / "run",
        cache_dir=tmp_path / "cache",
    )
    run = encons.train(cfg)
    assert isinstance(run, encons.Run) and run.run_dir == tmp_path / "run"
    assert run.checkpoint.name.startswith("best-") and math.isfinite(run.metrics["test/traj_rel_err"])

    # the checkpoint alone (no config.yaml beside it) rebuilds the model and its test metrics
    alone = tmp_path / "elsewhere" / "checkpoints" / "model.ckpt"
    alone.parent.mkdir(parents=True)
    shutil.copy(run.checkpoint, alone)
    loaded = encons.load(alone)
    assert not (alone.parent.parent / "config.yaml").exists()
    for key, value in run.module.state_dict().items():
        assert torch.equal(loaded.module.state_dict()[key], value), key
    metrics = encons.evaluate(loaded)
    assert metrics == {k: v for k, v in run.metrics.items() if k.startswith("test/")}
    assert encons.load(run.run_dir).checkpoint == run.checkpoint  # a run folder: its best checkpoint

    # roll the loaded model out from the first test state: matches the module's own prediction
    states = loaded.data.states["test"][:2].float()  # test states are float64; the model float32
    t = torch.arange(states.shape[1], dtype=states.dtype) * loaded.data.dt
    with torch.no_grad():
        pred = encons.rollout(loaded.model, states[:, 0], t, loaded.module.integrator)
    assert pred.shape == states.shape
    assert torch.allclose(pred[:, 0], states[:, 0], atol=1e-5)
    assert not torch.allclose(pred[:, -1], states[:, -1], atol=1e-3)  # a 2-epoch model is not the truth


def test_catalogue_reads_the_config_groups():
    models = encons.catalogue("model")
    assert "node" in models and "chnn" in models and all(not m.startswith("_") for m in models)
    assert "pendulum2" in encons.catalogue("system")
