"""CI's skip policy (tests/conftest.py): the session lists every skip reason, and under ENCONS_STRICT_SKIPS
any reason but no CUDA device or a declared model × system incompatibility fails it."""

from __future__ import annotations

from collections import Counter

import pytest

from tests import conftest


class Session:
    exitstatus = 0


def test_a_missing_installed_dependency_fails_a_strict_session_and_allowed_skips_do_not(monkeypatch):
    monkeypatch.setenv("ENCONS_STRICT_SKIPS", "1")
    monkeypatch.setattr(
        conftest,
        "_skips",
        Counter({"no CUDA device on this machine": 13, "declared incompatibility: model=chnn needs constraints": 19}),
    )
    session = Session()
    conftest.pytest_sessionfinish(session, 0)
    assert session.exitstatus == 0
    conftest._skips["psycopg2 missing: pip install encons[postgres]"] += 1
    conftest.pytest_sessionfinish(session, 0)
    assert session.exitstatus == pytest.ExitCode.TESTS_FAILED
    monkeypatch.delenv("ENCONS_STRICT_SKIPS")
    session = Session()
    conftest.pytest_sessionfinish(session, 0)  # outside CI a skip is reported, not fatal
    assert session.exitstatus == 0


def test_the_summary_lists_each_reason_with_its_count_and_marks_the_disallowed(monkeypatch):
    lines = []
    monkeypatch.setattr(conftest, "_skips", Counter({"no CUDA device on this machine": 2, "psycopg2 missing": 1}))

    class Reporter:
        def section(self, title):
            lines.append(title)

        def write_line(self, line):
            lines.append(line)

    conftest.pytest_terminal_summary(Reporter())
    assert lines == [
        "skip reasons",
        "   2 × no CUDA device on this machine",
        "   1 × psycopg2 missing   <- not an allowed skip",
    ]


def test_an_expected_failure_is_not_counted_as_a_skip(monkeypatch):
    """pytest reports an xfail as 'skipped' with ``wasxfail`` set: a strict xfail is an assertion, not a skip."""
    monkeypatch.setattr(conftest, "_skips", Counter())

    class Report:
        skipped = True
        longrepr = ("tests/test_x.py", 1, "Skipped: no CUDA device on this machine")

    xfailed = Report()
    xfailed.wasxfail = "chaotic: the floor is ~2e-2"
    xfailed.longrepr = "AssertionError: 0.02 < 1e-6"
    conftest.pytest_runtest_logreport(xfailed)
    conftest.pytest_runtest_logreport(Report())
    assert conftest._skips == Counter({"no CUDA device on this machine": 1})
