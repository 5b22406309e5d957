"""Sections 2–3 of ../compound_cell.md: encons' GLNN and baseline trained as Xiao et al. §4.3 says, outside
the package (no Lightning), on the paper's point split or encons' trajectory split.

    cd benchmarks/reports/xiao-300/compound_cell
    OMP_NUM_THREADS=1 python exp_split.py MODEL SPLIT EPOCHS EVERY OUT.json
        MODEL: glnn (GLNN(system, hidden=200, depth=4), the paper's compound-pendulum cell)
               so   (SecondOrder(system, hidden=200, depth=3), the paper's baseline 2)
        SPLIT: points (the paper's: the 10,000 points shuffled, torch generator seed 0, and halved)
               traj   (encons': the 10 training trajectories' points train, the 10 test trajectories' hold out)
        EVERY: score every EVERY epochs (and after the last)

Data: the compound pendulum's data of ``python -m encons.benchmark profile=xiao`` (``profile_data.py``): its
10 training trajectories and the first 500 states of its 10 test trajectories, 20 × 500 = 10,000 points of
h = 0.02 from [−1, 1]⁴, the paper's layout. (The report's first runs used the 20 trajectories of the
xiao300_gh run, a run of that profile; these are the profile's data as it composes them now.) The exact q̈ of
every point is ``CompoundPendulum.vector_field`` in float64.

Training: ``torch.manual_seed(0)`` before the model is made; ``torch.optim.Adam(lr=1e-3)``; each epoch the
training points in a random order (the global generator) in batches of 1000 (5 steps an epoch on 5000
points); the loss ``encons.numerics.metrics.acceleration_mse`` of ``encons.numerics.integrators.
state_derivative(model, x)`` against the exact ds/dt, in float32 (the model's dtype, as in a run).

Scores, every EVERY epochs on a float64 copy of the model: accel_mse on all training points, on all held-out
points, and on the held-out points at t < 0.5 s and t ≥ 0.5 s, with the t < 0.5 s points' share of the
held-out squared error; one-step: one RK4 step of h = 0.02 by the model (torchdiffeq ``odeint``, method rk4
on the grid [0, h]) from each held-out point that has a successor in its trajectory, mean over points of
‖x̃ − x‖² (summed over the 4 state entries). Writes OUT.json (the settings, the curve, the last scores, wall
times) and prints a line per score.
"""

from __future__ import annotations

import copy
import json
import sys
import time
from pathlib import Path

import torch
from torchdiffeq import odeint

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from profile_data import profile_data  # noqa: E402 - beside this script

POINTS, BATCH, LR, EARLY = 500, 1000, 1e-3, 0.5


def make_model(name: str, system):
    from encons.models.glnn import GLNN, SecondOrder

    torch.manual_seed(0)
    if name == "glnn":
        return GLNN(system, hidden=200, depth=4)
    if name == "so":
        return SecondOrder(system, hidden=200, depth=3)
    raise SystemExit(f"MODEL={name!r}; allowed: glnn, so")


def split(name: str, n_traj: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Indices of the training and held-out points among the n_traj × POINTS (trajectory-major)."""
    n = n_traj * POINTS
    if name == "points":
        perm = torch.randperm(n, generator=torch.Generator().manual_seed(0))
        return perm[: n // 2], perm[n // 2 :]
    if name == "traj":
        index = torch.arange(n)
        return index[: n // 2], index[n // 2 :]  # the training trajectories first, then the test ones
    raise SystemExit(f"SPLIT={name!r}; allowed: points, traj")


def scores(model, system, x, rates, times, nxt, has_next, train, held, dt) -> dict[str, float]:
    from encons.numerics.integrators import state_derivative
    from encons.numerics.metrics import acceleration_mse

    model64 = copy.deepcopy(model).double()
    with torch.no_grad():
        pred = state_derivative(model64, x)
        error = {
            name: acceleration_mse(pred[idx], rates[idx]).item() for name, idx in (("train", train), ("held", held))
        }
        early, late = held[times[held] < EARLY - 1e-9], held[times[held] >= EARLY - 1e-9]
        error["held_early"] = acceleration_mse(pred[early], rates[early]).item()
        error["held_late"] = acceleration_mse(pred[late], rates[late]).item()
        error["held_early_share"] = error["held_early"] * len(early) / (error["held"] * len(held))
        start = held[has_next[held]]
        step = odeint(model64, x[start], torch.tensor([0.0, dt], dtype=torch.float64), method="rk4")[-1]
        error["one_step"] = ((step - nxt[start]) ** 2).sum(-1).mean().item()
    return error


def main(argv: list[str]) -> None:
    from encons.numerics.integrators import state_derivative
    from encons.numerics.metrics import acceleration_mse

    if len(argv) != 5:
        raise SystemExit(__doc__)
    model_name, split_name, epochs, every, out = argv[0], argv[1], int(argv[2]), int(argv[3]), Path(argv[4])
    began = time.perf_counter()
    system, splits, dt = profile_data()
    traj = torch.cat([splits["train"][:, :POINTS], splits["test"][:, :POINTS]])  # (20, 500, 4) float64
    n_traj = traj.shape[0]
    x = traj.reshape(-1, 4)
    rates = system.vector_field(x, "angle")
    k = torch.arange(POINTS).repeat(n_traj)
    times = k * dt
    has_next = k < POINTS - 1
    nxt = torch.roll(x, -1, 0)  # the successor in its trajectory where has_next
    train, held = split(split_name, n_traj)
    model = make_model(model_name, system)
    optimizer = torch.optim.Adam(model.parameters(), lr=LR)
    x32, rates32 = x.float(), rates.float()
    curve, steps, trained = [], 0, 0.0
    print(f"{model_name} {split_name}: {len(train)} training, {len(held)} held-out points, {epochs} epochs", flush=True)
    for epoch in range(1, epochs + 1):
        tick = time.perf_counter()
        order = train[torch.randperm(len(train))]
        losses = []
        for batch in order.split(BATCH):
            loss = acceleration_mse(state_derivative(model, x32[batch]), rates32[batch])
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            losses.append(loss.item())
            steps += 1
        trained += time.perf_counter() - tick
        if epoch % every == 0 or epoch == epochs:
            row = {"epoch": epoch, "steps": steps, "loss": sum(losses) / len(losses)}
            row |= scores(model, system, x, rates, times, nxt, has_next, train, held, dt)
            row["train_s"] = round(trained, 1)
            curve.append(row)
            print(" ".join(f"{key} {value:.4g}" for key, value in row.items()), flush=True)
    result = {
        "what": "../compound_cell.md sections 2-3 (exp_split.py)",
        "model": model_name,
        "architecture": "GLNN(system, hidden=200, depth=4)"
        if model_name == "glnn"
        else "SecondOrder(system, hidden=200, depth=3)",
        "split": split_name,
        "epochs": epochs,
        "every": every,
        "seed": 0,
        "lr": LR,
        "batch": BATCH,
        "data": "conf/profile/xiao.yaml compound pendulum: 10 training trajectories + first 500 states of 10 test",
        "points": {"train": len(train), "held": len(held)},
        "dt": dt,
        "curve": curve,
        "final": curve[-1],
        "train_wall_s": round(trained, 1),
        "wall_s": round(time.perf_counter() - began, 1),
    }
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {out}; wall {result['wall_s']} s (training {result['train_wall_s']} s)")


if __name__ == "__main__":
    main(sys.argv[1:])
