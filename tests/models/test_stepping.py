"""The stepping seam: inputs u beside the state, discrete models, capability checks, and the
metrics of the existing models pinned from before the seam existed."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from omegaconf import open_dict
from torch import Tensor, nn

from encons.data import store
from encons.infra.errors import ConfigError, DataError
from encons.models.base import DiscreteModel, DynamicsModel
from encons.numerics.integrators import Integrator, rollout
from encons.systems.base import System, split_state
from encons.training.build import compose

K, MASS = 2.0, 0.5  # ForcedSpring: m q̈ = −k q + u


class ForcedSpring(System):
    """A unit test system with one input: m q̈ = −k q + u (closed forms below)."""

    name = "forced_spring"
    charts = ("angle",)
    common_chart = "angle"
    n_controls = 1

    def coord_dim(self, chart: str) -> int:
        return 1

    def vector_field(self, s: Tensor, chart: str, u: Tensor | None = None) -> Tensor:
        q, qd = split_state(s)
        return torch.cat([qd, (-K * q + (0 if u is None else u)) / MASS], -1)

    def energy(self, s: Tensor, chart: str) -> Tensor:
        q, qd = split_state(s)
        return (0.5 * MASS * qd**2 + 0.5 * K * q**2).squeeze(-1)

    def sample_initial(self, n: int, generator: torch.Generator) -> Tensor:
        return torch.randn(n, 2, generator=generator, dtype=torch.float64)

    def sample_controls(self, n: int, generator: torch.Generator) -> Tensor:
        return 2 * torch.rand(n, 1, generator=generator, dtype=torch.float64) - 1


class TrueField(DynamicsModel):
    """The true field of a system as a model (for exactness checks)."""

    supports_controls = True

    def __init__(self, system: System):
        super().__init__(system)
        self.system = system

    def forward(self, t, z, u=None):
        return self.system.field(z, "angle", u)


class VerletStepper(DiscreteModel):
    """q_{k+1} = 2 q_k − q_{k−1} + h² (a q_k + b u_k): a learnable linear force, Störmer–Verlet steps."""

    supports_controls = True
    objectives = ("residual", "rollout")

    def __init__(self, system: System, chart: str | None = None):
        super().__init__(system, chart)
        self.a, self.b = nn.Parameter(torch.zeros(())), nn.Parameter(torch.zeros(()))

    def step(self, q_prev, q, u, h):
        return 2 * q - q_prev + h**2 * (self.a * q + self.b * u)

    def residual(self, states, t, u=None):
        q, h = states[..., :1], float(t[1] - t[0])
        return q[..., 2:, :] - self.step(q[..., :-2, :], q[..., 1:-1, :], u[..., 1:-1, :], h)

    def rollout(self, start, t, u=None):
        h, qs = float(t[1] - t[0]), [start[..., 0, :1], start[..., 1, :1]]
        for k in range(1, len(t) - 1):
            qs.append(self.step(qs[-2], qs[-1], u[..., k, :], h))
        q = torch.stack(qs, -2)
        qd = torch.cat([start[..., :2, 1:], (q[..., 2:, :] - q[..., 1:-1, :]) / h], -2)
        return torch.cat([q, qd], -1)


def test_inputs_are_held_over_each_step_of_a_rollout():
    """m q̈ = −k q + u_k on [t_k, t_{k+1}): RK4 with fine substeps matches the exact piecewise solution."""
    system = ForcedSpring()
    t = torch.arange(6, dtype=torch.float64) * 0.3
    s0 = torch.tensor([[0.4, -0.2]], dtype=torch.float64)
    u = torch.tensor([[[1.0], [-2.0], [0.5], [3.0], [0.0], [9.0]]], dtype=torch.float64)
    pred = rollout(TrueField(system), s0, t, Integrator("rk4", substeps=50), u)
    w, exact, s = math.sqrt(K / MASS), [s0[0]], s0[0]
    for k in range(5):  # harmonic oscillator about the shifted rest point u_k / k over one step
        rest, (q, v), h = float(u[0, k, 0]) / K, s.tolist(), 0.3
        q = rest + (q - rest) * math.cos(w * h) + v / w * math.sin(w * h)
        v = -(s[0] - rest) * w * math.sin(w * h) + s[1] * math.cos(w * h)
        s = torch.tensor([q, float(v)], dtype=torch.float64)
        exact.append(s)
    assert torch.allclose(pred[0], torch.stack(exact), atol=1e-9)
    unheld = rollout(TrueField(system), s0, t, Integrator("rk4", substeps=50), u.roll(1, -2))
    assert not torch.allclose(unheld[0], torch.stack(exact), atol=1e-3)


def test_store_round_trips_constant_and_per_step_inputs(tmp_path):
    t = torch.arange(4, dtype=torch.float64)
    splits = {"train": torch.zeros(3, 4, 2), "test": torch.zeros(2, 4, 2)}
    per_step = torch.arange(24, dtype=torch.float64).reshape(3, 4, 2)
    store.save(tmp_path / "a.npz", t, splits, "angle", {"train": per_step, "test": torch.ones(2, 4, 2)})
    _, loaded, _ = store.load(tmp_path / "a.npz")
    inputs = store.load_inputs(tmp_path / "a.npz", loaded, 2)
    assert torch.equal(inputs["train"], per_step) and inputs["test"].shape == (2, 4, 2)
    np.savez(
        tmp_path / "b.npz",
        t=t.numpy(),
        train=np.zeros((3, 4, 2)),
        test=np.zeros((2, 4, 2)),
        u_train=np.array([[1.0], [2.0], [3.0]]),
        u_test=np.ones((2, 1)),
    )
    _, loaded, _ = store.load(tmp_path / "b.npz")
    assert torch.equal(
        store.load_inputs(tmp_path / "b.npz", loaded, 1)["train"][:, :, 0],
        torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64)[:, None].expand(3, 4),
    )


@pytest.mark.parametrize(
    "arrays, match",
    [
        ({}, "lacks 'u_train'"),
        ({"u_train": np.ones((3, 2)), "u_test": np.ones((2, 1))}, "u_train' has shape"),
        ({"u_train": np.ones((3, 5, 1)), "u_test": np.ones((2, 1))}, "u_train' has shape"),
        ({"u_train": np.full((3, 1), np.nan), "u_test": np.ones((2, 1))}, "NaN"),
    ],
)
def test_bad_inputs_in_a_file_are_one_clear_error(tmp_path, arrays, match):
    t = np.arange(4.0)
    np.savez(tmp_path / "c.npz", t=t, train=np.zeros((3, 4, 2)), test=np.zeros((2, 4, 2)), **arrays)
    _, loaded, _ = store.load(tmp_path / "c.npz")
    with pytest.raises(DataError, match=match) as err:
        store.load_inputs(tmp_path / "c.npz", loaded, 1)
    assert "allowed" in str(err.value) or "NaN" in match


@pytest.fixture(autouse=True)
def trust_this_module(monkeypatch):
    """The toy system and models below are config targets: trust them (Hydra's execution whitelist)."""
    monkeypatch.setenv("ENCONS_TRUSTED_TARGETS", f"{__name__}.*")


def toy_config(tmp_path, model: str, *overrides: str):
    cfg = compose(["debug=fast", "model=node", *overrides], tmp_path / "run", tmp_path / "cache")
    with open_dict(cfg):
        cfg.system = {"_target_": f"{__name__}.ForcedSpring"}
        if model != "node":
            cfg.model = {"_target_": f"{__name__}.{model}"}
    return cfg


def test_controlled_data_reach_training_rollouts_and_regularisers(tmp_path):
    from encons.entry.api import build, train

    data, module = build(toy_config(tmp_path, "node"))
    batch = next(iter(data.train_dataloader()))
    assert batch["u"].shape == (8, 5, 1) and bool((batch["u"] == batch["u"][:, :1]).all())
    data.setup()
    test = next(iter(data.test_dataloader()))
    # the served test states are the simulator's under the served inputs
    truth = rollout(
        TrueField(ForcedSpring()),
        test["states"][:, 0].double(),
        torch.arange(11, dtype=torch.float64) * data.dt,
        Integrator("rk4", substeps=10),
        test["u"].double(),
    )
    assert torch.allclose(truth, test["states"], atol=1e-5)  # test states are served in float64
    results = train(toy_config(tmp_path, "node", "regulariser=hamiltonian")).metrics
    assert math.isfinite(results["test/traj_rel_err"]) and math.isfinite(results["train/regulariser"])


def test_a_discrete_model_learns_its_force_from_the_residual(tmp_path):
    from encons.entry.api import build

    cfg = toy_config(tmp_path, "VerletStepper", "data.noise=0", "data.n_train=64", "data.dt=0.05")
    data, module = build(cfg)
    assert module.objective == "residual"
    batch = next(iter(data.train_dataloader()))
    first = module.loss(batch).item()
    opt = torch.optim.Adam(module.parameters(), lr=0.05)
    for _ in range(300):
        opt.zero_grad()
        module.loss(batch).backward()
        opt.step()
    assert module.loss(batch).item() < first / 100
    assert module.model.a.item() == pytest.approx(-K / MASS, rel=0.05)
    assert module.model.b.item() == pytest.approx(1 / MASS, rel=0.05)
    pred = module.predict(batch)  # rollout from the first two states
    assert torch.equal(pred[:, :2, 0], batch["states"][:, :2, 0])
    assert (pred[..., 0] - batch["states"][..., 0]).abs().max() < 1e-3  # positions; q̇ is a crude difference


@pytest.mark.parametrize(
    "model, overrides, match",
    [
        ("VerletStepper", ["objective=derivative"], "objective=derivative does not apply"),
        ("VerletStepper", ["regulariser=hamiltonian"], "needs a vector field"),
        ("VerletStepper", ["integrator=euler"], "integrator=euler does not apply"),
        ("TrueField", ["objective=residual"], "objective=residual does not apply"),
    ],
)
def test_what_a_model_does_not_support_is_one_error_naming_the_key(tmp_path, model, overrides, match):
    from encons.entry.api import build

    with pytest.raises(ConfigError, match=match):
        build(toy_config(tmp_path, model, *overrides))


def test_a_controlled_system_refuses_a_model_without_inputs(tmp_path):
    from encons.entry.api import build

    cfg = toy_config(tmp_path, "node")
    with open_dict(cfg):
        cfg.model = {"_target_": "encons.models.hnn.HNN", "hidden": 8, "depth": 1}
    with pytest.raises(ConfigError, match="cannot take control inputs.*allowed"):
        build(cfg)


# train/loss of the last step of a debug=fast run, recorded before the seam existed (commit a30d6e2)
PINNED = {
    ("model=node", "system=pendulum1"): 1.5838478803634644,
    ("model=hnn", "system=pendulum2"): 4.321069717407227,
    ("model=chnn", "system=gyroscope", "optimizer=adamw", "scheduler=none"): 7.340567588806152,  # the optimiser of then
    (
        "model=lnn_structure_angle",
        "system=pendulum1",
        "model.shared_trunk=false",
    ): 1.467573642730713,  # the two networks of then
    ("model=node", "system=mass_spring", "regulariser=hamiltonian", "objective=derivative"): 2.1088972091674805,
    ("model=inn_node", "system=damped_pendulum", "regulariser=dissipative"): 3.886685371398926,
}


@pytest.mark.parametrize("overrides", list(PINNED), ids=lambda o: "-".join(x.split("=")[1] for x in o))
def test_existing_models_train_as_before_the_seam(train_run, overrides):
    assert train_run(list(overrides))["train/loss"] == pytest.approx(PINNED[overrides], rel=1e-5)
