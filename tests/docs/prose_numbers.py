"""Prose numbers tied to committed files: the rules ``tests/docs/test_prose_numbers.py`` applies.

A reader meets numbers in README.md, ``docs/*.md`` and every ``.md`` under ``benchmarks/reports`` (a report's
README.md and RUN.md, and its hand-written diagnostics such as ``xiao-300/compound_divergence.md``). Each printed
number is one of three things:

* **not looked at**: inside a fenced block or a backtick span (a command, a key, a config value: by
  convention a number in backticks is a setting, not a result), inside a rendered table
  (``<!-- encons-report: ... -->``, checked by ``tests/docs/test_docs.py``), a link target, a heading, part of a
  word (``pendulum2``, ``L-NODE-RK4``, ``float64``), a list item's number, a year after a citation
  (``Zhong et al. 2021``), a date or a clock time (``27 November 2026``, ``26–27 November``, ``2026-11-26``,
  ``01:11–01:18``) or a reference (``§6``, ``Table 1``, ``Fig. 3``, ``Eq. 12``, ``eqs. 15``, ``equation (11)``,
  ``Theorem 1``, ``issue 42``; a range such as ``Figs. 3–4`` or ``eqs. 12–13`` too);
* **a setting**, by its word: a number list next to a setting's key or unit from ``SETTING`` (``lr 1e-3``,
  ``seeds 0–2``, ``N_train 8, 32, 128``, ``2000 epochs``, ``800 training trajectories``, ``3 × 200``
  networks, a hyphenated ``32-step`` rollout, ``16 cells``, ``12 runs``, ``nice 19``): the word marks it as a
  configuration or a size, not a result. A number joined to the unit by a
  preposition or article (``0.595 at epoch 37``, ``272 by epoch 300``) is a result at that setting: only the
  setting's own number (37, 300) is exempt;
* **marked** as not a result: the paragraph holds ``<!-- not-a-result: REASON N1 N2 ... -->``, whose
  numbers (as printed) are exempt in that paragraph. REASON says what they are, e.g. ``config``, ``size``,
  ``date``, ``paper Finzi et al. Table 2``. Only the listed numbers are exempt;
* **tied**: the paragraph (a block between blank lines; a list item or a table row is its own paragraph)
  names a committed file or folder by a relative path (to the repository or to the document) that holds
  the number. The items of a list speak with the paragraph that introduces them (the one just above, ending
  in a colon, or a list item ending in a colon for its sub-items), so a lead-in that names the file ties its
  items too. A paragraph that names a file or folder ties only to what it names (a named folder stands for its
  text files, recursively): naming ``a.csv`` does not let a number come from ``b.csv`` beside it. A report's
  document (any ``.md`` in a report's folder) also speaks for its own tables, and, in a paragraph that (with
  its lead-in) names nothing, for the files beside it (its folder, recursively). A ``.md`` used as a source,
  named or met in a folder's walk, gives only its table lines: prose never ties prose, so a number printed
  only in another document's prose (or the document's own) ties nothing;
* **recorded**: a table row of a report's ``.md`` is the report's record itself (a table typed where the run
  printed it, with no CSV beside it); prose that quotes it names that file.

A printed number matches a file if the file holds a number that prints the same at the printed precision:
``3.07e-5`` matches ``3.0712e-05`` (three significant digits), ``0.0000307`` matches it too (seven decimals),
``1,000`` is ``1000``, a file's ``−8.4`` (U+2212) matches ``−8.4`` or, as a drop, ``8.4``, a percentage
matches the file's fraction too (``94.7 %`` a file's ``0.947``; a percentage is a number followed by ``%``, or
by a list of numbers that ends in ``%``, as ``90 / 94 / 100 %`` or ``17–82 %``: a bare ``94.7`` or ``90``
matches only as printed, so a fraction ×100 that happens to print the same ties nothing), and a ratio
``1.71×`` matches a file's ``1.71`` or the quotient of two numbers the same paragraph prints (``0.169 vs
0.0994``). Anything else fails, naming the file, the line and the paragraph.

**Pending.** The paragraphs that held untied numbers when this check was written are listed by fingerprint (file
and a hash of the paragraph's text) in ``tests/docs/prose_numbers_pending.txt``: the debt, not an exemption of new
text. Any edit to such a paragraph changes its hash, so it must then be tied or marked; a listed paragraph that
is tied now, or gone, must leave the list. The list only shrinks.
"""

from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TEXT = {".csv", ".md", ".json", ".jsonl", ".yaml", ".txt", ".log", ".py"}

