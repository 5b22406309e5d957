"""Speed of the field Jacobians behind Lim & Kasim's regularisers: vectorised vs a Python loop.

Per call, for a batch of states through a d → d Softplus MLP field: ``vmap(jacrev)`` and
``vmap(jacfwd)`` (``encons.numerics.regularisers.field_jacobian``) against one batched
``autograd.grad(create_graph=True)`` per output dimension (the authors' ``compute_jacobian``).
Columns: the Jacobian alone, and the whole training use (C_H of eq. (4), batch mean, backward
to the parameters). The fastest of ``--repeats`` calls is reported in process CPU time, which
other people's load on a shared machine disturbs least (run with ``--threads 1`` there).

    python benchmarks/jacobian_speed.py [--dims 2 4 8] [--batch 1024] [--hidden 200] [--threads 1]
"""

from __future__ import annotations

import argparse
import time
from typing import Callable

import torch
from torch import Tensor, nn

from encons.infra import threads
from encons.models.networks import mlp
from encons.numerics.regularisers import field_jacobian, hamiltonian_violation


def loop_jacobian(field: nn.Module, z: Tensor) -> Tensor:
    """One batched autograd.grad per output dimension (the baseline; not used by encons)."""
    z = z.detach().requires_grad_(True)
    out = field(z)
    rows = [torch.autograd.grad(out[:, i].sum(), z, create_graph=True)[0] for i in range(out.shape[-1])]
    return torch.stack(rows, -2)


METHODS: dict[str, Callable[[nn.Module, Tensor], Tensor]] = {
    "vmap(jacrev)": lambda f, z: field_jacobian(f, z, "reverse"),
    "vmap(jacfwd)": lambda f, z: field_jacobian(f, z, "forward"),
    "autograd loop": loop_jacobian,
}


def fastest_ms(fn: Callable[[], object], repeats: int) -> float:
    fn()
    best = float("inf")
    for _ in range(repeats):
        start = time.process_time()
        fn()
        best = min(best, time.process_time() - start)
    return 1e3 * best


def main() -> None:
    parser = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    parser.add_argument("--dims", type=int, nargs="+", default=[2, 4, 8])
    parser.add_argument("--batch", type=int, default=1024)
    parser.add_argument("--hidden", type=int, default=200)
    parser.add_argument("--depth", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument(
        "--threads", type=int, default=None, help="torch threads (default: encons.infra.threads' policy)"
    )
    args = parser.parse_args()
    threads.apply(args.threads)
    torch.manual_seed(0)
    print(
        f"batch {args.batch}, MLP {args.depth} × {args.hidden} softplus, {torch.get_num_threads()} thread(s); "
        "ms per call (fastest of {args.repeats}, process CPU time)".replace("{args.repeats}", str(args.repeats))
    )
    print(f"{'d':>3} {'method':<15} {'Jacobian':>10} {'C_H + backward':>15} {'vs loop':>8}")
    for d in args.dims:
        field = mlp(d, d, args.hidden, args.depth, "softplus")
        z = torch.randn(args.batch, d)
        reference = loop_jacobian(field, z)
        timings = {}
        for name, method in METHODS.items():
            assert torch.allclose(method(field, z), reference, atol=1e-5), name
            jac_ms = fastest_ms(lambda: method(field, z), args.repeats)
            train_ms = fastest_ms(lambda: hamiltonian_violation(method(field, z)).mean().backward(), args.repeats)
            timings[name] = (jac_ms, train_ms)
        for name, (jac_ms, train_ms) in timings.items():
            speedup = timings["autograd loop"][1] / train_ms
            print(f"{d:>3} {name:<15} {jac_ms:>10.2f} {train_ms:>15.2f} {speedup:>7.2f}×")


if __name__ == "__main__":
    main()
