"""``compile=true``: the field through torch.compile (nn.Module.compile) gives the eager field's values
and gradients; combinations it is not for are refused in one line."""

from __future__ import annotations

import pytest
import torch

from encons.infra.errors import ConfigError
from encons.training.build import compose


def built(tmp_path, *overrides: str):
    from encons.entry.api import build

    return build(compose(["debug=fast", "model.hidden=32", *overrides], tmp_path / "run", tmp_path / "cache"))


@pytest.mark.slow
@pytest.mark.parametrize("model, system", [("lnn", "pendulum2")])
def test_compiled_rollout_loss_and_gradients_equal_eager(tmp_path, model, system):
    """LNN: the family with compile-only code (``layer_curvature``'s plain expression under torch.compile).
    Each case costs 80–90 s of inductor's C++ builds on a cold cache (CI's; chnn on the gyroscope 79 s, LNN
    90 s, one core at load 3), so CI runs this one; ``("chnn", "gyroscope")`` passes too when added here."""
    data, compiled = built(tmp_path, f"model={model}", f"system={system}", "compile=true")
    _, eager = built(tmp_path, f"model={model}", f"system={system}")
    eager.model.load_state_dict(compiled.model.state_dict())
    batch = next(iter(data.train_dataloader()))
    losses, grads = [], []
    for module in (compiled, eager):
        module.model.zero_grad()
        loss = module.loss(batch)
        loss.backward()
        losses.append(loss.detach())
        grads.append(torch.cat([p.grad.flatten() for p in module.model.parameters() if p.grad is not None]))
    assert compiled.model._compiled_call_impl is not None and eager.model._compiled_call_impl is None
    assert torch.allclose(losses[0], losses[1], rtol=1e-4)
    assert torch.allclose(grads[0], grads[1], rtol=1e-3, atol=1e-5 * grads[1].abs().max().item())


@pytest.mark.parametrize(
    "overrides, words",
    [
        (["model=hnn", "regulariser=hamiltonian", "compile=true"], "compile=true compiles the model's vector field"),
        (["model=symo", "system=pendulum_control", "objective=residual", "compile=true"], "is discrete"),
        (["compile=yes"], "compile='yes'"),
    ],
)
def test_compile_nonsense_is_one_line(tmp_path, overrides, words):
    with pytest.raises(ConfigError) as err:
        built(tmp_path, *overrides)
    assert "\n" not in str(err.value) and words in str(err.value) and "allowed" in str(err.value), err.value
