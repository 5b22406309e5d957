"""How much the absolute guard that ``guarded_solve`` replaced shrank the true q̈: shrink.json beside this script.

    PYTHONPATH=. OMP_NUM_THREADS=1 python benchmarks/reports/lnn-guard/shrink.py

The old solve was damped least squares at a fixed λ = 1: q̈ = (HᵀH + λ²I)⁻¹Hᵀr. Fed the true Lagrangian,
H = ∇²_q̇L = M(q), and the true q̈ along M's eigenvector of its smallest eigenvalue σ comes back multiplied by
σ² / (σ² + λ²). Per system (default settings, float64), over the states tests/models/test_unbiased_solve.py feeds
(``sample_initial`` of 1024 states, generator seed 3, the gyroscope's kept |sin θ| ≥ 0.1 as its data are, the first
256): the factor measured by the old solve itself (its q̈ along that eigenvector over the true q̈'s) and σ, as
median / min / max over the states. The factor equals the closed form to rounding (``closed_form_max_abs_err``).
"""

from __future__ import annotations

import json
from pathlib import Path

import torch
from hydra.utils import execution_whitelist

from encons.config.check import validate
from encons.config.trust import trusted_targets
from encons.entry import api
from encons.training.build import build_system

HERE = Path(__file__).resolve().parent
SYSTEMS = ["pendulum1", "pendulum2", "pendulum4", "gyroscope", "damped_oscillator", "compound_pendulum"]
LAMBDA = 1.0


def states(system, n: int = 256) -> torch.Tensor:
    """As tests/models/test_unbiased_solve.py's ``physical_states``."""
    s = system.sample_initial(4 * n, torch.Generator().manual_seed(3))
    if system.name == "gyroscope":
        s = s[torch.sin(s[:, 1]).abs() >= 0.1]
    return s[:n].double()


def stats(x: torch.Tensor) -> dict[str, float]:
    return {"median": x.median().item(), "min": x.min().item(), "max": x.max().item()}


def main() -> None:
    torch.set_num_threads(1)
    out = {"what": __doc__.split("\n")[0], "lambda": LAMBDA, "systems": {}}
    for name in SYSTEMS:
        with execution_whitelist(trusted_targets()):
            system = build_system(validate(api.compose(f"system={name}", output_dir=".")))
        s = states(system)
        m = system.mass_matrix(s[:, : s.shape[1] // 2]).double()  # H = M(q), symmetric positive definite
        sigma, vectors = torch.linalg.eigh(m)
        v = vectors[..., 0]  # M's smallest direction
        true = v  # a true q̈ along it ...
        r = (m @ true.unsqueeze(-1)).squeeze(-1)  # ... and the right-hand side that gives it
        eye = torch.eye(m.shape[-1], dtype=m.dtype)
        old = torch.linalg.solve(m.mT @ m + LAMBDA**2 * eye, (m.mT @ r.unsqueeze(-1))).squeeze(-1)
        factor = (old * v).sum(-1) / (true * v).sum(-1)
        closed = sigma[:, 0] ** 2 / (sigma[:, 0] ** 2 + LAMBDA**2)
        out["systems"][name] = {
            "states": int(s.shape[0]),
            "shrink": stats(factor),
            "sigma_min": stats(sigma[:, 0]),
            "closed_form_max_abs_err": (factor - closed).abs().max().item(),
        }
    (HERE / "shrink.json").write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
