"""Issue 40's figures: target lookups (``encons.config.trust.locate``) of one ``debug=fast`` run of
``model=hnn system=pendulum1`` from the Python API (composing not counted), the calls into
build/config/trust from other modules on that run, import cycles between encons modules (every import
counted, by ``tests/test_structure.py``'s own graph), and the test metrics of three configs (the
refactor's behaviour check: the same digits before and after).

    PYTHONPATH=. python benchmarks/structure_figures.py OUT.json [--metrics]
"""

from __future__ import annotations

import collections
import json
import sys
import tempfile
from pathlib import Path

WATCHED = ("encons.training.build", "encons.config.check", "encons.config.trust")
CONFIGS = [
    ("model=hnn", "system=pendulum1"),
    ("model=chnn", "system=gyroscope"),
    ("model=glnn", "system=damped_oscillator"),
]


def run(overrides, tmp: Path, count: bool):
    import encons
    from encons.config import trust

    calls: collections.Counter = collections.Counter()
    stops: list[str] = []
    real = trust.locate

    def counted(target, *a, **k):
        calls[target] += 1
        return real(target, *a, **k)

    def tracer(frame, event, arg):
        if event == "call":
            name = frame.f_globals.get("__name__", "")
            caller = frame.f_back.f_globals.get("__name__", "") if frame.f_back else ""
            if name in WATCHED and caller != name:  # entered from another module
                stops.append(f"{caller} -> {name}.{frame.f_code.co_name}")
        return None

    cfg = encons.compose(*overrides, "debug=fast", "logger=none", output_dir=tmp / "run", cache_dir=tmp / "cache")
    if count:
        trust.locate = counted
        sys.setprofile(None)
        sys.settrace(tracer)
    try:
        metrics = encons.train(cfg, summary=False).metrics
    finally:
        sys.settrace(None)
        trust.locate = real
    return metrics, calls, stops


def main() -> None:
    from tests.test_structure import PACKAGE, cycles, import_graph

    out = {"import_cycles": cycles(import_graph(PACKAGE))}
    with tempfile.TemporaryDirectory() as tmp:
        metrics, calls, stops = run(CONFIGS[0], Path(tmp) / "count", True)
        out["lookups"] = {"total": sum(calls.values()), "targets": len(calls), "per_target": dict(calls.most_common())}
        # the stops of cfg's route: calls into build/config/trust from another module (not from one of the
        # three, not this script's counting wrapper, not contextlib running a ``with`` of one of them)
        out["entries_from_outside"] = dict(
            collections.Counter(
                s.split(" -> ")[1].split(".")[1]
                for s in stops
                if not s.startswith((*WATCHED, "__main__", "contextlib"))
            )
        )
        out["entries_from_encons_modules"] = dict(
            collections.Counter(s.split(" -> ")[1].rsplit(".", 1)[0] for s in stops)
        )
        out["entry_calls"] = stops
        if "--metrics" in sys.argv:
            out["metrics"] = {}
            for i, overrides in enumerate(CONFIGS):
                m = metrics if i == 0 else run(overrides, Path(tmp) / str(i), False)[0]
                out["metrics"][" ".join(overrides)] = {
                    k: v for k, v in sorted(m.items()) if k.startswith("test/") or k.startswith("best/")
                }
    Path(sys.argv[1]).parent.mkdir(parents=True, exist_ok=True)
    Path(sys.argv[1]).write_text(json.dumps(out, indent=1) + "\n")
    print(json.dumps({k: v for k, v in out.items() if k != "metrics"}, indent=1))


if __name__ == "__main__":
    main()