NUMBER = re.compile(r"(?<![\w.\-/^])[-−]?(?:\d{1,3}(?:,\d{3})+|\d+)(?:\.\d+)?(?:[eE][-+−]?\d+)?(?![\w/]|\.\d)")
FILE_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
MARK = re.compile(r"<!--\s*not-a-result:(.*?)-->", re.S)
PATH = re.compile(r"(?<![\w/.])((?:\.\./)*[\w.-]+(?:/[\w.+-]+)*/?)")
REFERENCE = re.compile(
    r"(?:§|\bTables?\s|\bTab\.\s|\bFigs?\.\s|\bFigure\s|\b[Ee]qs?\.\s\(?|\b[Ee]quation\s\(?|"
    r"\bTheorem\s|\bSection\s|\bissue\s|\bAppendix\s|"
    r"\bet al\.,?\s|\bet al\.\s\(|&\s\w+\s|\bPR\s|#)$"
)
RANGE = re.compile(r"(?:§|\bTables?\s|\bFigs?\.\s|\b[Ee]qs?\.\s\(?)\d+(?:\.\d+)?\)?(?:\s*[–/-]\s*|,\s|\sand\s)\(?$")


_N = r"[-−]?\d[\d,]*(?:\.\d+)?(?:[eE][-+−]?\d+)?"
_LIST = rf"{_N}(?:\s*(?:,|–|-|…|\.\.\.|/|and|or|to|and then)\s*{_N})*"
KEYS = (
    r"lr|learning rates?|seeds?|batch(?: size)?|widths?|depths?|N_train|n_train|rtol|atol|tol|weight decay|epochs?|"
    r"K|k|dt|horizon|noise|patience|max_epochs|chunks? of|windows? of|step size|grid of|every|nice(?: -n)?"
)
UNITS = (
    r"epochs?|trajector(?:y|ies)|steps?|seeds|networks?|layers?|hidden units|units|neurons|starts|members|cores?|"
    r"threads?|workers?|points|samples|GPUs?|CPUs?|iterations|batches|dimensions|frames|links|bodies|trials|"
    r"time steps|hidden layers|pixels|px|channels|evaluations|rollouts|states|digits|bits|masses|pendulums|"
    r"cells|models|runs|windows|videos"
)
_MONTH = (
    r"(?:January|February|March|April|May|June|July|August|September|October|November|December|"
    r"Jan|Feb|Mar|Apr|Jun|Jul|Aug|Sept?|Oct|Nov|Dec)\b\.?"
)
DATE = re.compile(
    rf"\b(?:\d{{1,2}}[–-])?\d{{1,2}}\s+{_MONTH}(?:\s+\d{{4}})?|\b{_MONTH}\s+\d{{1,2}}(?:,?\s+\d{{4}})?\b|"
    rf"\b{_MONTH}\s+\d{{4}}|"
    r"\b\d{4}-\d\d-\d\d\b|\b\d{1,2}:\d\d(?::\d\d)?(?:[–-]\d{1,2}:\d\d(?::\d\d)?)?\b"
)
#: words that join a result to a unit rather than qualify the unit ("0.595 at epoch 37" is a result at a setting)
_JOINS = r"(?:at|in|after|by|over|from|to|per|of|on|for|and|or|than|vs|against|the|a|an)\b"
SETTING = re.compile(
    rf"(?<![\w.])(?:(?:{KEYS})\s*(?:=|:|of)?\s*{_LIST}|{_LIST}(?:\s+(?:(?!{_JOINS})[a-z-]+\s+)?|-)(?:{UNITS})\b|"
    rf"\d+\s*[×x]\s*\d+(?:\s*[×x]\s*\d+)*(?!\.\d|\d))"
)

#: what follows a percentage: "%", or a list of numbers that ends in "%" ("90 / 94 / 100 %", "17–82 %")
PERCENT = re.compile(rf"(?:\s*(?:,|–|-|/|and|or|to|vs\.?)\s*{_N})*\s?%")


def documents(root: Path = ROOT) -> list[Path]:
    """The prose a reader meets: README.md, docs/*.md and every .md under benchmarks/reports."""
    reports = root / "benchmarks" / "reports"
    return [
        root / "README.md",
        *sorted((root / "docs").glob("*.md")),
        *sorted(reports.rglob("*.md")),
    ]


@dataclass
class Paragraph:
    doc: Path
    line: int
    text: str  # as written
    exempt: set[str] = field(default_factory=set)
    settings: int = 0
    lead: str = ""  # a list item's lead-in paragraph (ending in a colon), else empty
    percent: set[int] = field(default_factory=set)  # indices (in ``numbers(p)``) of numbers followed by %


