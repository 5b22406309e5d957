"""Result tables of the README and ``docs/``, rendered from committed reports (``python -m encons.report --docs``).

A table lives between two markers in the Markdown; the opening one names its source and columns::

    <!-- encons-report: benchmarks/reports/finzi-2000/summary.csv | system, model, test/geom_rel_err: encons -->
    | system | model | encons |
    ...
    <!-- /encons-report -->

Each column is ``CSV column`` or ``CSV column: header``. An optional ``| where COLUMN=V1,V2`` keeps only the
rows whose COLUMN is one of the values. Numbers print to 3 significant digits; an empty cell prints ``—``
(a metric that does not apply). ``render`` rewrites every block from its CSV; ``stale`` lists the blocks
whose text differs, each as ``(markdown file, source CSV)``, so a check names the file and the table.
"""

from __future__ import annotations

import csv
import re
from pathlib import Path

from encons.infra.errors import ConfigError
from encons.infra.io import write_text

ROOT = Path(__file__).resolve().parents[2]
BLOCK = re.compile(r"(<!-- encons-report: (?P<spec>.*?) -->\n)(?P<body>.*?)(<!-- /encons-report -->)", re.S)


def documents(root: Path = ROOT) -> list[Path]:
    """The Markdown a reader sees: the README and every page of the manual."""
    return [root / "README.md", *sorted((root / "docs").glob("*.md"))]


def _cell(text: str) -> str:
    if text.strip() == "":
        return "—"
    try:
        value = float(text)
    except ValueError:
        return text
    return text if text.isdigit() else f"{value:.3g}"


def table(spec: str, root: Path = ROOT) -> str:
    """The Markdown table a marker's ``spec`` describes, read from its CSV."""
    source, _, rest = (part.strip() for part in spec.partition("|"))
    columns_spec, _, where = rest.partition("| where ")
    path = root / source
    allowed = "allowed: a committed CSV under benchmarks/reports/ and its column names"
    if not source.startswith("benchmarks/reports/") or not path.is_file():
        raise ConfigError(f"source={source!r} is not a committed report file; {allowed}")
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    columns = [
        tuple(p.strip() for p in c.split(":", 1)) if ":" in c else (c.strip(), c.strip())
        for c in columns_spec.split(",")
        if c.strip()
    ]
    missing = [c for c, _ in columns if rows and c not in rows[0]]
    if missing:
        raise ConfigError(f"columns={missing} not in {source}; {allowed}")
    if where.strip():
        key, _, values = where.partition("=")
        keep = {v.strip() for v in values.split(",")}
        rows = [r for r in rows if r.get(key.strip()) in keep]
    lines = ["| " + " | ".join(h for _, h in columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(_cell(r[c]) for c, _ in columns) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def render(text: str, root: Path = ROOT) -> str:
    """``text`` with every marked block re-rendered from its source."""
    return BLOCK.sub(lambda m: m.group(1) + table(m.group("spec"), root) + m.group(4), text)


def stale(root: Path = ROOT) -> list[tuple[str, str]]:
    """(markdown file, source CSV) of every block whose committed text differs from a fresh render."""
    out = []
    for doc in documents(root):
        for m in BLOCK.finditer(doc.read_text()):
            if m.group("body") != table(m.group("spec"), root):
                out.append((str(doc.relative_to(root)), m.group("spec").partition("|")[0].strip()))
    return out


def write(root: Path = ROOT) -> list[Path]:
    """Re-render every block in place; the files that changed."""
    changed = []
    for doc in documents(root):
        text = doc.read_text()
        new = render(text, root)
        if new != text:
            write_text(doc, new)
            changed.append(doc)
    return changed
