"""The stacked path of a seed ensemble (``encons.training.stacked``), family by family: K members' training steps as one
(the ensemble dimension in the layers, or vmap over the member axis) equal each member's own step."""

from __future__ import annotations

import itertools

import pytest
import torch

from encons.entry import api
from encons.entry.api import build
from encons.training import ensemble, stacked

#: one model of every family the papers use, at its usual system, and the stacked way it takes
FAMILIES = [
    ("hnn", "pendulum2", [], "ensemble dimension"),
    ("hnn_angle", "pendulum2", [], "ensemble dimension"),
    ("hnn_structure", "pendulum2", ["model.shared_trunk=false"], "ensemble dimension"),
    ("lnn", "pendulum2", [], "ensemble dimension"),
    ("lnn_structure_angle", "pendulum2", [], "ensemble dimension"),
    ("glnn", "damped_oscillator", ["objective=acceleration"], "ensemble dimension"),
    ("second_order", "damped_oscillator", [], "ensemble dimension"),
    ("chnn", "gyroscope", [], "vmap"),
    ("clnn", "gyroscope", [], "vmap"),
    ("nsf", "mass_spring", ["objective=derivative"], "ensemble dimension"),
    (
        "node",
        "mass_spring",
        ["objective=derivative", "regulariser=hamiltonian", "regulariser.weight=10"],
        "ensemble dimension",
    ),
    ("inn_node", "mass_spring", ["objective=derivative", "regulariser=hamiltonian", "regulariser.weight=10"], "vmap"),
    ("node", "damped_pendulum", ["objective=derivative", "regulariser=dissipative"], "ensemble dimension"),
    ("lnode", "pendulum_control", ["evaluators.santos.steps=20"], "ensemble dimension"),
    ("symo", "pendulum_control", ["objective=residual", "evaluators.santos.steps=20"], "ensemble dimension"),
    ("e2e_symo", "pendulum_control", ["evaluators.santos.steps=20"], "ensemble dimension"),  # Newton, per member
    ("node", "pixel_pendulum", [], "ensemble dimension"),  # each member's own autoencoder
    ("node", "pixel_pendulum", ["regulariser=hamiltonian", "regulariser.weight=10"], "ensemble dimension"),
    ("inn_node", "pixel_pendulum", [], "vmap"),  # the autoencoder's layers stacked beside a vmapped model
]


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("cache")


def _members(model, system, extra, cache, tmp_path, k=2):
    built = [
        build(
            api.compose(
                f"model={model}",
                f"system={system}",
                "debug=fast",
                "logger=none",
                *extra,
                f"seed={s}",
                output_dir=tmp_path / f"m{s}",
                cache_dir=cache,
            )
        )
        for s in range(k)
    ]
    return built[0][0], [m for _, m in built]


@pytest.mark.parametrize("model, system, extra, way", FAMILIES, ids=lambda v: v if isinstance(v, str) else None)
def test_stacked_steps_equal_each_members_own(tmp_path, cache, model, system, extra, way):
    """Four batches, three AdamW steps between them: the stacked losses equal the members' separate ones (relative
    1e-4) at each, the last after the steps, and the path says which stacked way it took. (Weights are not compared
    entry by entry: Adam turns the rounding noise of a gradient that is ~0, e.g. of a weight LNN's separable start
    zeroes, into a step of ±lr.)"""
    data, members = _members(model, system, extra, cache, tmp_path)
    _, twins = _members(model, system, extra, cache, tmp_path)  # the separate runs, trained apart
    cfg = api.compose(
        f"model={model}",
        f"system={system}",
        "debug=fast",
        "logger=none",
        *extra,
        output_dir=tmp_path / "ens",
        cache_dir=cache,
    )
    module = ensemble._module(cfg, members, [0, 1], data, True)
    assert module.path == f"stacked ({way})", module.path
    opt = stacked.optimizer(members[0].optimizer, list(module.stacked.parameters()))
    opts = [t.optimizer(t.parameters()) for t in twins]
    batches = itertools.cycle(list(data.train_dataloader()))
    for _ in range(4):
        batch = next(batches)
        losses = module.stacked.training_loss(batch)
        want = []
        for twin, o in zip(twins, opts):
            o.zero_grad()
            loss = twin.training_loss(batch)
            loss.backward()
            o.step()
            want.append(loss.detach())
        assert losses.detach() == pytest.approx(torch.stack(want), rel=1e-4)
        opt.zero_grad()
        losses.sum().backward()
        opt.step()


def test_a_loop_is_kept_only_with_its_reason(tmp_path, cache):
    """An observation model with a parameter outside ``nn.Linear`` layers (here a scale added to the pixel
    models' autoencoder) has no stacked copy: the loop, saying so in full."""
    data, members = _members("node", "pixel_pendulum", [], cache, tmp_path)
    for member in members:
        member.observation.scale = torch.nn.Parameter(torch.ones(()))
    cfg = api.compose(
        "model=node", "system=pixel_pendulum", "debug=fast", "logger=none", output_dir=tmp_path / "e", cache_dir=cache
    )
    assert (
        ensemble._module(cfg, members, [0, 1], data, None).path
        == "loop: observation=Autoencoder has a parameter outside nn.Linear layers"
    )
