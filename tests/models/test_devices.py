"""Every tensor a model, system, metric or integrator creates follows its inputs' device and dtype:
one training step (loss and backward) of every catalogue model on three simulated systems (one per
code path: a rigid body in both charts, controls, pixels) where it can serve them, on the ``meta`` device (devices,
dtypes and shapes only: a tensor created on the CPU beside meta ones fails the step) and, where present, on every
simulated system on CUDA (``gpu`` mark), its loss compared with the CPU's float64 loss, and a whole tiny run (one model,
an ensemble) there.

Meta tensors hold no values, so on meta three value reads are stood in for: torchdiffeq's
fixed-grid loop (it reads the times' values to build its grid) is replaced by the same method's own
step function over the given times, the integrator's step size (read from the times) is left out, and
SyMo's Newton iteration stops at its iteration count (``model.train_iters=0``) rather than its tolerance.
"""

from __future__ import annotations

import copy

import pytest
import torch
from torchdiffeq._impl.odeint import SOLVERS

import encons.numerics.integrators
from encons.entry import api
from encons.infra.errors import ConfigError
from tests.helpers import simulated_systems

FLAGSHIP = "gyroscope"
SYSTEMS = [s if s == FLAGSHIP else pytest.param(s, marks=pytest.mark.slow) for s in simulated_systems()]
#: On meta: a rigid body in both charts, controls and pixels; the other systems repeat the code paths of these
#: (the models are the same classes), at ~25 s each.
META_SYSTEMS = [
    s
    for s in SYSTEMS
    if (s if isinstance(s, str) else s.values[0]) in {"gyroscope", "pendulum_control", "pixel_pendulum"}
]


def meta_odeint(func, y0, t, method="rk4", options=None, **_):
    """``odeint`` over the steps of ``t`` with ``method``'s own step, reading no values."""
    solver = SOLVERS[method](func, y0, step_size=1.0, rtol=0.0, atol=0.0)
    field = lambda time, y, perturb=None: func(time, y)  # noqa: E731 - torchdiffeq's step passes perturb
    ys = [y0]
    for k in range(t.shape[0] - 1):
        dy, _ = solver._step_func(field, t[k], t[k + 1] - t[k], t[k + 1], ys[-1])
        ys.append(ys[-1] + dy)
    return torch.stack(ys)


def step_loss(module, batch: dict) -> torch.Tensor:
    """``TrainingModule.training_step``'s loss, without its logging and its finiteness check (a value read)."""
    loss = module.loss(batch)
    if module.regulariser is not None:
        with torch.no_grad():
            points = module.observe(batch)[1]
        u = batch.get("u")
        u = None if u is None else u[:, : points.shape[1]].flatten(0, 1)
        loss = loss + module.regulariser(module.model, points.flatten(0, 1), u)
    return loss


def built_pairs(system: str, cache, device: str):
    """(model name, data, module) for every catalogue model that can serve ``system``."""
    for model in api.catalogue("model"):
        extra = ["model.train_iters=0"] if device == "meta" and "symo" in model else []
        cfg = api.compose(
            "debug=fast",
            f"model={model}",
            f"system={system}",
            *extra,
            output_dir=cache / "run",
            cache_dir=cache / "data",
        )
        try:
            data, module = api.build(cfg)
        except ConfigError:  # a model that cannot serve this system (chart, controls, constraints)
            continue
        yield model, data, module


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("devices")


@pytest.mark.parametrize("system", META_SYSTEMS)
def test_training_step_on_meta(system, cache, monkeypatch):
    monkeypatch.setattr(encons.numerics.integrators, "odeint", meta_odeint)
    monkeypatch.setattr(encons.numerics.integrators.Integrator, "options", lambda self, t: {"method": self.method})
    stepped = []
    for model, data, module in built_pairs(system, cache, "meta"):
        batch = {k: v.to("meta") for k, v in next(iter(data.train_dataloader())).items()}
        module.to("meta")
        loss = step_loss(module, batch)
        loss.backward()
        assert (loss.device.type, loss.dtype, loss.shape) == ("meta", torch.float32, ()), model
        grads = [p.grad for p in module.parameters() if p.grad is not None]
        assert grads and all(g.device.type == "meta" and g.dtype == torch.float32 for g in grads), model
        stepped.append(model)
    assert stepped, f"no catalogue model serves {system}"


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device on this machine")
@pytest.mark.parametrize("system", SYSTEMS)
def test_training_step_on_cuda_matches_cpu(system, cache, monkeypatch):
    """The GPU's loss is as close to the CPU's float64 loss as 4× the CPU's own float32 error (at least 1e-3
    relative): the Lagrangian models' Hessian solves on an untrained pixel latent are near-singular (lnn_structure
    17 % from float64 in float32 on the CPU, glnn 1e6 against 1e13; 2026-11-27), where no tighter match exists."""
    monkeypatch.setattr(torch.backends.cudnn, "allow_tf32", False)  # PyTorch's default TF32 convolutions: ~1e-3
    for model, data, module in built_pairs(system, cache, "cuda"):
        batch = next(iter(data.train_dataloader()))
        on_gpu = copy.deepcopy(module).to("cuda")
        cpu_loss = step_loss(module, batch).detach()
        exact = step_loss(
            copy.deepcopy(module).double(), {k: v.double() if v.is_floating_point() else v for k, v in batch.items()}
        ).detach()
        gpu_loss = step_loss(on_gpu, {k: v.to("cuda") for k, v in batch.items()})
        gpu_loss.backward()
        assert gpu_loss.device.type == "cuda", model
        if not torch.isfinite(cpu_loss):  # no reference: the CPU's float32 step fails too
            continue
        tol = max(1e-3 * float(exact.abs()), 4 * float((cpu_loss.double() - exact).abs()))
        assert abs(float(gpu_loss) - float(exact)) <= tol, (model, float(gpu_loss), float(cpu_loss), float(exact))


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device on this machine")
@pytest.mark.parametrize("seeds", [None, "[0,1]"], ids=["one model", "ensemble"])
def test_a_run_trains_and_tests_on_cuda(seeds, train_run):
    """The whole run on the GPU, as ``trainer.accelerator=gpu`` gives it: the training loop (an ensemble's
    manual step too), the dopri5 test and its metrics (a step alone missed tensors made on the CPU there)."""
    extra = [] if seeds is None else [f"seeds={seeds}"]
    metrics = train_run(["model=node", "system=gyroscope", "trainer.accelerator=gpu", *extra])
    assert torch.isfinite(torch.tensor(metrics["test/traj_rel_err"])), metrics
