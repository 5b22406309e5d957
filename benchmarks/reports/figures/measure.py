import tempfile, time, torch, encons
TMP = tempfile.gettempdir()
torch.set_num_threads(1)
def run(i, fig):
    cfg = encons.compose("debug=fast", "model=node", "system=pendulum2", "logger=none", f"figures={fig}",
                         output_dir=f"{TMP}/encons-figcost/{fig}{i}", cache_dir=f"{TMP}/encons-figcost/cache")
    t = time.perf_counter(); encons.train(cfg, summary=False); return time.perf_counter() - t
run(0, "true")
rows = [(fig, run(i, fig)) for i in range(1, 4) for fig in ("true", "false")]
for fig in ("true", "false"):
    w = sorted(t for f, t in rows if f == fig)
    print(f"| figures={fig} | {' / '.join(f'{t:.2f}' for t in w)} | {w[1]:.2f} |")
