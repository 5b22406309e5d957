"""The stacked path of a seed ensemble (``encons.training.stacked``), family by family: K members' training steps as one
(the ensemble dimension in the layers, or vmap over the member axis) equal each member's own step."""

from __future__ import annotations

import itertools

import pytest
import torch

from encons.entry import api
from encons.entry.api import build
from encons.models.base import DynamicsModel
from encons.systems.pendulum import NPendulum
from encons.training import ensemble, stacked
from encons.training.members import StackedEnsemble
from encons.training.module import TrainingModule

#: one model of every family the papers use, at its usual system, and the stacked way it takes
FAMILIES = [
    ("hnn", "pendulum2", [], "ensemble dimension"),
    ("hnn_angle", "pendulum2", [], "ensemble dimension"),
    ("hnn_structure", "pendulum2", ["model.shared_trunk=false"], "ensemble dimension"),
    ("lnn", "pendulum2", [], "ensemble dimension"),
    ("lnn_structure_angle", "pendulum2", [], "ensemble dimension"),
    ("glnn", "damped_oscillator", ["objective=acceleration"], "ensemble dimension"),
    ("second_order", "damped_oscillator", [], "ensemble dimension"),
    ("chnn", "gyroscope", [], "ensemble dimension"),  # member-stacked masses, their per-rollout cache
    ("clnn", "gyroscope", [], "ensemble dimension"),
    ("nsf", "mass_spring", ["objective=derivative"], "ensemble dimension"),
    (
        "node",
        "mass_spring",
        ["objective=derivative", "regulariser=hamiltonian", "regulariser.weight=10"],
        "ensemble dimension",
    ),
    (
        "inn_node",
        "mass_spring",
        ["objective=derivative", "regulariser=hamiltonian", "regulariser.weight=10"],
        "ensemble dimension",
    ),
    ("node", "damped_pendulum", ["objective=derivative", "regulariser=dissipative"], "ensemble dimension"),
    ("lnode", "pendulum_control", ["evaluators.santos.steps=20"], "ensemble dimension"),
    ("symo", "pendulum_control", ["objective=residual", "evaluators.santos.steps=20"], "ensemble dimension"),
    ("e2e_symo", "pendulum_control", ["evaluators.santos.steps=20"], "ensemble dimension"),  # Newton, per member
    ("node", "pixel_pendulum", [], "ensemble dimension"),  # each member's own autoencoder
    ("node", "pixel_pendulum", ["regulariser=hamiltonian", "regulariser.weight=10"], "ensemble dimension"),
    ("inn_node", "pixel_pendulum", [], "ensemble dimension"),
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
        == "loop: observation=Autoencoder has a parameter outside nn.Linear layers and modules that define ensemble"
    )


#: Lim & Kasim's NSF cell (``benchmarks/ensemble_speed.py``, ``lim_kasim-nsf``): 2 × 200, one 30-step window
LIM_KASIM_NSF = [
    "model=nsf",
    "system=mass_spring",
    "objective=derivative",
    "optimizer=adamw",
    "model.depth=2",
    "model.hidden=200",
    "data.batch_size=1",
    "data.chunk_len=30",
    "data.n_val=2",
    "data.n_test=2",
]


def test_the_probe_asks_whether_the_stacked_code_computes_the_losses_not_how_float32_rounds(tmp_path, cache):
    """NSF at Lim & Kasim's sizes inverts a 2-form made of differences of derivatives: member 0's float32 loss on
    the first batch is itself good to ~1e-4, computed stacked or apart, and the two differ by more than the
    probe's 1e-4 (2e-4 measured). The probe compares float64 copies, where they agree, so the ensemble takes the
    ensemble dimension; a float32 probe sent it down the slower ``vmap`` path."""
    built = [
        build(api.compose(*LIM_KASIM_NSF, "logger=none", f"seed={s}", output_dir=tmp_path / f"m{s}", cache_dir=cache))
        for s in range(2)
    ]
    data, members = built[0][0], [m for _, m in built]
    cfg = api.compose(*LIM_KASIM_NSF, "logger=none", output_dir=tmp_path / "ens", cache_dir=cache)
    module = ensemble._module(cfg, members, [0, 1], data, True)
    assert module.path == "stacked (ensemble dimension)", module.path
    batch = next(iter(data.train_dataloader()))
    got = module.stacked.training_loss(batch).detach()
    want = torch.stack([m.training_loss(batch).detach() for m in members])
    assert float(((got - want).abs() / want.abs()).max()) > 1e-4  # float32 alone would have refused it
    assert stacked.probe(module.stacked, members, batch, rtol=1e-9) is None  # float64: the same code


