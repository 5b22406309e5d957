"""Throughput of a seed ensemble (``encons.training.ensemble``) against the same members trained as separate models.

Per cell, K members are built as the runs ``seed=0..K-1`` would be (``encons.training.build``); one training step
is what the ensemble does per batch without Lightning around it: the members' losses on one batch, one
backward, one optimiser step. "separate": each member alone (its own loss, backward and AdamW step), K of
them in turn: K separate runs in one process, without their K-fold Lightning overhead (which an ensemble
saves too, so the ratio is a lower bound of a whole run's). "ensemble": the path ``encons.training.ensemble`` takes for
the cell (``stacked``: one vmapped forward/backward and one AdamW over stacked weights; ``loop``: the members'
losses in turn, one backward). Reported: member-steps per CPU second and the ratio ensemble / separate at K
members, fastest of ``--repeats`` interleaved rounds of ``--steps`` steps, one thread (process CPU time, so
that other processes on shared cores do not count).

Cells (conf/profile): ``lim_kasim`` mass-spring NODE (2 × 200 softplus, derivative objective, one 30-state
trajectory per batch), ``santos`` cart-pole NODE-RK4 at N_train = 8 (2 × 256 tanh, one-step objective, batch
of one trajectory of 33 states), ``finzi`` gyroscope CHNN (3 × 200, batch 200 windows of 5; report only),
``pixels`` pixel-pendulum NODE (profile=pixels: 28 × 28 frames, two stacked, through each member's 2 × 200 ReLU
autoencoder to a latent of 2; 2 × 200 NODE; batch 32 windows of 3 frames).
``--layers`` also times the network alone: ``vmap`` of ``functional_call`` against an ensemble dimension written
into the layers (``baddbmm``). ``--split`` also splits one step at the largest K by ``torch.profiler`` into
matrix products (``mm``/``addmm``/``bmm``/``baddbmm``: the arithmetic an ensemble cannot share), the optimiser
step and the rest, both ways. ``--ceiling`` measures what an ensemble could share at best: a separate
member-step's fixed cost O, the part of its time T that does not grow with the batch (its per-call overhead,
with the optimiser step: that does not grow with the batch either), from the same step on the batch served
twice over (``torch.cat`` of each tensor with itself: the same windows, twice the arithmetic), O = 2 T(B) −
T(2B), fastest of ``--repeats`` interleaved rounds. K members that shared every fixed cost and none of the
arithmetic would take (T − O) + O / K per member-step, so the ratio's ceiling at K is T / (T − O + O / K), and
the table gives the measured ratio's fraction of it. Usage:
``python benchmarks/ensemble_speed.py [--cells lim_kasim santos finzi] [--members 1 2 4 8 16] [--steps 20]
[--repeats 3] [--threads 1] [--layers] [--split] [--ceiling] [--out FILE.md]``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import torch

from encons.entry import api
from encons.entry.api import build
from encons.infra import threads
from encons.training import ensemble, stacked

SMALL_DATA = ["data.n_val=2", "data.n_test=2", "logger=none"]
#: The papers' cells (conf/profile), one family each where it is used: the profile's protocol for that model.
LIM_KASIM = [
    "system=mass_spring",
    "objective=derivative",
    "optimizer=adamw",
    "scheduler=none",
    "optimizer.lr=1e-4",
    "optimizer.weight_decay=0.0",
    "model.depth=2",
    "model.hidden=200",
    "data.batch_size=1",
    "data.chunk_len=30",
]
XIAO = [
    "system=damped_oscillator",
    "objective=acceleration",
    "optimizer=adamw",
    "scheduler=none",
    "optimizer.lr=1e-3",
    "optimizer.weight_decay=0.0",
    "data.chunk_len=200",
    "data.batch_size=5",
    "model.hidden=200",
    "model.depth=3",
]
SANTOS = [
    "experiment=symo_paper",
    "system=cartpole",
    "optimizer.lr=1e-3",
    "model.hidden=256",
    "data.n_train=8",
    "data.batch_size=1",
]
ZHONG = ["experiment=paper", "system=pendulum2"]
FINZI = [
    "system=gyroscope",
    "data.noise=0.0",
    "data.chunk_len=5",
    "data.batch_size=200",
    "model.hidden=200",
    "model.depth=3",
    "optimizer=adamw",
    "scheduler=none",
    "optimizer.lr=1e-2",
    "optimizer.weight_decay=1e-4",
]
PIXELS = [
    "system=pixel_pendulum",
    "optimizer=adamw",
    "scheduler=none",
    "optimizer.lr=1e-4",
    "optimizer.weight_decay=0.0",
    "model.hidden=200",
    "model.depth=2",
    "data.windows=all",
    "data.chunk_len=3",
]
CELLS = {
    "lim_kasim": [*LIM_KASIM, "model=node"],
    "lim_kasim-hnn": [*LIM_KASIM, "model=hnn"],
    "lim_kasim-lnn": [*LIM_KASIM, "model=lnn"],
    "lim_kasim-node+C_H": [*LIM_KASIM, "model=node", "regulariser=hamiltonian", "regulariser.weight=5e4"],
    "lim_kasim-nsf": [*LIM_KASIM, "model=nsf"],
    "xiao-glnn": [*XIAO, "model=glnn"],
    "xiao-second_order": [*XIAO, "model=second_order"],
    "santos": [*SANTOS, "model=node", "integrator=rk4"],
    "santos-lnode": [*SANTOS, "model=lnode", "integrator=rk4"],
    "santos-symo": [*SANTOS, "model=symo", "objective=residual"],
    "santos-e2e_symo": [*SANTOS, "model=e2e_symo"],
    "zhong-hnn": [*ZHONG, "model=hnn"],
    "zhong-hnn_angle": [*ZHONG, "model=hnn_angle"],
    "zhong-lnn_structure": [*ZHONG, "model=lnn_structure", "model.shared_trunk=false"],
    "finzi": [*FINZI, "model=chnn"],
    "finzi-clnn": [*FINZI, "model=clnn"],
    "pixels-node": [*PIXELS, "model=node"],
}
SLOW = ("finzi", "zhong")  # cells whose step takes 10x longer: a tenth of the steps


def members(cell: list[str], k: int, cache: str) -> tuple[list, dict]:
    """``k`` members (seeds 0..k-1) of ``cell`` and one training batch."""
    mods, batch = [], None
    for seed in range(k):
        cfg = api.compose(*cell, *SMALL_DATA, f"seed={seed}", output_dir=tempfile.mkdtemp(), cache_dir=cache)
        data, module = build(cfg)
        mods.append(module)
        batch = batch or next(iter(data.train_dataloader()))
    return mods, batch


def separate_step(mods: list, opts: list, batch: dict) -> None:
    for m, opt in zip(mods, opts):
        opt.zero_grad(set_to_none=True)
        m.training_loss(batch).backward()
        opt.step()


def ensemble_step(module, opt, batch: dict) -> None:
    opt.zero_grad(set_to_none=True)
    if isinstance(module, ensemble.StackedEnsemble):
        module.stacked.training_loss(batch).sum().backward()
    else:
        sum(m.training_loss(batch) for m in module.members).backward()
    opt.step()


def timed(step, steps: int) -> float:
    """Process CPU time per step (one thread: the step's own compute, steadier than wall time on shared cores)."""
    step()  # warm-up
    start = time.process_time()
    for _ in range(steps):
        step()
    return (time.process_time() - start) / steps


def fastest(steps_of: dict[str, Callable[[], None]], steps: int, rounds: int = 5) -> dict[str, float]:
    """Each named step's process CPU time per step (s), fastest of ``rounds`` interleaved rounds of ``steps``
    (interleaved: load on the shared cores hits every way alike)."""
    best = dict.fromkeys(steps_of, float("inf"))
    for _ in range(rounds):
        for name, step in steps_of.items():
            best[name] = min(best[name], timed(step, steps))
    return best


def ab_line(name: str, k: int, before: str, now: str, times: dict[str, float]) -> None:
    """Print an A/B of one cell's stacked step: ``times["before"]`` and ``times["now"]`` (s, ``fastest``)."""
    print(
        f"{name} K={k}: {before} {times['before'] * 1e3:.3f} ms, {now} {times['now'] * 1e3:.3f} ms per stacked "
        f"step: {times['before'] / times['now']:.3f}x",
        flush=True,
    )


def pools(cells: list[str], cache: str) -> Iterator[tuple[str, list[str], list, dict]]:
    """Each of ``cells`` (names in ``CELLS``) with 8 members (``members``) and its batch, on one thread: what the
    in-process A/B scripts under ``benchmarks/reports/ensemble_speed/`` loop over."""
    torch.set_num_threads(1)
    for name in cells:
        yield name, CELLS[name], *members(CELLS[name], 8, cache)


def stacked_ensemble(cell: list[str], pool: list, batch: dict, k: int, cache: str):
    """``pool[:k]`` (``members``) as the stacked ensemble of ``cell`` (stacked wherever it can, not by timing)
    and its optimiser over the stacked weights."""
    cfg = api.compose(*cell, *SMALL_DATA, output_dir=tempfile.mkdtemp(), cache_dir=cache)
    module = ensemble._module(cfg, pool[:k], list(range(k)), _Data(batch), True)
    return module, stacked.optimizer(pool[0].optimizer, list(module.stacked.parameters()))


MATMUL = ("aten::mm", "aten::addmm", "aten::bmm", "aten::baddbmm")


def split(step, steps: int) -> dict[str, float]:
    """Self CPU time per step (ms) of ``step`` in matrix products, the optimiser step (its own ops) and the rest."""
    from torch.profiler import ProfilerActivity, profile

    step()
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for _ in range(steps):
            step()
    events = prof.key_averages()
    total = sum(e.self_cpu_time_total for e in events)
    matmul = sum(e.self_cpu_time_total for e in events if e.key in MATMUL)
    optim = sum(e.cpu_time_total for e in events if e.key.startswith("Optimizer.step"))
    return {
        "matmul": matmul / steps / 1e3,
        "optimiser": optim / steps / 1e3,
        "rest": (total - matmul - optim) / steps / 1e3,
    }


def line(values) -> str:
    """A table row as the script prints it: floats to three significant digits."""
    return " | ".join(f"{v:.3g}" if isinstance(v, float) else str(v) for v in values)


def fixed_share(module, opt, batch: dict, steps: int, repeats: int) -> float:
    """O / T of one separate member-step (see the module's docstring): the share of its time that does not grow
    with the batch, from the step on ``batch`` and on ``batch`` served twice over."""
    twice = {key: torch.cat([value, value]) for key, value in batch.items()}
    t = fastest(
        {
            "once": lambda: separate_step([module], [opt], batch),
            "twice": lambda: separate_step([module], [opt], twice),
        },
        steps,
        repeats,
    )
    return min(max(2 * t["once"] - t["twice"], 0.0) / t["once"], 1.0)


def measure(
    name: str,
    cell: list[str],
    ks: list[int],
    steps: int,
    repeats: int,
    cache: str,
    splits: list[dict] | None = None,
    path: bool | None = None,
    ceilings: list[dict] | None = None,
) -> list[dict]:
    rows = []
    pool, batch = members(cell, max(ks), cache)
    fixed = (
        None
        if ceilings is None
        else fixed_share(pool[0], pool[0].optimizer(pool[0].parameters()), batch, steps, repeats)
    )
    for k in ks:
        mods = pool[:k]
        module = ensemble._module(
            api.compose(*cell, *SMALL_DATA, output_dir=tempfile.mkdtemp(), cache_dir=cache),
            mods,
            list(range(k)),
            _Data(batch),
            path,  # None: the path a run takes (stacked where it measures faster); True: stacked wherever it can
        )
        if isinstance(module, ensemble.StackedEnsemble):
            opt = stacked.optimizer(mods[0].optimizer, list(module.stacked.parameters()))
        else:
            opt = mods[0].optimizer([p for m in mods for p in m.parameters()])
        opts = [m.optimizer(m.parameters()) for m in mods]
        t = fastest(
            {
                "separate": lambda: separate_step(mods, opts, batch),
                "ensemble": lambda: ensemble_step(module, opt, batch),
            },
            steps,
            repeats,
        )
        best_sep, best_ens = t["separate"], t["ensemble"]
        row = {
            "cell": name,
            "K": k,
            "path": module.path.split(":")[0],
            "separate member-steps/s": k / best_sep,
            "ensemble member-steps/s": k / best_ens,
            "ensemble / separate": best_sep / best_ens,
        }
        rows.append(row)
        print(line(row.values()), flush=True)
        if ceilings is not None and fixed is not None:
            ceiling = 1 / (1 - fixed + fixed / k)
            ceilings.append(
                {
                    "cell": name,
                    "K": k,
                    "fixed share of a separate member-step": fixed,
                    "ceiling": ceiling,
                    "ensemble / separate": row["ensemble / separate"],
                    "of the ceiling": row["ensemble / separate"] / ceiling,
                }
            )
            print("  ceiling: " + line(ceilings[-1].values()), flush=True)
        if module.path.startswith("loop"):
            print(f"  ({name}: {module.path})", flush=True)
        if splits is not None and k == max(ks):
            for way, fn in (
                ("separate", lambda: separate_step(mods, opts, batch)),
                ("ensemble", lambda: ensemble_step(module, opt, batch)),
            ):
                part = split(fn, steps)
                total = sum(part.values())
                splits.append(
                    {
                        "cell": name,
                        "K": k,
                        "way": way,
                        "ms per member-step": total / k,
                        **{f"{p} share": v / total for p, v in part.items()},
                    }
                )
                print(line(splits[-1].values()), flush=True)
    return rows


def mlp_rows(ks: list[int], steps: int, repeats: int, width: int = 200, rows: int = 30, dim: int = 2) -> list[dict]:
    """Forward + backward of the lim_kasim network (2 × ``width`` softplus MLP on ``rows`` states of ``dim``) for K
    members three ways: K separate nets in turn; ``vmap`` of ``functional_call`` over stacked weights (what
    ``encons.training.stacked`` does); an ensemble dimension written into the layers (``baddbmm`` on (K, in, out)
    weights)."""
    from torch.func import functional_call, stack_module_state, vmap

    from encons.models.networks import mlp

    out = []
    for k in ks:
        nets = [mlp(dim, dim, width, 2) for _ in range(k)]
        params, _ = stack_module_state(nets)
        weights = [params[f"{i}.weight"].detach().transpose(1, 2).contiguous().requires_grad_() for i in (0, 2, 4)]
        biases = [params[f"{i}.bias"].detach().unsqueeze(1).contiguous().requires_grad_() for i in (0, 2, 4)]
        x = torch.randn(rows, dim)
        xs = x.expand(k, rows, dim)

        def separate():
            for net in nets:
                net(x).sum().backward()

        def vmapped():
            vmap(lambda p, x: functional_call(nets[0], p, (x,)), in_dims=(0, None))(params, x).sum().backward()

        def dimension():
            h = xs
            for i, (w, b) in enumerate(zip(weights, biases)):
                h = torch.baddbmm(b, h, w)
                h = torch.nn.functional.softplus(h) if i < 2 else h
            h.sum().backward()

        best = {"separate": float("inf"), "vmap": float("inf"), "dimension": float("inf")}
        for _ in range(repeats):
            for name, fn in (("separate", separate), ("vmap", vmapped), ("dimension", dimension)):
                best[name] = min(best[name], timed(fn, steps))
        row = {
            "K": k,
            "separate ms": 1e3 * best["separate"],
            "vmap ms": 1e3 * best["vmap"],
            "ensemble dimension ms": 1e3 * best["dimension"],
            "separate / vmap": best["separate"] / best["vmap"],
            "separate / dimension": best["separate"] / best["dimension"],
        }
        out.append(row)
        print(line(row.values()), flush=True)
    return out


class _Data:
    """The one batch ``encons.training.ensemble._module``'s probe reads, as a data module would serve it."""

    def __init__(self, batch: dict):
        self.batch = batch

    def train_dataloader(self):
        return [self.batch]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cells", nargs="+", default=list(CELLS), choices=list(CELLS))
    parser.add_argument("--members", nargs="+", type=int, default=[1, 2, 4, 8, 16])
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument(
        "--path",
        choices=["auto", "stacked"],
        default="auto",
        help="auto: the path a run takes (timed on the first batch); stacked: the stacked path wherever it computes",
    )
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument(
        "--layers", action="store_true", help="also time the network alone: vmap vs an ensemble dimension"
    )
    parser.add_argument("--split", action="store_true", help="also split one step at the largest K (torch.profiler)")
    parser.add_argument(
        "--ceiling", action="store_true", help="also measure each cell's fixed cost and the ratio's ceiling from it"
    )
    args = parser.parse_args()
    threads.apply(args.threads)
    cache = tempfile.mkdtemp()
    header = ["cell", "K", "path", "separate member-steps/s", "ensemble member-steps/s", "ensemble / separate"]
    print(" | ".join(header), flush=True)
    splits: list[dict] | None = [] if args.split else None
    ceilings: list[dict] | None = [] if args.ceiling else None
    rows = [
        r
        for name in args.cells
        for r in measure(
            name,
            CELLS[name],
            args.members,
            max(1, args.steps // (10 if name.startswith(SLOW) else 1)),
            args.repeats,
            cache,
            splits,
            None if args.path == "auto" else True,
            ceilings,
        )
    ]
    tables = [(header, rows)]
    if splits:
        tables.append((list(splits[0]), splits))
    if ceilings:
        tables.append((list(ceilings[0]), ceilings))
    if args.layers:
        print("network alone (lim_kasim 2 × 200 softplus, 30 states), forward + backward:", flush=True)
        layer_rows = mlp_rows(args.members, args.steps, args.repeats)
        tables.append((list(layer_rows[0]), layer_rows))
    if args.out:
        lines = []
        for head, body in tables:
            lines += ["", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
            lines += [
                "| " + " | ".join(f"{r[h]:.3g}" if isinstance(r[h], float) else str(r[h]) for h in head) + " |"
                for r in body
            ]
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(
            "\n".join(lines) + f"\n\n{torch.get_num_threads()} thread(s); command: python "
            f"benchmarks/ensemble_speed.py {' '.join(__import__('sys').argv[1:])}\n"
        )


if __name__ == "__main__":
    main()
