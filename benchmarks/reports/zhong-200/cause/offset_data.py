"""The offset data of ``benchmarks/reports/zhong-200/cause.md`` (items 1–2): the ``profile=zhong`` trajectories of a
system with each trajectory's angles shifted by the 2πk that Finzi et al.'s conversion would serve it, and item 1's
table (how many trajectories it shifts, and by how much).

    python benchmarks/reports/zhong-200/cause/offset_data.py [--system pendulum2|gyroscope] [--out FILE]
        [--cache DIR] [--seed 0]

The data are those ``python -m encons.benchmark profile=zhong`` trains that system's grid on: the run config is
composed by the benchmark's own ``expand`` (the profile's ``common`` and ``per_system`` overrides, ``experiment=paper``)
and the trajectories are the simulation cache it builds (``--cache``: its folder, default the runs' own
``paths.cache_dir``; simulated there if missing). Finzi et al.'s ``RigidBodyDataset(angular_coords=True)`` serves
angles as follows, and so does this script: one random 5-step chunk of each trajectory, the chunks of the whole
generated set in a random generation order (their ``split_dataset`` splits one generated set at random), the angles
recovered from Cartesian states (pendulum: ``atan2`` of each rod; gyroscope: scipy's
``Rotation.from_matrix(R).as_euler("ZXZ")``, θ on [0, π]), then ``np.unwrap(axis=0)`` over the chunks flattened over
trajectories and steps. A trajectory's k is the served angle minus the true one (on the served branch) at its
chunk's first step, over 2π. Every trajectory's angles, train, val and test alike and over all its steps, are then
shifted by 2πk (the gyroscope: φ and ψ; θ is never shifted, its branch left as encons simulates it), and written
with ``encons.data.store.save`` (chart ``angle``), to be trained through ``data.path=FILE``.

Writes FILE (default ``<cache>/zhong-offset-<system>.npz``) and, beside this script, ``item1-<system>.json`` and
``.md``: per split the share of trajectories served with some angle + 2πk, k ≠ 0, and the range of k, for the random
generation order and, as a contrast, for the splits generated in order (train, val, test) unshuffled. Everything is
seeded (``--seed``, default 0): the same command writes the same arrays (``content_sha256`` in the JSON; the .npz's
zip timestamps differ).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

import encons
from encons.data import store
from encons.tools.benchmark import expand
from encons.training.build import compose

HERE = Path(__file__).resolve().parent
CHUNK = 5  # Finzi et al.'s chunk_len, Zhong et al.'s §4.1 windows
SYSTEMS = ("pendulum2", "gyroscope")


def profile_config(system: str, cache: str | None, output_dir: str):
    """The run config ``python -m encons.benchmark profile=zhong`` composes for ``system``'s grid (its first model:
    every model of the grid shares the data)."""
    bench = compose(
        ["profile=zhong", f"systems=[{system}]", "models=[hnn]", "seeds=[0]", "n_train=[]"], config_name="benchmark"
    )
    run = expand(bench)[0]
    return run.overrides, compose(run.overrides, output_dir, cache)


def served_angles(system: str, body, chunks: torch.Tensor) -> torch.Tensor:
    """The angles Finzi et al.'s conversion recovers from the Cartesian states of ``chunks`` (..., 2n) in the angle
    chart, before the unwrap: each on its principal branch."""
    n = chunks.shape[-1] // 2
    if system == "gyroscope":
        from scipy.spatial.transform import Rotation

        from encons.systems.gyroscope import _rotation

        rot = _rotation(chunks[..., :n]).reshape(-1, 3, 3).numpy()
        return torch.from_numpy(Rotation.from_matrix(rot).as_euler("ZXZ")).reshape(*chunks.shape[:-1], 3)
    cart = body.to_chart(chunks, "angle", "cartesian")  # the rods' end points
    return body.to_chart(cart, "cartesian", "angle")[..., :n]  # atan2 of each rod, in (−π, π]


def on_branch(system: str, q: torch.Tensor) -> torch.Tensor:
    """The true angles ``q`` on the branch the served ones take: the gyroscope's θ < 0 is served as (φ + π, −θ,
    ψ + π) (scipy's θ ∈ [0, π]); θ itself is taken modulo 2π into (−π, π] first."""
    if system != "gyroscope":
        return q
    phi, theta, psi = q.unbind(-1)
    theta = torch.remainder(theta + math.pi, 2 * math.pi) - math.pi
    turn = math.pi * (theta < 0).to(q.dtype)
    return torch.stack([phi + turn, theta.abs(), psi + turn], -1)


def offsets(system: str, body, trajectories: torch.Tensor, order: np.ndarray, starts: np.ndarray):
    """k (N, n) of each trajectory and the largest distance of a served angle from true + 2πk (a check: ~1e-12)."""
    n = trajectories.shape[-1] // 2
    idx = torch.as_tensor(starts)[:, None] + torch.arange(CHUNK)
    chunks = torch.gather(trajectories, 1, idx[..., None].expand(-1, -1, trajectories.shape[-1]))
    wrapped = served_angles(system, body, chunks[order]).numpy()  # in generation order
    served = np.empty_like(wrapped)
    served[order] = np.unwrap(wrapped.reshape(-1, n), axis=0).reshape(wrapped.shape)  # Finzi: the flattened chunks
    true = on_branch(system, chunks[:, 0, :n]).numpy()
    turns = (served[:, 0] - true) / (2 * np.pi)
    k = np.round(turns).astype(np.int64)
    theta = torch.remainder(chunks[:, 0, 1] + math.pi, 2 * math.pi) - math.pi
    flipped = (theta < 0).numpy() if system == "gyroscope" else np.zeros(len(k), bool)  # served on scipy's branch
    return k, float(np.abs(turns - k).max() * 2 * np.pi), flipped


def shares(k: np.ndarray, split_of: np.ndarray) -> dict:
    """Per split: trajectories, the share with some k ≠ 0, and k's range (per angle and over all)."""
    out = {}
    for name in dict.fromkeys(split_of):
        ks = k[split_of == name]
        out[name] = {
            "trajectories": len(ks),
            "shifted": int((ks != 0).any(-1).sum()),
            "shifted_share": float((ks != 0).any(-1).mean()),
            "k_min": int(ks.min()),
            "k_max": int(ks.max()),
            "k_min_per_angle": ks.min(0).tolist(),
            "k_max_per_angle": ks.max(0).tolist(),
        }
    return out


def content_hash(t: torch.Tensor, splits: dict[str, torch.Tensor]) -> str:
    digest = hashlib.sha256(t.numpy().tobytes())
    for name in sorted(splits):
        digest.update(name.encode() + splits[name].numpy().tobytes())
    return digest.hexdigest()


def table(result: dict) -> str:
    names = ", ".join(result["angles"])
    rows = [
        f"# Item 1 of cause.md: {result['system']}, the profile=zhong data shifted as Finzi et al.'s conversion would",
        "",
        f"Written by `{result['command']}` (seed {result['seed']}; angles {names}; the largest distance of a served "
        f"angle from true + 2πk: {result['max_residual']:.1e}).",
        "",
        f"| generation order | split | trajectories | served with some angle + 2πk, k ≠ 0 | k (min … max) | "
        f"k of {names} |",
        "|---|---|---|---|---|---|",
    ]
    for order, label in (("random", "random (the construction)"), ("in_order", "train, val, test unshuffled")):
        for split, s in result[order].items():
            rows.append(
                f"| {label} | {split} | {s['trajectories']} | {s['shifted']} ({100 * s['shifted_share']:.1f} %) | "
                f"{s['k_min']} … {s['k_max']} | "
                + ", ".join(f"{a} … {b}" for a, b in zip(s["k_min_per_angle"], s["k_max_per_angle"]))
                + " |"
            )
    rows += [
        "",
        *(
            [
                f"Besides, {100 * result['other_branch_share']:.1f} % of the trajectories have θ < 0 at their chunk's "
                "first step and are served on scipy's θ ∈ [0, π] branch (φ + π, −θ, ψ + π); the offset data keep "
                "encons' branch.",
                "",
            ]
            if result["system"] == "gyroscope"
            else []
        ),
        f"The offset data (the random order's k) hold {result['data']['trajectories']} trajectories, content sha256 "
        f"`{result['data']['content_sha256'][:16]}…`.",
        "",
    ]
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--system", default="pendulum2", choices=SYSTEMS)
    parser.add_argument("--out", type=Path, help="the offset data file (default <cache>/zhong-offset-<system>.npz)")
    parser.add_argument("--cache", help="the simulation cache folder (default the runs' paths.cache_dir)")
    parser.add_argument("--seed", type=int, default=0, help="the chunks' starts and the generation order")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        overrides, cfg = profile_config(args.system, args.cache, tmp)
        data, module = encons.build(cfg)  # simulates the cache file if it is missing, as a run would
    t, splits, chart = store.load(data.cache_file)
    assert chart == "angle", chart
    body = module.system
    n = body.coord_dim("angle")
    names = list(splits)
    split_of = np.concatenate([[name] * len(splits[name]) for name in names])
    length = min(v.shape[1] for v in splits.values())
    trajectories = torch.cat([v[:, :length] for v in splits.values()])  # the chunks' starts lie in the train length
    rng = np.random.default_rng(args.seed)
    starts = rng.integers(0, length - CHUNK + 1, size=len(trajectories))
    order = rng.permutation(len(trajectories))
    k, residual, flipped = offsets(args.system, body, trajectories, order, starts)
    k_in_order, residual_in_order, _ = offsets(args.system, body, trajectories, np.arange(len(trajectories)), starts)
    angles = ["φ", "θ", "ψ"] if args.system == "gyroscope" else [f"θ{i + 1}" for i in range(n)]
    if args.system == "gyroscope" and (k[:, 1] != 0).any():
        raise SystemExit("gyroscope: a shift of θ, which scipy serves on [0, π]; the construction does not hold")
    shift = torch.from_numpy(2 * np.pi * k).double()
    shifted, first = {}, 0
    for name in names:
        v = splits[name].clone()
        v[..., :n] += shift[first : first + len(v), None, :]
        shifted[name], first = v, first + len(v)
    out = args.out or Path(cfg.paths.cache_dir) / f"zhong-offset-{args.system}.npz"
    out.parent.mkdir(parents=True, exist_ok=True)
    store.save(out, t, shifted, "angle")
    command = (
        "python benchmarks/reports/zhong-200/cause/offset_data.py --system "
        + args.system
        + (f" --seed {args.seed}" if args.seed else "")
    )
    result = {
        "system": args.system,
        "seed": args.seed,
        "command": command,
        "run_overrides": overrides,
        "cache_file": data.cache_file.name,
        "angles": angles,
        "chunk_len": CHUNK,
        "max_residual": max(residual, residual_in_order),
        "random": shares(k, split_of),
        "in_order": shares(k_in_order, split_of),
        "other_branch_share": float(flipped.mean()),  # the gyroscope: θ < 0 at the chunk's first step
        "data": {
            "trajectories": {name: len(v) for name, v in shifted.items()},
            "content_sha256": content_hash(t, shifted),
        },
    }
    result["data"]["trajectories"] = sum(result["data"]["trajectories"].values())
    (HERE / f"item1-{args.system}.json").write_text(json.dumps(result, indent=1, ensure_ascii=False) + "\n")
    (HERE / f"item1-{args.system}.md").write_text(table(result))
    print(table(result))
    print(f"offset data: {out}")
    return result


if __name__ == "__main__":
    main(sys.argv[1:])
