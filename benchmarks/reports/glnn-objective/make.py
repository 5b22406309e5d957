"""GLNN on the example recording: objective=rollout (the default) against objective=acceleration, seeds 0-2.

    python benchmarks/reports/glnn-objective/make.py OUT [EPOCHS]

writes OUT/example.npz (``python -m encons.data.recording``), trains one seed ensemble per objective on it with
the docs/data.md command at the same budget, and prints one CSV row per objective and seed (test metrics of the
best-by-validation checkpoint, its 1-based epoch; whether the run logged a stall line; the ensemble's wall) to stdout.
"""

import json
import subprocess
import sys
import time
from pathlib import Path

out = Path(sys.argv[1]).resolve()
epochs = sys.argv[2] if len(sys.argv) > 2 else "100"
out.mkdir(parents=True, exist_ok=True)
py = [sys.executable, "-m"]
if not (out / "example.npz").exists():
    subprocess.run([*py, "encons.data.recording", str(out / "example.npz")], check=True, capture_output=True)
base = ["system=from_file", f"system.path={out / 'example.npz'}", "data.recording.angles=true", "model=glnn",
        "model.angular=true", "data.n_steps=50", "data.test_steps=200", "logger=none", "figures=false",
        "trainer.enable_progress_bar=false", f"trainer.max_epochs={epochs}", "seeds=[0,1,2]"]
keys = ["traj_rel_err", "traj_rel_err_window", "state_mse", "baseline_linear_ode/traj_rel_err"]
print("objective,seed," + ",".join(keys) + ",best_epoch,stalled,ensemble_wall_s")
for objective in ("rollout", "acceleration"):
    run = out / objective
    started = time.perf_counter()
    subprocess.run([*py, "encons.train", *base, f"objective={objective}", f"hydra.run.dir={run}"], check=True,
                   capture_output=True)
    wall = time.perf_counter() - started
    stalled = [line for line in (run / "train.log").read_text().splitlines() if "stalled:" in line]
    for seed in (0, 1, 2):
        m = json.loads((run / f"seed{seed}" / "test_metrics.json").read_text())
        best = int(next((run / f"seed{seed}" / "checkpoints").glob("best-epoch*.ckpt")).stem.removeprefix("best-epoch"))
        print(f"{objective},{seed}," + ",".join(f"{m[k]:.6g}" for k in keys)
              + f",{best},{bool(stalled)},{wall:.0f}", flush=True)
