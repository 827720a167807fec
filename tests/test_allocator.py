"""renderer.allocator: freed frames kept for the next ones, in a process that asks for it."""

from __future__ import annotations

import platform
import subprocess
import sys

import pytest

from shadowmap.renderer.allocator import keep_freed_memory

GLIBC = platform.libc_ver()[0] == "glibc"

# Three frame-sized arrays written and let go, ten times over: with glibc's defaults what is
# freed at the heap's top beyond its trim threshold (twice the largest block freed, 4 MiB) goes
# back to the system, so every round faults those pages in again.
ROUNDS = """
import resource, sys
import numpy as np
from shadowmap.renderer.allocator import keep_freed_memory
kept = keep_freed_memory(int(sys.argv[1]))
faults = []
for _ in range(10):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    arrays = [np.ones(2 * 2**20, np.uint8) for _ in range(3)]
    del arrays
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
print(kept, sum(faults[2:]))
"""


def _rounds(limit: int) -> tuple[bool, int]:
    out = subprocess.run([sys.executable, "-c", ROUNDS, str(limit)], capture_output=True,
                         text=True, timeout=60, check=True).stdout.split()
    return out[0] == "True", int(out[1])


@pytest.mark.skipif(not GLIBC, reason="the allocator's settings are glibc's")
def test_kept_freed_memory_is_used_again_without_page_faults():
    kept, faults = _rounds(64 * 2**20)
    default, default_faults = _rounds(0)
    assert kept and not default
    assert default_faults > 8 * 500  # over 2 MiB of 4 KiB pages in each of 8 rounds
    assert faults < 100


def test_zero_leaves_the_allocator_alone():
    assert keep_freed_memory(0) is False
