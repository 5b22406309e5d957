"""Why HNN-structure's first loss on the gyroscope's offset data is not finite (item 2b of ../cause.md).

    python benchmarks/reports/zhong-200/cause/item2b_nan.py DATA.npz [--cache DIR] [--out item2b_nan.json]

DATA.npz: the offset data of ``offset_data.py --system gyroscope`` (as ``item2b.sh`` writes it). Builds the run
``item2b.sh`` trains on it (profile=zhong's HNN-structure, seed 0: the same initial weights) and takes its first
training batch. Then, with those weights: the loss on that batch and on the same batch with every angle wrapped
into [−π, π) (the states encons serves); each window's loss alone (how many are not finite); and the learned
M(q)'s smallest eigenvalue and condition number at the windows' first states, offset and wrapped. Writes the JSON.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
from pathlib import Path

import torch

from encons.entry import api


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("data", type=Path)
    parser.add_argument("--cache", default=None)
    parser.add_argument("--out", type=Path, default=Path(__file__).with_name("item2b_nan.json"))
    args = parser.parse_args()
    overrides = [  # as item2b.sh's offset run (its results.csv `overrides`)
        "system=gyroscope",
        "model=hnn_structure",
        "model.shared_trunk=false",
        "experiment=paper",
        "logger=none",
        "system.min_sin_theta=0.0",
        "seed=0",
        "threads=1",
        f"data.path={args.data.resolve()}",
    ]
    extra = {"cache_dir": args.cache} if args.cache else {}
    cfg = api.compose(*overrides, output_dir=tempfile.mkdtemp(), **extra)
    data, module = api.build(cfg)
    batch = next(iter(data.train_dataloader()))
    states = batch["states"]
    n = module.model.n
    wrapped = states.clone()
    wrapped[..., :n] = torch.remainder(states[..., :n] + math.pi, 2 * math.pi) - math.pi
    with torch.no_grad():
        window_losses = torch.stack([module.training_loss({"states": states[i : i + 1]}) for i in range(len(states))])

        def spectrum(q: torch.Tensor) -> dict:
            eig = torch.linalg.eigvalsh(module.model.mass(q))
            return {
                "smallest eigenvalue min": eig[:, 0].min().item(),
                "smallest eigenvalue median": eig[:, 0].median().item(),
                "condition number max": (eig[:, -1] / eig[:, 0]).max().item(),
            }

        result = {
            "what": __doc__.split("\n")[0],
            "overrides": overrides[:-1] + ["data.path=DATA.npz"],
            "windows": len(states),
            "window states": states.shape[1],
            "largest |angle| in the batch": states[..., :n].abs().max().item(),
            "loss, offset batch": module.training_loss(batch).item(),
            "loss, same batch wrapped": module.training_loss({"states": wrapped}).item(),
            "windows whose own loss is not finite": int((~torch.isfinite(window_losses)).sum()),
            "largest finite window loss": window_losses[torch.isfinite(window_losses)].max().item(),
            "M(q) at the first states, offset": spectrum(states[:, 0, :n]),
            "M(q) at the first states, wrapped": spectrum(wrapped[:, 0, :n]),
        }
    tmp = args.out.with_suffix(".tmp")
    tmp.write_text(json.dumps(result, indent=1) + "\n")
    tmp.replace(args.out)
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
