"""How a render process's C allocator hands back freed memory.

Every render makes arrays of a frame's size and more (the read-back, the PNG writer's rows, the
float64 steps of the depth and visibility images), and lets them go. With glibc's defaults a
freed block of that size soon goes back to the system (unmapped, or trimmed off the heap's top
once more than about twice the largest recent block is free there), and the next render's
array of the same size is fresh memory again: every first write to one of its pages is a page
fault. A batch worker writing a 640x480 view's colour, visibility and depth took about 2,300
faults per view that way, and 1.5 times as long as without them (``bench/page_faults.py``).

:func:`keep_freed_memory` tells glibc to keep up to a bound of freed memory for the next
allocations instead. It changes the whole process, so the library never calls it on its own:
the processes the project runs only to render call it when they start (the service's render
worker, the batch's pool workers and Ray actors), and so may any program of a user's that
renders in a loop. Elsewhere than glibc it does nothing.
"""

from __future__ import annotations

import ctypes
import platform

__all__ = ["KEEP_FREED_BYTES", "keep_freed_memory"]

#: Freed memory a render process keeps for its next allocations, by default: frames up to
#: 1920x1080 with every output, several times over.
KEEP_FREED_BYTES = 64 * 2**20

# glibc's mallopt parameters (malloc.h).
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
#: glibc's ceiling for the mmap threshold on 64-bit systems (DEFAULT_MMAP_THRESHOLD_MAX):
#: blocks larger than this are always mapped on their own, and unmapped when freed.
_MMAP_THRESHOLD_MAX = 32 * 2**20


def keep_freed_memory(limit: int = KEEP_FREED_BYTES) -> bool:
    """Keep up to ``limit`` bytes of freed memory in this process for later allocations.

    Sets glibc's trim threshold to ``limit`` (free memory at the top of the heap is given back
    only beyond it) and its mmap threshold to ``min(limit, 32 MiB)`` (smaller blocks come from
    the heap, where they are used again, rather than from mappings of their own, which are
    unmapped when freed). Blocks larger than that, a 4096x4096 frame's, are mapped and
    unmapped as before.

    Parameters
    ----------
    limit : int
        Bytes; 0 leaves the allocator as it is.

    Returns
    -------
    bool
        Whether the allocator was changed (False with ``limit`` 0, and where the C library is
        not glibc).
    """
    if limit <= 0 or platform.libc_ver()[0] != "glibc":
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    limit = min(limit, 2**31 - 1)  # an int to mallopt
    return bool(mallopt(_M_TRIM_THRESHOLD, limit)
                and mallopt(_M_MMAP_THRESHOLD, min(limit, _MMAP_THRESHOLD_MAX)))
