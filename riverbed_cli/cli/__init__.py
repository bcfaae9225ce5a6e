"""The ``riverbed`` command line: one thin click module per subcommand over a library function.

Importing it sets the process-wide memory settings the commands are measured with (docs/tubes.md, start-up): NumPy's
huge pages off (inherited by child processes and dask workers through the environment) and glibc keeping freed arrays
(this process only). The user's own settings win.
"""

import ctypes
import os

# NumPy asks the kernel for transparent huge pages on its large arrays. Where a huge page costs a compaction or the
# host backs it anew (THP defrag "madvise", virtual machines), first touching the cost volumes takes longer than with
# ordinary pages: on a THP-madvise VM a fresh `riverbed match --fusion none` of the 740 x 500 speed pair took
# 0.081-0.145 s (median 0.142 s) with them against 0.085-0.091 s (median 0.088 s) without (docs/tubes.md). Read when
# NumPy is imported, which the commands do later; the user's own setting wins, and dask workers started by
# `riverbed block` inherit it.
os.environ.setdefault("NUMPY_MADVISE_HUGEPAGE", "0")

#: glibc's malloc settings (bytes) under which freed arrays stay in the process for the next ones
MALLOC_KEEP = {"MALLOC_MMAP_THRESHOLD_": 1 << 30, "MALLOC_TRIM_THRESHOLD_": 1 << 30}


def keep_freed_memory():
    """Keep freed arrays in the process for the next stage instead of returning them to the kernel.

    glibc serves large blocks with mmap and gives them back on free (and trims its heap), so every stage's arrays
    are fresh pages the kernel must fault in and zero. Raising both thresholds to 1 GiB keeps them: a fresh
    ``riverbed match`` of the speed pair faults 21 % fewer pages, the tiled 40 MP pair took 17-22 s instead of
    24-30 s at 1290 MiB peak RSS instead of 1187 (docs/tubes.md). Set for this process only (``mallopt``): dask
    workers keep dask's own setting (its nanny lowers the trim threshold to return memory). Nothing is changed when
    the user set ``MALLOC_MMAP_THRESHOLD_``, ``MALLOC_TRIM_THRESHOLD_`` or ``GLIBC_TUNABLES``, or off glibc.
    Returns True when set.
    """
    if any(k in os.environ for k in (*MALLOC_KEEP, "GLIBC_TUNABLES")):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    # M_MMAP_THRESHOLD (-3) and M_TRIM_THRESHOLD (-1) of <malloc.h>
    kept = mallopt(-3, MALLOC_KEEP["MALLOC_MMAP_THRESHOLD_"]) and mallopt(-1, MALLOC_KEEP["MALLOC_TRIM_THRESHOLD_"])
    return bool(kept)


keep_freed_memory()
