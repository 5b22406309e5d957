"""The layout of issue 49: a name is a module or a function, never both, and a config saved before the layout
(its ``_target_``s in the old flat modules) still loads."""

from __future__ import annotations

import importlib

import pytest
import torch
from omegaconf import OmegaConf

import encons
from encons.infra import checkpoints


@pytest.mark.parametrize(
    "name, says",
    [
        ("train", "encons.train is the API's function"),
        ("evaluate", "encons.evaluate is the API's function"),
        ("benchmark", "import encons.tools.benchmark"),
        ("report", "import encons.tools.report"),
        ("sweep", "import encons.tools.sweep"),
        ("control", "import encons.tools.control"),
    ],
)
def test_a_command_file_is_only_a_command(name, says):
    with pytest.raises(ImportError, match=says):
        importlib.import_module(f"encons.{name}")
    assert f"encons.{name}" not in __import__("sys").modules


def test_the_api_names_are_functions_whatever_was_imported():
    import encons.entry.api
    import encons.entry.cli  # noqa: F401 - imports every library module a command uses
    import encons.training.build  # noqa: F401

    assert encons.train is encons.entry.api.train and encons.evaluate is encons.entry.api.evaluate
    assert encons.build is encons.entry.api.build and callable(encons.build)


def test_current_targets_renames_the_moved_modules_only():
    saved = {
        "regulariser": {"_target_": "encons.regularisers.Hamiltonian", "weight": 1.0},
        "callbacks": {"best": {"_target_": "encons.callbacks.BestCheckpoint"}},
        "integrator": [{"_target_": "encons.integrators.Integrator"}],
        "model": {"_target_": "encons.models.hnn.HNN"},
        "optimizer": {"_target_": "torch.optim.Adam"},
    }
    assert checkpoints.current_targets(saved) == {
        "regulariser": {"_target_": "encons.numerics.regularisers.Hamiltonian", "weight": 1.0},
        "callbacks": {"best": {"_target_": "encons.training.callbacks.BestCheckpoint"}},
        "integrator": [{"_target_": "encons.numerics.integrators.Integrator"}],
        "model": {"_target_": "encons.models.hnn.HNN"},
        "optimizer": {"_target_": "torch.optim.Adam"},
    }


def old_names(node):
    """``node`` with every moved target written as before the layout (the inverse of ``current_targets``)."""
    if isinstance(node, dict):
        out = {k: old_names(v) for k, v in node.items()}
        for old, new in checkpoints.MOVED.items():
            if isinstance(out.get("_target_"), str) and out["_target_"].startswith(new):
                out["_target_"] = old + out["_target_"][len(new) :]
        return out
    return [old_names(v) for v in node] if isinstance(node, list) else node


def test_a_checkpoint_saved_before_the_layout_loads_and_scores_the_same(tmp_path):
    cfg = encons.compose(
        "model=node",
        "system=pendulum1",
        "debug=fast",
        "trainer.max_epochs=1",
        "figures=false",
        output_dir=tmp_path / "run",
        cache_dir=tmp_path / "cache",
    )
    run = encons.train(cfg, summary=False)
    state = torch.load(run.checkpoint, weights_only=True)
    before = old_names(state[checkpoints.CONFIG_KEY])
    assert "encons.training.callbacks." not in str(before) and "encons.callbacks." in str(before)
    state[checkpoints.CONFIG_KEY] = before
    torch.save(state, run.checkpoint)
    config_yaml = run.run_dir / "config.yaml"
    config_yaml.write_text(
        OmegaConf.to_yaml(OmegaConf.create(old_names(OmegaConf.to_container(OmegaConf.load(config_yaml)))))
    )
    again = encons.load(run.run_dir)
    assert encons.evaluate(again)["test/traj_rel_err"] == pytest.approx(run.metrics["test/traj_rel_err"], rel=1e-6)
