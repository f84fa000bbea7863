"""The process heap's policy: memory the program frees stays with the process, for its next frame.

A frame's work allocates and frees arrays of tens of megabytes (a 1920 x 1920 colour frame in float64 is 88 MB).
glibc's malloc gives every block over 32 MB its own ``mmap`` and unmaps it when freed, and trims the heap's top
once over 64 MB of it is free, so the next frame maps fresh pages and faults every one of them in. On a virtual
machine whose host takes back the pages a guest frees (free page reporting: the Firecracker VM this project is
built and tested on), faulting a page in again after it was free for a few seconds cost 8 ms a megabyte: 3-4 s to
touch 440 MB, against 0.1 s right after it was freed. A rendered campaign frame spent a fifth of its time so, and
the reference renderer a third of its (``agf bench``: ``render.frame_s`` 0.847 -> 0.665 s, the reference 7.97 ->
5.05 s; ``agf simulate --random 30 --seed 4242``: 160 -> 142 s, its system time 34 -> 15 s, the same picks).

So the heap never unmaps or trims: a freed block is reused by the next allocation, whose pages are already in.
The process keeps its peak use, as a controller that measures frame after frame needs it again anyway. A C
library other than glibc is left as it is.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools

# mallopt parameters (glibc's malloc.h)
M_TRIM_THRESHOLD = -1
M_MMAP_MAX = -4
NEVER_TRIM = 2**31 - 1  # bytes free at the heap's top before it is trimmed: the largest mallopt takes


@functools.cache
def keep_freed_memory() -> bool:
    """Make this process's heap keep what it frees (see the module): no block gets its own mapping, and the
    heap is never trimmed. Processes forked after the call inherit it. Returns whether the C library took it
    (False on a C library without glibc's ``mallopt``)."""
    name = ctypes.util.find_library("c")
    try:
        mallopt = ctypes.CDLL(name).mallopt
    except (OSError, AttributeError, TypeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(M_MMAP_MAX, 0)) and bool(mallopt(M_TRIM_THRESHOLD, NEVER_TRIM))
