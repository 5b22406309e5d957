"""Inputs and starts of the controlled systems' data (``system.inputs``, ``system.init_center``): per-step
random inputs vary within a trajectory, come back from the seed and change the cache key; multisine inputs
stay within u_max; starts near a chosen state stay in its box."""

from __future__ import annotations

import pytest
import torch

from encons.entry import api
from encons.entry.api import build
from encons.infra.errors import ConfigError
from encons.systems.controlled import CartPole, ControlledPendulum

FAST = ["debug=fast", "logger=none", "trainer.enable_progress_bar=false", "~evaluators/santos", "model=lnode"]


def data_of(tmp_path, *overrides):
    cfg = api.compose(*FAST, "system=cartpole", *overrides, output_dir=tmp_path / "run", cache_dir=tmp_path / "cache")
    return build(cfg)[0]


def test_per_step_inputs_vary_within_a_trajectory_come_back_from_the_seed_and_change_the_cache_key(tmp_path):
    steps = data_of(tmp_path / "a", "system.inputs=steps")
    again = data_of(tmp_path / "b", "system.inputs=steps")
    constant = data_of(tmp_path / "c")
    u = steps.arrays["train"]["u"]  # (N, T, 1)
    assert u.shape == (16, 11, 1)
    assert (u.std(1) > 0.3).all()  # every trajectory's input changes over time
    assert (u[:, 1:] != u[:, :-1]).float().mean() > 0.99  # a fresh value every step
    assert u.abs().max() <= 2.0
    torch.testing.assert_close(again.arrays["train"]["u"], u, rtol=0, atol=0)  # the same seed, the same inputs
    torch.testing.assert_close(again.arrays["train"]["states"], steps.arrays["train"]["states"], rtol=0, atol=0)
    assert (constant.arrays["train"]["u"].std(1) == 0).all()  # Santos et al.'s one input per trajectory
    assert steps.cache_file.name != constant.cache_file.name
    assert steps.cache_file.name == again.cache_file.name
    other_seed = data_of(tmp_path / "d", "system.inputs=steps", "data.seed=1")
    assert not torch.equal(other_seed.arrays["train"]["u"], u)


def test_multisine_inputs_are_bounded_smooth_and_differ_per_trajectory():
    system = ControlledPendulum(inputs="multisine", tones=4)
    t = torch.arange(33, dtype=torch.float64) * 0.1
    u = system.sample_inputs(64, t, torch.Generator().manual_seed(0))
    assert u.shape == (64, 33, 1) and u.abs().max() <= system.u_max
    assert (u.std(1) > 0.05).all() and u[:, 0].std() > 0.1
    # band-limited: the highest tone (4 periods per span) moves a sample by at most 2π·4/3.2·Σa·dt
    assert u.diff(dim=1).abs().max() <= 2 * torch.pi * 4 / 3.2 * system.u_max * 0.1 + 1e-12


def test_starts_near_a_chosen_state_stay_in_its_box():
    center, half = [0.2, 0.0, 0.0, 0.0], [0.1, 0.05, 0.0, 0.2]
    s = CartPole(init_center=center, init_range=half).sample_initial(500, torch.Generator().manual_seed(0))
    assert ((s - torch.tensor(center, dtype=torch.float64)).abs() <= torch.tensor(half, dtype=torch.float64)).all()
    assert s[:, 0].min() < 0.12 and s[:, 0].max() > 0.28  # spread over the box


@pytest.mark.parametrize(
    "kw,match",
    [
        ({"inputs": "chirp"}, r"^system.inputs=chirp; allowed: constant, steps, multisine$"),
        ({"init_center": [0.0]}, r"^system.init_center=\[0.0\]; allowed: null"),
    ],
)
def test_bad_input_and_start_options_are_refused_in_one_line(kw, match):
    with pytest.raises(ConfigError, match=match):
        CartPole(**kw)
