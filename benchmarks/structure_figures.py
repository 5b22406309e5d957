"""Issue 40's figures: target lookups of one ``debug=fast`` run from the Python API, the stops ``cfg``
makes in build/config/trust, import cycles between encons modules, and the test metrics of three configs
(the refactor's behaviour check: same digits before and after).

    python benchmarks/structure_figures.py OUT.json [--metrics]
"""

from __future__ import annotations

import ast
import collections
import json
import sys
import tempfile
from pathlib import Path

WATCHED = ("encons.build", "encons.config", "encons.trust")
CONFIGS = [("model=hnn", "system=pendulum1"), ("model=chnn", "system=gyroscope"),
           ("model=glnn", "system=damped_oscillator")]


def imports_graph(package: Path) -> dict[str, set[str]]:
    """Every ``encons`` module → the encons modules it imports anywhere (TYPE_CHECKING, __main__, lazily)."""
    modules = {".".join(p.relative_to(package.parent).with_suffix("").parts).removesuffix(".__init__"): p
               for p in package.rglob("*.py")}
    graph = {}
    for name, path in modules.items():
        found = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0 and node.module.startswith("encons"):
                for a in node.names:
                    sub = f"{node.module}.{a.name}"
                    found.add(sub if sub in modules else node.module)
            elif isinstance(node, ast.Import):
                found.update(a.name for a in node.names if a.name.startswith("encons"))
        graph[name] = {m for m in found if m in modules and m != name}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    sys.setrecursionlimit(10000)
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def run(overrides, tmp: Path, count: bool):
    import encons
    from encons import trust

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
    import encons

    out = {}
    graph = imports_graph(Path(encons.__file__).parent)
    out["import_cycles"] = cycles(graph)
    with tempfile.TemporaryDirectory() as tmp:
        metrics, calls, stops = run(CONFIGS[0], Path(tmp) / "count", True)
        out["lookups"] = {"total": sum(calls.values()), "targets": len(calls), "per_target": dict(calls.most_common())}
        # the stops of cfg's route: calls into build/config/trust from another module (not from one of the
        # three, not this script's counting wrapper, not contextlib running build's ``with trust.whitelist()``)
        out["entries_from_outside"] = dict(collections.Counter(
            s.split(" -> ")[1].split(".")[1] for s in stops if not s.startswith((*WATCHED, "__main__", "contextlib"))))
        out["entries_from_encons_modules"] = dict(collections.Counter(s.split(" -> ")[1].rsplit(".", 1)[0] for s in stops))
        out["entry_calls"] = stops
        if "--metrics" in sys.argv:
            out["metrics"] = {}
            for i, overrides in enumerate(CONFIGS):
                m = metrics if i == 0 else run(overrides, Path(tmp) / str(i), False)[0]
                out["metrics"][" ".join(overrides)] = {k: v for k, v in sorted(m.items())
                                                        if k.startswith("test/") or k.startswith("best/")}
    Path(sys.argv[1]).parent.mkdir(parents=True, exist_ok=True)
    Path(sys.argv[1]).write_text(json.dumps(out, indent=1) + "\n")
    print(json.dumps({k: v for k, v in out.items() if k != "metrics"}, indent=1))


if __name__ == "__main__":
    main()
