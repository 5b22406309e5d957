"""The System seam: the Cartesian point-system base (``encons.systems.base.PointSystem``) gives the
pendulums and the gyroscope the numbers they had before it — fields, energies, chart maps, constraints
and mass matrices in both charts, against ``tests/systems/point_systems_main.npz``, computed on main
before the base existed by the ``values()`` below run with main's encons first on ``sys.path`` — and
physics a system does not know is one error type wherever it is asked for."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from encons.data.from_file import FileSystem
from encons.infra.errors import PhysicsError
from encons.systems.base import PointSystem
from encons.systems.damped_pendulum import DampedPendulum
from encons.systems.gyroscope import Gyroscope
from encons.systems.latent import LatentSystem
from encons.systems.mass_spring import MassSpring
from encons.systems.pendulum import NPendulum

REFERENCE = Path(__file__).parent / "point_systems_main.npz"


def systems() -> dict:
    return {
        "pendulum2": NPendulum(n_links=2),
        "pendulum4": NPendulum(n_links=4, masses=[1.0, 2.0, 1.5, 1.0], lengths=[1.0, 0.5, 1.0, 0.7], g=3.0),
        "damped_pendulum": DampedPendulum(),
        "gyroscope": Gyroscope(),
    }


def values() -> dict[str, np.ndarray]:
    out = {}
    for name, system in systems().items():
        s = system.sample_initial(5, torch.Generator().manual_seed(0))
        angle = system.to_chart(s, system.base_chart, "angle")
        cart = system.to_chart(angle, "angle", "cartesian")
        out[f"{name}/angle"], out[f"{name}/cartesian"] = angle, cart
        for chart, st in (("angle", angle), ("cartesian", cart)):
            out[f"{name}/field_{chart}"] = system.vector_field(st, chart)
            out[f"{name}/energy_{chart}"] = system.energy(st, chart)
        out[f"{name}/back_to_angle"] = system.to_chart(cart, "cartesian", "angle")
        out[f"{name}/constraints"] = system.constraints(cart[..., : system.coord_dim("cartesian")])
        out[f"{name}/point_masses"] = system.point_masses()
        out[f"{name}/mass_matrix"] = system.mass_matrix(angle[..., : system.coord_dim("angle")])
    return {k: v.detach().numpy() for k, v in out.items()}


def test_pendulums_and_gyroscope_share_the_point_system_base():
    assert all(isinstance(system, PointSystem) for system in systems().values())


@pytest.mark.parametrize("name", ["pendulum2", "pendulum4", "damped_pendulum", "gyroscope"])
def test_point_systems_give_the_numbers_they_gave_before_the_base(name):
    now = values()
    with np.load(REFERENCE) as before:
        keys = [k for k in before.files if k.startswith(f"{name}/")]
        assert len(keys) == 10
        for key in keys:  # the kinetic energy sums Σ v·(M v) in another order: ulps, not more
            np.testing.assert_allclose(now[key], before[key], rtol=1e-13, atol=1e-13, err_msg=key)


def test_missing_physics_is_one_error_type_everywhere(tmp_path):
    path = tmp_path / "file.npz"
    traj = np.zeros((2, 3, 2))
    np.savez(path, t=np.arange(3) * 0.1, train=traj, test=traj)
    s, gen = torch.zeros(1, 2, dtype=torch.float64), torch.Generator()
    for system in (FileSystem(str(path)), LatentSystem(2, NPendulum(1))):
        for ask in (
            lambda: system.vector_field(s, "angle"),
            lambda: system.energy(s, "angle"),
            lambda: system.sample_initial(1, gen),
            lambda: system.mass_matrix(s[..., :1]),
        ):
            with pytest.raises(PhysicsError, match=f"^system '{system.name}' has no known "):
                ask()
    with pytest.raises(PhysicsError, match="has no known holonomic constraints"):
        MassSpring().constraints(s)
    with pytest.raises(PhysicsError, match="has no known frames"):
        NPendulum(1).render(s, "angle")
