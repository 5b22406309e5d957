"""Bare training loop on Xiao et al.'s compound-pendulum data (§4.3): which protocol detail closes the gap?

    python benchmarks/reports/xiao-seeds/compound_fit.py MODEL VARIANT [EPOCHS] [SEED] > OUT.json

MODEL: so (baseline q̈ = F(q, q̇), 3 × 200) or glnn (eq. (11), two 4 × 200 networks). VARIANT, one change
(several joined by +, e.g. tanh+std) against encons' setting (softplus, float32, raw inputs and targets, Adam 1e-3, batches of 1000):
  base       encons' setting
  tanh       tanh activations
  std        (baseline) inputs standardised, targets scaled by their std (the loss stays in q̈ units)
  f64        float64
  lr3e-3     Adam lr 3e-3
  fcranmer   (GLNN) its F network initialised as its L network (Cranmer et al.'s scales, encons.models.networks.cranmer_init_)
Data are the paper's layout: 20 trajectories × 500 points (h = 0.02, t < 10 s, starts uniform in
[−1, 1]⁴, γ₁ = γ₂ = 0.5, exact q̈ from encons' CompoundPendulum, which equals eq. (12) to 1e-14), the
10,000 points shuffled (data seed 0) and halved: train / test. Printed every 25 epochs: accel_mse
(mean over points of ‖q̈̂ − q̈‖², float64) on train and test, and their half-component MSE (torch's MSELoss).
"""

from __future__ import annotations

import json
import sys
import time

import torch
from torchdiffeq import odeint

from encons.metrics import acceleration_mse
from encons.models.glnn import GLNN, SecondOrder
from encons.models.networks import cranmer_init_
from encons.systems.dissipative import CompoundPendulum


def paper_data(seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    system = CompoundPendulum()
    g = torch.Generator().manual_seed(seed)
    s0 = system.sample_initial(20, g)
    t = torch.arange(500, dtype=torch.float64) * 0.02
    traj = odeint(lambda _, s: system.vector_field(s, "angle"), s0, t, method="dopri5", rtol=1e-10, atol=1e-10)
    x = traj.reshape(-1, 4)
    rates = system.vector_field(x, "angle")
    perm = torch.randperm(len(x), generator=g)
    tr, te = perm[: len(x) // 2], perm[len(x) // 2:]
    return x[tr], rates[tr], x[te], rates[te]


class Scaled(torch.nn.Module):
    """net((z − μ) / σ) · σ_q̈: the baseline's MLP on standardised inputs, predicting standardised q̈."""

    def __init__(self, net: torch.nn.Module, mu: torch.Tensor, sd: torch.Tensor, out_sd: torch.Tensor):
        super().__init__()
        self.net = net
        self.register_buffer("mu", mu)
        self.register_buffer("sd", sd)
        self.register_buffer("out_sd", out_sd)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return self.net((z - self.mu) / self.sd) * self.out_sd


def main() -> None:
    model_name, variant = sys.argv[1], sys.argv[2]
    flags = set(variant.split("+"))
    epochs = int(sys.argv[3]) if len(sys.argv) > 3 else 300
    seed = int(sys.argv[4]) if len(sys.argv) > 4 else 0
    dtype = torch.float64 if "f64" in flags else torch.float32
    xtr, rtr, xte, rte = paper_data()
    torch.manual_seed(seed)
    activation = "tanh" if "tanh" in flags else "softplus"
    system = CompoundPendulum()
    if model_name == "so":
        model = SecondOrder(system, hidden=200, depth=3, activation=activation)
    else:
        model = GLNN(system, hidden=200, depth=4, activation=activation)
    mu, sd = xtr.mean(0), xtr.std(0)
    qdd_sd = rtr[:, 2:].std(0)
    if "std" in flags and model_name == "so":  # inputs standardised, targets scaled by their std
        model.net = Scaled(model.net, mu, sd, qdd_sd)
    if "fcranmer" in flags:
        cranmer_init_(model.force_net)
    model = model.to(dtype)
    lr = 3e-3 if "lr3e-3" in flags else 1e-3
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    batch = 1000
    t0 = torch.zeros((), dtype=dtype)

    def rates_of(x: torch.Tensor) -> torch.Tensor:
        return model(t0, x)

    def score(x: torch.Tensor, r: torch.Tensor) -> float:
        parts = [acceleration_mse(rates_of(x[i:i + 1000].to(dtype)).double().detach(), r[i:i + 1000]) * len(x[i:i + 1000])
                 for i in range(0, len(x), 1000)]
        return float(sum(parts) / len(x))

    curve, started = [], time.perf_counter()
    g = torch.Generator().manual_seed(seed)
    for epoch in range(1, epochs + 1):
        perm = torch.randperm(len(xtr), generator=g)
        for i in range(0, len(xtr), batch):
            idx = perm[i:i + batch]
            loss = acceleration_mse(rates_of(xtr[idx].to(dtype)), rtr[idx].to(dtype))
            opt.zero_grad()
            loss.backward()
            opt.step()
        if epoch % 25 == 0 or epoch == epochs:
            tr, te = score(xtr, rtr), score(xte, rte)
            curve.append({"epoch": epoch, "steps": epoch * ((len(xtr) + batch - 1) // batch), "train": tr, "test": te,
                          "test_mse_mean_over_components": te / 2, "wall_s": time.perf_counter() - started})
            print(json.dumps(curve[-1]), file=sys.stderr, flush=True)
    print(json.dumps({"model": model_name, "variant": variant, "epochs": epochs, "seed": seed,
                      "E_qdd2_test": float((rte[:, 2:] ** 2).sum(-1).mean()), "curve": curve}, indent=1))


if __name__ == "__main__":
    main()
