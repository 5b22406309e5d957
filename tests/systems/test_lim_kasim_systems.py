"""Lim & Kasim's four systems and the derivative objective's data: closed forms and protocols."""

from __future__ import annotations

import math

import pytest
import torch
from hydra.utils import instantiate
from torch.func import jvp
from torchdiffeq import odeint

from encons.data import store
from encons.data.datamodule import TrajectoryDataModule
from encons.data.simulate import simulate
from encons.systems.damped_pendulum import DampedPendulum
from encons.systems.mass_spring import MassSpring
from encons.systems.pendulum import NPendulum
from encons.training.build import compose


def test_mass_spring_follows_the_closed_form():
    system = MassSpring(mass=2.0, stiffness=8.0)
    s0 = torch.tensor([[0.3, -1.1], [-1.0, 0.4]], dtype=torch.float64)
    t = torch.linspace(0, 5, 51, dtype=torch.float64)
    traj = simulate(system, s0, t)
    w = 2.0
    q = s0[:, :1] * torch.cos(w * t) + s0[:, 1:] / w * torch.sin(w * t)
    assert torch.allclose(traj[..., 0], q, atol=1e-7)
    energy = system.energy(traj, "angle")
    assert torch.allclose(energy, energy[:, :1], rtol=1e-8)


def test_damped_pendulum_fields_agree_across_charts_and_dissipate_energy():
    system = DampedPendulum(damping=0.05)
    angle = torch.randn(64, 2, dtype=torch.float64)
    cart, pushed = jvp(
        lambda s: system.to_chart(s, "angle", "cartesian"), (angle,), (system.vector_field(angle, "angle"),)
    )
    assert torch.allclose(system.vector_field(cart, "cartesian"), pushed, atol=1e-10)
    assert torch.allclose(system.vector_field(angle, "angle")[:, 1], -torch.sin(angle[:, 0]) - 0.05 * angle[:, 1])
    for chart, s in (("angle", angle), ("cartesian", cart)):
        rate = jvp(lambda x: system.energy(x, chart), (s,), (system.vector_field(s, chart),))[1]
        assert torch.allclose(rate, -0.05 * angle[:, 1] ** 2, atol=1e-10)


def test_damped_pendulum_simulated_in_cartesian_matches_the_angle_chart():
    system = DampedPendulum()
    s0 = system.sample_initial(4, torch.Generator().manual_seed(0))
    t = torch.arange(8, dtype=torch.float64) * 2 * math.pi / 29
    cart = simulate(system, s0, t)
    ref = odeint(
        lambda _, s: system.vector_field(s, "angle"),
        system.to_chart(s0, "cartesian", "angle"),
        t,
        method="rk4",
        options={"step_size": t[1].item() / 10},
    ).movedim(0, 1)
    assert torch.allclose(cart, system.to_chart(ref, "angle", "cartesian"), atol=1e-6)
    assert system.constraints(cart[..., :2]).abs().max() < 1e-6


@pytest.mark.parametrize(
    "name, dt, steps, test_t",
    [
        ("mass_spring", 2 * math.pi / 29, 29, 100.0),
        ("pendulum", 2 * math.pi / 29, 29, 100.0),
        ("double_pendulum", 2 * math.pi / 299, 299, 100.0),
        ("damped_pendulum", 2 * math.pi / 29, 29, 100.0),
    ],
)
def test_system_configs_follow_the_paper_protocol(tmp_path, name, dt, steps, test_t):
    cfg = compose([f"system={name}"], tmp_path)
    assert cfg.data.dt == pytest.approx(dt, rel=1e-12) and cfg.data.n_steps == steps
    assert cfg.data.test_steps * dt >= test_t > (cfg.data.test_steps - 1) * dt
    assert cfg.data.n_test == 100 and cfg.data.n_train == (2000 if name == "double_pendulum" else 250)
    assert cfg.data.noise == (0.0 if name == "double_pendulum" else 0.1)
    system = instantiate(cfg.system)
    if name == "pendulum":
        q = torch.tensor([[0.7, 0.0]], dtype=torch.float64)
        assert system.vector_field(q, "angle")[0, 1].item() == pytest.approx(-3.0 * math.sin(0.7))


def derivative_data(tmp_path, system, chart, **kwargs) -> TrajectoryDataModule:
    dm = TrajectoryDataModule(
        system,
        chart,
        n_train=6,
        n_val=2,
        n_test=2,
        n_steps=40,
        dt=0.01,
        noise=0.0,
        substeps=2,
        chunk_len=5,
        batch_size=6,
        cache_dir=str(tmp_path),
        objective="derivative",
        **kwargs,
    )
    dm.prepare_data()
    dm.setup()
    return dm


def test_derivative_targets_are_the_true_field_in_the_served_chart(tmp_path):
    system = NPendulum(n_links=2)
    dm = derivative_data(tmp_path, system, "cartesian")
    batch = next(iter(dm.train_dataloader()))
    states, rates = batch["states"], batch["rates"]
    assert states.shape == rates.shape == (6, 5, 8)
    assert torch.allclose(rates.double(), system.vector_field(states.double(), "cartesian"), atol=1e-4)


def test_derivative_targets_of_loaded_data_are_central_differences(tmp_path):
    system = MassSpring()
    t = torch.arange(41, dtype=torch.float64) * 0.01
    s0 = torch.randn(6, 2, dtype=torch.float64)
    traj = simulate(system, s0, t)
    store.save(tmp_path / "user.npz", t, {"train": traj, "test": traj[:2]}, "angle")
    dm = derivative_data(tmp_path, system, "angle", path=str(tmp_path / "user.npz"))
    true = system.vector_field(dm.states["train"].double(), "angle")
    rates = dm.arrays["train"]["rates"].double()
    assert torch.allclose(rates, true, atol=1e-4)
    assert not torch.allclose(rates, true, atol=1e-6)
