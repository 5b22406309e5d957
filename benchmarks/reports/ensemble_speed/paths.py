"""Which path each model takes in a 2-seed ensemble (debug=fast, its usual system)."""
import tempfile, torch
from encons import api, ensemble
from encons.build import build
torch.set_num_threads(1)
cache = tempfile.mkdtemp()
CASES = [("node","pendulum2",[]),("hnn","pendulum2",[]),("hnn_angle","pendulum2",[]),("hnn_structure","pendulum2",[]),
 ("hnn_structure_angle","pendulum2",[]),("lnn","pendulum2",[]),("lnn_angle","pendulum2",[]),("lnn_structure","pendulum2",[]),
 ("lnn_structure_angle","pendulum2",[]),("chnn","gyroscope",[]),("clnn","gyroscope",[]),("nsf","mass_spring",[]),
 ("inn_node","mass_spring",["regulariser=hamiltonian"]),("node","mass_spring",["regulariser=hamiltonian"]),
 ("lnode","pendulum_control",[]),("symo","pendulum_control",["objective=residual"]),("e2e_symo","pendulum_control",[]),
 ("glnn","damped_oscillator",[]),("second_order","damped_oscillator",[]),("node","pixel_pendulum",[])]
for model, system, extra in CASES:
    try:
        mods, data = [], None
        for s in (0, 1):
            cfg = api.compose(f"model={model}", f"system={system}", "debug=fast", "logger=none", *extra, f"seed={s}",
                              output_dir=tempfile.mkdtemp(), cache_dir=cache)
            d, m = build(cfg); mods.append(m); data = data or d
        path = ensemble._module(cfg, mods, [0, 1], data, None).path
    except Exception as err:
        path = f"ERROR {type(err).__name__}: {str(err).splitlines()[0][:150]}"
    print(f"| {model} {' '.join(extra)} | {system} | {path} |", flush=True)
