"""The ``riverbed`` command line: one thin click module per subcommand over a library function.

Importing it sets the process-wide memory settings the commands are measured with (docs/tubes.md, start-up): NumPy's
huge pages off (inherited by child processes and dask workers through the environment) and glibc keeping freed arrays
(this process only). The user's own settings win.
"""

import os

# NumPy asks the kernel for transparent huge pages on its large arrays. Where a huge page costs a compaction or the
# host backs it anew (THP defrag "madvise", virtual machines), first touching the cost volumes takes longer than with
# ordinary pages: on a THP-madvise VM a fresh `riverbed match --fusion none` of the 740 x 500 speed pair took
# 0.081-0.145 s (median 0.142 s) with them against 0.085-0.091 s (median 0.088 s) without (docs/tubes.md). Read when
# NumPy is imported, which the commands do later; the user's own setting wins, and dask workers started by
# `riverbed block` inherit it.
os.environ.setdefault("NUMPY_MADVISE_HUGEPAGE", "0")

from ..scale.heap import MALLOC_KEEP, keep_freed_memory  # noqa: E402,F401  (re-exported)

keep_freed_memory()
