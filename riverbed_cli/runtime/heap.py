"""The process's heap: freed arrays kept for the next ones, and the pages a match will use faulted in beforehand.

A fresh process's first match faults in every page of its arrays: on the dev VM about 2 us per 4 KiB page, 45-80 MiB
(15-40 ms) for the 740 x 500 speed pair, a sixth of its matching time. The commands keep freed memory in the process
(:func:`keep_freed_memory`, called by :class:`~riverbed_cli.runtime.Env`); then a block taken from the heap, touched
and freed stays there, already faulted in, for the match's arrays. :func:`prefault_heap` does the touching in a thread
while the command loads its kernels, which leaves the second core idle (docs/architecture.md, "The process").

Nothing here runs unless :func:`keep_freed_memory` succeeded (glibc, and the user did not set malloc's thresholds):
without it a freed block goes back to the kernel. ``RIVERBED_PREFAULT=0`` in the environment turns the prefault off
(the benchmarks' A/B).

NumPy's transparent huge pages: the :class:`~riverbed_cli.runtime.Env` sets ``NUMPY_MADVISE_HUGEPAGE=0`` (read when
NumPy is imported; the user's own setting wins). Where a huge page costs a compaction or the host backs it anew (THP
defrag "madvise", virtual machines), first touching the cost volumes takes longer than with ordinary pages: on a
THP-madvise VM a fresh ``riverbed match --fusion none`` of the 740 x 500 speed pair took 0.081-0.145 s (median 0.142 s)
with them against 0.085-0.091 s (median 0.088 s) without.
"""

import contextlib
import ctypes
import os
import threading

#: glibc's malloc settings (bytes) under which freed arrays stay in the process for the next ones
MALLOC_KEEP = {"MALLOC_MMAP_THRESHOLD_": 1 << 30, "MALLOC_TRIM_THRESHOLD_": 1 << 30}

#: how much of the heap :func:`prefault_heap` touches for a match, per pixel and per disparity searched (bytes). A
#: match's heap grew by 90-131 B per pixel besides 6 B per tube cell (the cost volume and SGM's two half-sums, int16) on
#: the speed pair and the 1024 x 1024 aerial pair, fused or not. The per-pixel part is kept under that: what the match
#: does not take of the block stays faulted in beside its arrays (the aerial pair's peak RSS 426 -> 462 MiB at 96 B,
#: 437 MiB at 72), while a block too small serves none of the large arrays (at 48 B as slow as none)
HEAP_PER_PIXEL = 72
HEAP_PER_CELL = 6
#: the most :func:`prefault_heap` touches (bytes), whatever the estimate
PREFAULT_MAX = 1 << 30

_kept = False
_libc = None


def keep_freed_memory():
    """Keep freed arrays in the process for the next stage instead of returning them to the kernel.

    glibc serves large blocks with mmap and gives them back on free (and trims its heap), so every stage's arrays
    are fresh pages the kernel must fault in and zero. Raising both thresholds to 1 GiB keeps them: a fresh
    ``riverbed match`` of the speed pair faults 21 % fewer pages, the tiled 40 MP pair took 17-22 s instead of
    24-30 s at 1290 MiB peak RSS instead of 1187. Set for this process only (``mallopt``): dask
    workers keep dask's own setting (its nanny lowers the trim threshold to return memory). Nothing is changed when
    the user set ``MALLOC_MMAP_THRESHOLD_``, ``MALLOC_TRIM_THRESHOLD_`` or ``GLIBC_TUNABLES``, or off glibc.
    Returns True when set.
    """
    global _kept, _libc
    if _kept:
        return True
    if any(k in os.environ for k in (*MALLOC_KEEP, "GLIBC_TUNABLES")):
        return False
    try:
        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    # M_MMAP_THRESHOLD (-3) and M_TRIM_THRESHOLD (-1) of <malloc.h>
    _kept = bool(mallopt(-3, MALLOC_KEEP["MALLOC_MMAP_THRESHOLD_"]) and
                 mallopt(-1, MALLOC_KEEP["MALLOC_TRIM_THRESHOLD_"]))
    if _kept:
        libc.malloc.restype = ctypes.c_void_p
        libc.malloc.argtypes = [ctypes.c_size_t]
        libc.free.argtypes = [ctypes.c_void_p]
        libc.memset.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_size_t]
        _libc = libc
    return _kept


def match_heap_bytes(pixels, mean_width):
    """What to prefault for a match of ``pixels`` pixels searching ``mean_width`` disparities each (bytes): a little
    under the heap such a match grows by (:data:`HEAP_PER_PIXEL`)."""
    return int(pixels * (HEAP_PER_PIXEL + HEAP_PER_CELL * float(mean_width)))


@contextlib.contextmanager
def prefault_heap(nbytes):
    """Fault in ``nbytes`` of the heap in a thread while the ``with`` body runs (loading kernels, say), and leave
    them free for what follows (module docstring).

    No-op unless :func:`keep_freed_memory` is in effect. The block is taken from the heap by the calling thread (so
    it is that thread's arena's), touched by the helper thread (``memset`` releases the GIL) and freed when the body
    ends; at most :data:`PREFAULT_MAX` bytes.
    """
    libc = _libc
    nbytes = min(int(nbytes), PREFAULT_MAX)
    wanted = libc is not None and nbytes > 0 and os.environ.get("RIVERBED_PREFAULT", "1") != "0"  # set: kept
    block = libc.malloc(nbytes) if wanted else None
    if not block:
        yield
        return

    helper = threading.Thread(target=libc.memset, args=(block, 0, nbytes), name="riverbed-prefault", daemon=True)
    helper.start()
    try:
        yield
    finally:
        helper.join()
        libc.free(block)