class _Float32Mix(DynamicsModel):
    """A user's model that makes a float32 tensor of its own (a plain attribute, not a buffer): ż = net(z M)."""

    def __init__(self, system):
        super().__init__(system)
        self.net = torch.nn.Linear(2 * self.n, 2 * self.n)
        self.mix = torch.eye(2 * self.n)

    def forward(self, t, z, u=None):
        return self.net(z @ self.mix)


def test_a_model_that_runs_only_in_float32_is_probed_as_it_trains(tmp_path, cache):
    """The probe's float64 copies cannot run it (float64 @ float32 raises): its losses are compared in float32,
    and it stacks, where a float64 probe alone sent it down the loop ("the stacked field failed ... double !=
    float")."""
    data, (first,) = _members("node", "pendulum2", [], cache, tmp_path, k=1)
    torch.manual_seed(0)
    members = [
        TrainingModule(_Float32Mix(first.system), first.system, first.dt, first.integrator, first.optimizer)
        for _ in range(2)
    ]
    module = StackedEnsemble(members, [0, 1])
    assert module.path == "stacked (ensemble dimension)"
    assert stacked.probe(module.stacked, members, next(iter(data.train_dataloader()))) is None


class _Scaled(DynamicsModel):
    """A user's model with a parameter outside ``nn.Linear`` layers and no ``ensemble``: ż = e^c · net(z)."""

    def __init__(self, system):
        super().__init__(system)
        self.net = torch.nn.Linear(2 * self.n, 2 * self.n)
        self.log_gain = torch.nn.Parameter(torch.randn(()))

    def forward(self, t, z, u=None):
        return self.log_gain.exp() * self.net(z)


def test_a_model_without_an_ensemble_dimension_stacks_by_vmap():
    """Its members' fields, one ``vmap`` call over the member axis, equal each member's own (rows folded
    member-major); with the dimension asked for, there is none to take."""
    torch.manual_seed(0)
    models = [_Scaled(NPendulum(2)) for _ in range(3)]
    assert stacked.dimension_model(models) is None
    one = stacked.StackedModel(models)
    z = torch.randn(3 * 5, 4)
    want = torch.cat([m(torch.zeros(()), z[5 * k : 5 * (k + 1)]) for k, m in enumerate(models)])
    assert torch.allclose(one(torch.zeros(()), z), want, rtol=1e-6, atol=1e-7)
    with torch.no_grad():  # and member k's slices go back into its own model
        for weight in one.weights:
            weight.add_(torch.arange(3.0).reshape(-1, *[1] * (weight.dim() - 1)))
    one.copy_to(models)
    stacks = dict(zip(one.names, one.weights))
    assert all(torch.equal(p, stacks[n][k]) for k, m in enumerate(models) for n, p in m.named_parameters())


def test_an_ensemble_linear_is_its_members_layers_and_takes_its_gradient_as_it_comes():
    """K ``nn.Linear`` as one ``EnsembleLinear``: each member's outputs and weight gradients (float64, to 1e-12);
    the weight's gradient arrives in the parameter's own layout (Wᵀ row-major), so autograd keeps the product's
    result instead of copying it into another layout (no ``copy_`` of a weight's size in the backward), and
    ``copy_members`` writes each member's (out, in) weight back."""
    from encons.models.networks import EnsembleLinear

    torch.manual_seed(0)
    layers = [torch.nn.Linear(5, 7).double() for _ in range(3)]
    stack = EnsembleLinear(layers)
    x = torch.randn(3, 4, 5, dtype=torch.float64)
    out = stack(x)
    for k, layer in enumerate(layers):
        assert torch.allclose(out[k], layer(x[k]), atol=1e-12)
        layer(x[k]).pow(2).sum().backward()
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CPU], record_shapes=True) as prof:
        out.pow(2).sum().backward()
    copies = [e.input_shapes for e in prof.events() if e.name == "aten::copy_" and [3, 7, 5] in e.input_shapes]
    assert not copies  # (K, out, in) weights: the gradient copied into the parameter's layout
    grad = stack.weight_t.grad
    assert grad is not None and grad.stride() == stack.weight_t.stride()
    for k, layer in enumerate(layers):
        assert torch.allclose(stack.weight[k], layer.weight) and torch.allclose(
            grad[k].T, layer.weight.grad, atol=1e-12
        )
    with torch.no_grad():
        stack.weight_t.add_(1.0)
    stacked.copy_members(torch.nn.Sequential(stack), [torch.nn.Sequential(layer) for layer in layers])
    for k, layer in enumerate(layers):
        assert torch.equal(layer.weight, stack.weight[k]) and torch.equal(layer.bias, stack.bias[k])