def paragraphs(doc: Path) -> list[Paragraph]:
    """The paragraphs of ``doc`` with fenced blocks and rendered tables dropped; list items and table rows
    are paragraphs of their own, a paragraph's line is where it starts."""
    text = doc.read_text()
    text = re.sub(
        r"```.*?```|<!-- encons-report:.*?<!-- /encons-report -->",
        lambda m: "\n" * m.group(0).count("\n"),
        text,
        flags=re.S,
    )
    out: list[Paragraph] = []
    lines: list[str] = []
    start = 0
    for i, line in enumerate([*text.split("\n"), ""], 1):
        item = re.match(r"\s*(?:[-*+]|\d+\.)\s|\s*\|", line)
        if not line.strip() or (item and lines and not lines[-1].rstrip().endswith("<!--")):
            if lines:
                out.append(Paragraph(doc, start, "\n".join(lines)))
            lines = []
        if line.strip():
            if not lines:
                start = i
            lines.append(line)
    lead, depth = "", -1  # the lead-in in force, and its indent (-1: a paragraph, not an item)
    for p in out:
        item = re.match(r"(\s*)(?:[-*+]|\d+\.)\s", p.text)
        indent = len(item.group(1)) if item else -1
        if item and indent > depth:
            p.lead = lead
        elif item or lead:
            lead, depth = "", -1
        if re.sub(r"<!--.*?-->", "", p.text, flags=re.S).rstrip().endswith(":") and not p.lead:
            lead, depth = p.text, indent
        for mark in MARK.findall(p.text):
            p.exempt |= {_canon(n) for n in NUMBER.findall(mark)}
    return out


def _canon(printed: str) -> str:
    return printed.replace(",", "").replace("−", "-").lstrip("+")


def _visible(text: str) -> str:
    """The text a reader reads as prose: comments, code spans, link targets and headings blanked out."""
    text = re.sub(r"<!--.*?-->", " ", text, flags=re.S)
    text = re.sub(r"`[^`]*`", " ", text)
    text = re.sub(r"\]\([^)]*\)", "]", text)
    text = re.sub(r"^\s*#+ .*$", " ", text, flags=re.M)
    return re.sub(r"^\s*\d+\.\s", " ", text, flags=re.M)


def numbers(p: Paragraph) -> list[str]:
    """The printed numbers of a paragraph that are looked at (see the module's first list)."""
    text = _visible(p.text)
    settings = [m.span() for m in SETTING.finditer(text)]
    dates = [m.span() for m in DATE.finditer(text)]
    found = []
    p.percent = set()
    for m in NUMBER.finditer(text):
        if any(a <= m.start() and m.end() <= b for a, b in dates):
            continue
        if any(a <= m.start() and m.end() <= b for a, b in settings):
            p.settings += 1
            continue
        before = text[max(0, m.start() - 20) : m.start()]
        if REFERENCE.search(before) or RANGE.search(text[max(0, m.start() - 30) : m.start()]):
            continue
        if re.match(r"(?:1[89]|20)\d\d$", m.group(0)) and re.search(r"(?:et al\.,?|&\s?\w+|\w+,)\s*\(?$", before):
            continue
        if PERCENT.match(text, m.end()):
            p.percent.add(len(found))
        found.append(m.group(0))
    return found


def is_report(doc: Path, root: Path = ROOT) -> bool:
    reports = root / "benchmarks" / "reports"
    return doc.parent != reports and reports in doc.parents


def is_record(p: Paragraph, root: Path = ROOT) -> bool:
    return is_report(p.doc, root) and p.text.lstrip().startswith("|")


def sources(p: Paragraph, root: Path = ROOT) -> list[Path]:
    """The committed files a paragraph (or its lead-in) names (a folder stands for its text files); for a report's
    document also the document itself (of a .md, ``file_numbers`` reads only the tables) and, only where the
    paragraph names nothing, the files beside it (its folder, recursively)."""
    named: list[Path] = []
    for candidate in PATH.findall(p.text + "\n" + p.lead):
        candidate = candidate.rstrip(".")
        if "/" not in candidate and "." not in candidate:
            continue
        for base in (root, p.doc.parent):
            path = (base / candidate).resolve()
            if path.exists() and root in path.parents and path != p.doc:
                named.append(path)
                break
    if is_report(p.doc, root):
        named += [p.doc] if named else [p.doc.parent, p.doc]
    files = []
    for path in named:
        if path.is_file():
            files.append(path)
        else:
            files += [
                f
                for f in sorted(path.rglob("*"))
                if f.is_file() and f.suffix in TEXT and f != p.doc and not f.name.startswith(".")
            ]
    return files


