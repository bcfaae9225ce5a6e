"""One decorator for riverbed's compiled kernels: :func:`kernel`.

Every Numba kernel of the package is ``@kernel`` (a plain function of arrays, compiled on first use),
``@kernel(parallel=True)`` (its ``prange`` loops on Numba's threads: as many as it has, ``riverbed --threads``
or ``NUMBA_NUM_THREADS``) or ``@kernel(inline=True)`` (a helper inlined into the kernels that call it). All are
cached on disk: inside :class:`~riverbed_cli.runtime.Env` in a folder keyed by a digest of the kernel modules'
sources (:mod:`.numba_cache`), so an edited helper recompiles the kernels that inline it. ``boundscheck=False``
keeps a kernel's indexing unchecked whatever ``NUMBA_BOUNDSCHECK`` says (the hot loops whose indices are proved by
construction). The rules a kernel follows (explicit dtypes, no Python objects in its loops, threads over rows) are
docs/architecture.md's ("Adding a kernel").
"""

from numba import njit


def kernel(function=None, *, parallel=False, inline=False, boundscheck=None):
    """``njit(cache=True, ...)`` with riverbed's options: ``parallel`` (``prange`` loops on Numba's threads),
    ``inline`` (``inline="always"``: compiled into its callers), ``boundscheck`` (None: Numba's default). Used
    bare (``@kernel``) or with options (``@kernel(parallel=True)``)."""
    options = {"cache": True}
    if parallel:
        options["parallel"] = True
    if inline:
        options["inline"] = "always"
    if boundscheck is not None:
        options["boundscheck"] = boundscheck
    decorate = njit(**options)
    return decorate if function is None else decorate(function)
