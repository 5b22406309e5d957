"""``encons.infra.allocator``: the memory a step frees stays in the process (no page faults on the next step)."""

from __future__ import annotations

import platform
import subprocess
import sys

import pytest

STEPS = """
import resource, sys, torch
from encons.infra import allocator
kept = allocator.keep_freed_memory() if sys.argv[1] == "keep" else False
def step():  # large temporaries of two sizes, interleaved, and results kept to the step's end: a stacked step's
    kept = []
    for i in range(10):
        x = torch.ones(8, 200, 200) + i
        kept += [x * 2, torch.ones(8, 60, 200)]
    return sum(k.sum() for k in kept)
for _ in range(3):
    step()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    step()
print(kept, (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 20)
"""


def _faults_per_step(mode: str) -> tuple[bool, float]:
    out = subprocess.run([sys.executable, "-c", STEPS, mode], capture_output=True, text=True, check=True)
    kept, faults = out.stdout.split()
    return kept == "True", float(faults)


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="glibc's malloc only")
def test_freed_memory_is_kept_so_a_repeated_step_does_not_fault_its_pages_in_again():
    # three processes each way, interleaved: the kernel's own reclaim (kswapd, DAMON) faults pages of any process
    # in now and then (kept: 0, 0, 36, 0 faults per step in four tries here, 189 once in CI), so the fewest of the
    # kept runs against the middle of the default ones
    runs = [(_faults_per_step("keep"), _faults_per_step("default")) for _ in range(3)]
    assert all(keep[0] and not default[0] for keep, default in runs)
    faults = min(keep[1] for keep, _ in runs)
    default_faults = sorted(default[1] for _, default in runs)[1]
    assert default_faults > 500  # ~17 MB handed back to the kernel and faulted in again each step (4 KiB pages)
    assert faults < default_faults / 20


def test_the_users_own_malloc_tunables_win(monkeypatch):
    from encons.infra import allocator

    monkeypatch.setattr(allocator, "_kept", False)
    monkeypatch.setenv("GLIBC_TUNABLES", "glibc.malloc.trim_threshold=0")
    assert allocator.keep_freed_memory() is False
