"""The ``riverbed`` command line: one thin click module per subcommand over a library function."""

import os

# NumPy asks the kernel for transparent huge pages on its large arrays. Where a huge page costs a compaction or the
# host backs it anew (THP defrag "madvise", virtual machines), first touching the cost volumes takes longer than with
# ordinary pages: here 64 MiB in 140-170 ms against 37-59 ms, a fresh `riverbed match` of the 740 x 500 speed pair
# 0.12-0.20 s against 0.14 s (docs/tubes.md). Read when NumPy is imported, which the commands do later; the user's own
# setting wins, and dask workers started by `riverbed block` inherit it.
os.environ.setdefault("NUMPY_MADVISE_HUGEPAGE", "0")
