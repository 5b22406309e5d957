"""What each benchmark profile costs, measured: a few epochs of one cell per family of each profile.

Each cell is the profile's own run (``encons.tools.benchmark.expand``, seed 0) with ``trainer.max_epochs`` set to
``--epochs`` and ``test=false``, trained in this process, one after the other, one thread. Its epochs' cost
split (train / validation / checkpoint seconds) comes from the run's ``costs.json``
(``encons.training.callbacks.CostLine``); the per-epoch figures are means over epochs 2.. (the first pays one-off
warm-ups). The full-protocol cost of a cell is that epoch × the profile's ``trainer.max_epochs`` (testing and
data simulation not counted); a profile's full cost is the mean measured cell's full cost × the number of runs
the profile has (seeds included), since only some of its cells are measured.
Writes ``<out>/README.md`` and ``<out>/costs.csv`` (``--tag`` names a column set, e.g. before/after).
Usage: ``python benchmarks/profile_costs.py [--profiles zhong finzi ...] [--epochs 3] [--tag after]
[--extra key=value ...] [--out benchmarks/reports/costs]``.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: profile -> the cells timed (system/label, as the report names them; -n<N> for a data-efficiency size).
CELLS = {
    "zhong": ["pendulum2/hnn", "gyroscope/chnn"],
    "finzi": ["gyroscope/chnn"],
    "lim_kasim": ["mass_spring/node", "double_pendulum/inn_node+C_H'"],
    "santos": ["cartpole/symo-n8", "cartpole/e2e_symo-n8", "cartpole/node-rk4-n8"],
    "xiao": ["compound_pendulum/glnn-h200-d4", "compound_pendulum/second_order-h200-d3"],
    "pixels": ["pixel_pendulum/hnn"],
    "control": ["cartpole/symo"],
}
FIELDS = [
    "tag",
    "profile",
    "cell",
    "epochs",
    "train_s",
    "validation_s",
    "checkpoint_s",
    "epoch_s",
    "max_epochs",
    "full_h",
    "profile_runs",
    "wall_s",
    "error",
]


def profile_runs(profile: str):
    from hydra import compose, initialize_config_dir

    from encons.infra.paths import config_dir
    from encons.tools.benchmark import expand

    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        cfg = compose("benchmark", [f"profile={profile}", "out=/tmp/unused"])
    return expand(cfg)


def measure(profile: str, cell: str, epochs: int, extra: list[str], cache: str) -> dict:
    from encons.training import runs
    from encons.training.build import compose

    planned = profile_runs(profile)
    system, label = cell.split("/", 1)
    n = None
    if "-n" in label and label.rsplit("-n", 1)[1].isdigit():
        label, n = label.rsplit("-n", 1)[0], int(label.rsplit("-n", 1)[1])
    run = next(
        r for r in planned if r.system == system and r.label == label and r.n_train == n and r.seed == planned[0].seed
    )
    full = compose(list(run.overrides), tempfile.mkdtemp(), cache)
    row = {
        "profile": profile,
        "cell": cell,
        "epochs": epochs,
        "max_epochs": full.trainer.max_epochs,
        "profile_runs": len(planned),
        "error": "",
    }
    with tempfile.TemporaryDirectory() as out:
        cfg = compose(
            [
                "trainer.enable_model_summary=false",
                *run.overrides,
                f"trainer.max_epochs={epochs}",
                "test=false",
                *extra,
            ],
            out,
            cache,
        )
        started = time.perf_counter()
        try:
            runs.train(cfg, summary=False)
        except Exception as err:  # noqa: BLE001 - a cell that fails is reported, the others still run
            row["error"] = f"{type(err).__name__}: {str(err).splitlines()[0][:200]}"
        row["wall_s"] = round(time.perf_counter() - started, 2)
        costs = Path(out) / "costs.json"
        if costs.is_file():
            rows = json.loads(costs.read_text())["epochs"]
            kept = rows[1:] or rows
            for key in ("train", "validation", "checkpoint"):
                row[f"{key}_s"] = sum(r[key] for r in kept) / len(kept)
            row["epoch_s"] = row["train_s"] + row["validation_s"] + row["checkpoint_s"]
            row["full_h"] = row["epoch_s"] * row["max_epochs"] / 3600
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profiles", nargs="+", default=list(CELLS))
    parser.add_argument("--cells", nargs="*", default=None, help="profile:system/label, instead of every cell")
    parser.add_argument("--epochs", type=int, default=3)
    parser.add_argument("--tag", default="after")
    parser.add_argument("--extra", nargs="*", default=[], help="train overrides after the profile's")
    parser.add_argument("--out", default="benchmarks/reports/costs")
    parser.add_argument("--cache", default=os.path.join(tempfile.gettempdir(), "encons-costs-cache"))
    args = parser.parse_args()
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import torch

    torch.set_num_threads(1)
    todo = (
        [tuple(c.split(":", 1)) for c in args.cells]
        if args.cells is not None
        else [(p, c) for p in args.profiles for c in CELLS[p]]
    )
    out = Path(args.out)
    table = out / "costs.csv"
    old = list(csv.DictReader(table.open())) if table.is_file() else []
    for profile, cell in todo:
        load = os.getloadavg()[0]
        row = {"tag": args.tag, **measure(profile, cell, args.epochs, args.extra, args.cache)}
        print(json.dumps(row), f"(load {load:.1f})", flush=True)
        old = [r for r in old if (r["tag"], r["profile"], r["cell"]) != (row["tag"], profile, cell)] + [row]
        write(out, old, args)


def write(out: Path, rows: list[dict], args) -> None:
    from encons.infra.io import atomic_open, write_text

    out.mkdir(parents=True, exist_ok=True)
    with atomic_open(out / "costs.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=FIELDS)
        writer.writeheader()
        writer.writerows({k: r.get(k, "") for k in FIELDS} for r in rows)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    num = lambda v, f="{:.3g}": f.format(float(v)) if v not in ("", None) else "–"  # noqa: E731
    lines = [
        "# Profile costs, measured",
        "",
        f"Written by `{' '.join(['python', *sys.argv])}` at commit {commit}, "
        f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, one thread, `nice -n 10`, "
        f"load average at the end {os.getloadavg()[0]:.1f} on 2 shared cores (each row's load in the run log). "
        "Seconds per epoch are means over epochs 2..N of the run's `costs.json` "
        "(`encons.training.callbacks.CostLine`); "
        "full = epoch × the profile's `trainer.max_epochs` (no test, no data simulation). "
        "`before`: the profile as on main before validation.* (every epoch, the rollout criterion); "
        "`after`: with the profile's `validation.*`.",
        "",
        "| tag | profile | cell | train s | validation s | checkpoint s | epoch s | max epochs | full (h) | error |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['tag']} | {r['profile']} | {r['cell']} | {num(r.get('train_s'))} | "
            f"{num(r.get('validation_s'))} | {num(r.get('checkpoint_s'))} | {num(r.get('epoch_s'))} | "
            f"{r['max_epochs']} | {num(r.get('full_h'))} | {r.get('error', '')} |"
        )
    lines += [
        "",
        "## Full cost per profile",
        "",
        "Mean measured cell's full cost × the profile's runs (every cell × seed), one core.",
        "",
        "| tag | profile | runs | full (core-hours) |",
        "|---|---|---|---|",
    ]
    groups: dict[tuple, list] = {}
    for r in rows:
        if r.get("full_h") not in ("", None):
            groups.setdefault((r["tag"], r["profile"]), []).append(r)
    for (tag, profile), rs in groups.items():
        mean = sum(float(r["full_h"]) for r in rs) / len(rs)
        lines.append(f"| {tag} | {profile} | {rs[0]['profile_runs']} | {mean * int(rs[0]['profile_runs']):.3g} |")
    write_text(out / "README.md", "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