@lru_cache(maxsize=None)
def file_numbers(path: Path) -> tuple[float, ...]:
    """The numbers a file holds; of a .md only those in its tables (prose never ties prose)."""
    text = path.read_text(errors="replace")
    if path.suffix == ".md":
        text = "\n".join(line for line in text.splitlines() if line.lstrip().startswith("|"))
    text = text.replace(",", " ")
    # a U+2212 minus reads as a sign and, as before, as a magnitude ("−63.9 %" a drop of 63.9 %)
    signed = ["-" + n for n in re.findall(r"−((?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)", text)]
    values = []
    for n in FILE_NUMBER.findall(text) + signed:
        try:
            values.append(float(n))
        except ValueError:
            continue
    return tuple(values)


@lru_cache(maxsize=None)
def _printed(path: Path, how: str, digits: int, percent: bool = False) -> frozenset[str]:
    """The file's numbers printed at a precision; with ``percent`` also ×100 (a fraction printed as a percentage)."""
    fmt = f"{{:.{digits}{how}}}"
    out = set()
    for v in file_numbers(path):
        out.add(fmt.format(v))
        if percent:
            out.add(fmt.format(v * 100))
    return frozenset(out)


def _precision(printed: str) -> tuple[float, str, int]:
    """(value, format kind, digits): ``3.07e-5`` -> e with 2 digits, ``0.0000307`` -> f with 7."""
    text = _canon(printed)
    mantissa, _, exponent = text.lower().partition("e")
    if exponent:
        return float(text), "e", max(len(mantissa.lstrip("-").replace(".", "").lstrip("0")) - 1, 0)
    return float(text), "f", len(mantissa.partition(".")[2])


def matches(printed: str, path: Path, percent: bool = False) -> bool:
    """Whether ``path`` holds a number that prints as ``printed`` at its precision, or, where the printed number
    is a percentage (``percent``: followed by %), whose fraction it is (94.7 % for 0.947)."""
    value, how, digits = _precision(printed)
    return f"{{:.{digits}{how}}}".format(value) in _printed(path, how, digits, percent)


def is_ratio(printed: str, others: list[str]) -> bool:
    """Whether ``printed`` is, at its precision, the quotient of two of ``others``."""
    value, how, digits = _precision(printed)
    want = f"{{:.{digits}{how}}}".format(value)
    values = [float(_canon(o)) for o in others]
    return any(b and f"{{:.{digits}{how}}}".format(a / b) == want for a in values for b in values)


def fingerprint(p: Paragraph, root: Path = ROOT) -> str:
    """``file:hash`` of a paragraph's text (any edit changes it), as ``tests/docs/prose_numbers_pending.txt``
    lists it."""
    return f"{p.doc.relative_to(root)}:{hashlib.sha1(p.text.encode()).hexdigest()[:12]}"


@dataclass
class Verdict:
    tied: int = 0
    marked: int = 0
    settings: int = 0
    recorded: int = 0
    untied: list[str] = field(default_factory=list)
    paragraphs: set[str] = field(default_factory=set)  # fingerprints of the paragraphs with untied numbers
    where: dict[str, str] = field(default_factory=dict)  # an untied entry -> its paragraph's fingerprint


def check(root: Path = ROOT, docs: list[Path] | None = None) -> Verdict:
    verdict = Verdict()
    for doc in docs if docs is not None else documents(root):
        for p in paragraphs(doc):
            printed = numbers(p)
            if not printed:
                continue
            verdict.settings += p.settings
            files = sources(p, root)
            for i, n in enumerate(printed):
                if _canon(n) in p.exempt:
                    verdict.marked += 1
                elif any(matches(n, f, i in p.percent) for f in files if f != p.doc or not is_record(p, root)):
                    verdict.tied += 1
                elif re.search(rf"(?<![\w.]){re.escape(n)}\s?×", _visible(p.text)) and is_ratio(n, printed):
                    verdict.tied += 1
                elif is_record(p, root):
                    verdict.recorded += 1
                else:
                    where = ", ".join(str(f.relative_to(root)) for f in files[:4]) or "no committed file named"
                    verdict.untied.append(
                        f"{doc.relative_to(root)}:{p.line}: {n} not in {where} — {' '.join(p.text.split())[:300]}"
                    )
                    verdict.paragraphs.add(fingerprint(p, root))
                    verdict.where[verdict.untied[-1]] = fingerprint(p, root)
    return verdict
