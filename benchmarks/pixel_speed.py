"""Speed of learning from pixels (Lim & Kasim §6) at the paper's sizes: frames per second through
encoder + latent rollout + decoder.

Sizes: 28 × 28 frames, two stacked per encoder input, MLP autoencoder 2 × 200 ReLU, latent 2
(``pixel_pendulum``) or 20 (``pixel_damped_pendulum``), each model's default network, RK4 one step
per frame. Reported per latent model:
- ``train frames/s``: one training step (batch of 32 windows × 5 frames, Lim & Kasim's batch size;
  loss = latent rollout + reconstruction + predicted frames [+ regulariser], backward, AdamW), frames
  of the batch per second of the fastest of a few steps;
- ``rollout frames/s``: the test pass (20 videos × 100 frames: encode, roll the latent out to
  t = 100, decode every frame, no gradient where the model allows), frames per second;
and, once per system, the time to simulate and render the paper-size dataset (196 videos × 100 frames).
Usage: ``python benchmarks/pixel_speed.py [--steps 5] [--threads 1] [--videos N] [--frames F]`` (``--videos``: N
training, validation and test videos each instead of the paper's 160/16/20; ``--frames``: F steps per video instead
of 100; both for a smoke run).
"""

from __future__ import annotations

import argparse
import tempfile
import time

import torch

from encons.entry import api

RUNS = [
    ("pixel_pendulum", "node", []),
    ("pixel_pendulum", "hnn", []),
    ("pixel_pendulum", "nsf", []),
    ("pixel_pendulum", "node", ["regulariser=hamiltonian", "regulariser.weight=500"]),
    ("pixel_damped_pendulum", "node", []),
    ("pixel_damped_pendulum", "node", ["regulariser=dissipative", "regulariser.weight=500"]),
]


def fastest(fn, steps: int) -> float:
    """Fastest wall time (s) of ``steps`` calls after one warm-up."""
    times = []
    for i in range(steps + 1):
        start = time.perf_counter()
        fn()
        if i:
            times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    parser.add_argument("--steps", type=int, default=5)
    parser.add_argument(
        "--threads", type=int, default=None, help="torch threads (default: encons.infra.threads' policy)"
    )
    parser.add_argument("--videos", type=int, default=None)
    parser.add_argument("--frames", type=int, default=None)
    args = parser.parse_args()
    sizes = [] if args.videos is None else [f"data.{k}={args.videos}" for k in ("n_train", "n_val", "n_test")]
    sizes += [] if args.frames is None else [f"data.n_steps={args.frames}"]
    print(f"{'system':<24}{'model':<26}{'train frames/s':>15}{'rollout frames/s':>18}")
    with tempfile.TemporaryDirectory() as tmp:
        generated = set()
        for system, model, extra in RUNS:
            cfg = api.compose(
                f"system={system}",
                f"model={model}",
                "logger=none",
                *extra,
                *sizes,
                f"threads={args.threads or 'null'}",
                output_dir=f"{tmp}/run",
                cache_dir=f"{tmp}/cache",
            )
            data, module = api.build(cfg)
            if system not in generated:  # again, timed, into a fresh cache file
                generated.add(system)
                data.cache_file.unlink()
                start = time.perf_counter()
                data.prepare_data()
                print(
                    f"{system}: dataset simulated, rendered and written in {time.perf_counter() - start:.2f} s "
                    f"({sum(a['obs'].shape[0] for a in data.arrays.values())} videos × "
                    f"{data.arrays['test']['obs'].shape[1]} frames)"
                )
            batch = next(iter(data.train_dataloader()))
            opt = torch.optim.AdamW(module.parameters(), lr=1e-4)

            def train_step() -> None:
                opt.zero_grad(set_to_none=True)
                loss = module.loss(batch)
                if module.regulariser is not None:  # as TrainingModule.training_step
                    with torch.no_grad():
                        points = module.observe(batch)[1]
                    loss = loss + module.regulariser(module.model, points.flatten(0, 1))
                loss.backward()
                opt.step()

            test = next(iter(data.test_dataloader()))

            def test_pass() -> None:
                x, states = module.observe(test)
                module.observation.decode(module.predict(test, states)).detach()

            frames = batch["obs"].shape[0] * batch["obs"].shape[1]
            train = frames / fastest(train_step, args.steps)
            rollout = test["obs"].shape[0] * test["obs"].shape[1] / fastest(test_pass, args.steps)
            name = model + "".join(f" {e.split('=')[1]}" for e in extra[:1])
            print(f"{system:<24}{name:<26}{train:>15.0f}{rollout:>18.0f}", flush=True)


if __name__ == "__main__":
    main()
