"""Santos et al. end to end: each new model × new system trains on a tiny config and reports the §7
metrics; SyMo learns the pendulum's true inertia from positions and known controls alone."""

from __future__ import annotations

import math

import pytest
import torch

from encons.infra.errors import ConfigError
from tests.helpers import SANTOS_TINY

SANTOS_KEYS = ("mse_train", "mse_test", "mse_integration", "energy_mse_integration")
TINY = [*SANTOS_TINY, "data.chunk_len=3"]


@pytest.mark.slow
@pytest.mark.parametrize("system", ["cartpole"])  # pendulum_control: every model, §7 included, in test_train_e2e
@pytest.mark.parametrize("model", ["symo", "e2e_symo", "lnode", "lnode+midpoint", "node"])
def test_model_trains_end_to_end_with_the_section_7_metrics(train_run, model, system):
    name, _, integrator = model.partition("+")
    extra = [f"integrator={integrator}"] if integrator else []
    results = train_run([f"model={name}", f"system={system}", *TINY, *extra])
    for key in SANTOS_KEYS + ("train/loss", "test/traj_rel_err"):
        key = key if "/" in key else f"test/{key}"
        assert math.isfinite(results[key]), key
    assert ("test/mass_mse" in results) == (name != "node")  # models with a learned M(q)
    # beside each one-step MSE, its floor: the true dynamics stepped as this model steps (far below a tiny run's)
    assert results["test/mse_test_floor"] < results["test/mse_test"] / 100


@pytest.mark.parametrize(
    "overrides, match",
    [
        (["model=symo", "integrator=midpoint"], "integrator=midpoint does not apply to model=symo"),
        (["model=e2e_symo", "objective=derivative"], "objective=derivative does not apply to model=e2e_symo"),
        (["model=lnode", "objective=residual"], "objective=residual does not apply to model=lnode"),
        (["model=symo", "model.train_tol=0"], "model.train_tol=0"),
        (["model=symo", "system=cartpole", "system.u_max=-1"], "system.u_max=-1"),
        (["model=hnn", "system=cartpole"], "cannot take control inputs"),
    ],
)
def test_incompatible_santos_configs_are_one_line_errors(tmp_path, overrides, match):
    from encons.entry.api import build
    from encons.training.build import compose

    with pytest.raises(ConfigError, match=match):
        build(compose(["debug=fast", "system=pendulum_control", *overrides], tmp_path / "run", tmp_path / "c"))


def test_symo_learns_the_true_inertia_of_the_pendulum(tmp_path):
    """From 32 noiseless trajectories, the DEL residual (eq. (15)) fixes M = m l²/3 (the known
    controls set the scale of L); 400 Adam steps on whole trajectories bring M(q) within 1e-3."""
    from encons.entry.api import build
    from encons.training.build import compose

    torch.manual_seed(0)
    cfg = compose(
        [
            "model=symo",
            "system=pendulum_control",
            "logger=none",
            "data.n_train=32",
            "data.chunk_len=33",
            "data.batch_size=32",
            "model.hidden=32",
        ],
        tmp_path / "run",
        tmp_path / "c",
    )
    data, module = build(cfg)
    batch = next(iter(data.train_dataloader()))
    first = module.loss(batch).item()
    opt = torch.optim.Adam(module.parameters(), lr=3e-3)
    for _ in range(400):
        opt.zero_grad()
        module.loss(batch).backward()
        opt.step()
    assert module.loss(batch).item() < first / 1000
    q = torch.linspace(-math.pi, math.pi, 64)[:, None]
    assert (module.model.mass(q) - 1 / 3).abs().max() < 1e-2


@pytest.mark.parametrize("model", ["node", "e2e_symo"])
def test_onestep_objective_is_the_mse_of_each_state_from_the_true_states_before_it(tmp_path, model):
    """Santos et al. §7's loss: every state of a window predicted from the ``history`` true states before
    it (NODE: one, E2E-SyMo: two), squared error averaged over predictions and coordinates."""
    from encons.entry import api

    torch.manual_seed(0)
    cfg = api.compose(
        f"model={model}",
        "system=pendulum_control",
        "experiment=symo_paper",
        "logger=none",
        "data.n_train=3",
        "data.batch_size=3",
        "model.hidden=8",
        output_dir=tmp_path / "run",
        cache_dir=tmp_path / "cache",
    )
    data, module = api.build(cfg)
    data.setup("fit")
    batch = next(iter(data.train_dataloader()))
    states, u, h = batch["states"], batch["u"], module.model.history
    assert module.objective == "onestep" and states.shape[1] == 33
    errors = []
    for k in range(h, states.shape[1]):
        one = {"states": states[:, k - h : k + 1], "u": u[:, k - h : k + 1]}
        errors.append((module.predict(one)[:, -1] - states[:, k]).square())
    with torch.no_grad():
        assert torch.allclose(module.loss(batch), torch.stack(errors).mean(), rtol=1e-5)
