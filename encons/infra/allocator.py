"""Keep the memory a training step frees in the process's heap, instead of handing it back to the kernel.

glibc's malloc serves a block of at least ``M_MMAP_THRESHOLD`` (128 KiB at the start, raised as mapped blocks
are freed) by a fresh ``mmap`` and unmaps it when freed, and trims the heap's top beyond ``M_TRIM_THRESHOLD``.
A training step allocates and frees the same large tensors every step, so every step faults their pages in
again and the kernel zeroes them: 896 minor page faults per step of the Lim & Kasim LNN as a stacked ensemble of
8 (activations and weight gradients (8, 200, 200)), 32 with the thresholds below, and 11.2 → 8.5 ms per step on
one thread (``benchmarks/ensemble_speed.py``; a separate run's step faults 8 times, a stacked ensemble's
tensors are K times larger). PyTorch's CPU performance guide recommends jemalloc or tcmalloc (``LD_PRELOAD``)
for the same reason; this is the in-process equivalent with glibc's own allocator: memory a step frees stays
with the process (up to the trim threshold) and is reused by the next step.

Nothing changes where the user set glibc's malloc tunables themselves (``GLIBC_TUNABLES``), or off glibc.
"""

from __future__ import annotations

import ctypes
import os
import platform

M_TRIM_THRESHOLD, M_TOP_PAD, M_MMAP_THRESHOLD = -1, -2, -3  # glibc's <malloc.h>
SETTINGS = {
    M_MMAP_THRESHOLD: 32 << 20,  # glibc's largest (DEFAULT_MMAP_THRESHOLD_MAX on 64-bit): blocks below it from the heap
    M_TRIM_THRESHOLD: 512 << 20,  # free heap top kept before trimming
    M_TOP_PAD: 64 << 20,  # extra heap requested per growth
}
_kept = False


def keep_freed_memory() -> bool:
    """Set glibc's malloc thresholds (:data:`SETTINGS`) once per process; whether they are set (False: not glibc,
    or the user's ``GLIBC_TUNABLES`` names malloc settings, which win)."""
    global _kept
    if _kept:
        return True
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    if "glibc.malloc." in os.environ.get("GLIBC_TUNABLES", ""):
        return False
    mallopt = getattr(ctypes.CDLL(None), "mallopt", None)
    if mallopt is None:
        return False
    _kept = all(mallopt(option, value) == 1 for option, value in SETTINGS.items())
    return _kept
