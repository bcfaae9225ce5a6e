"""What running riverbed does to its process, in one place: :class:`Env`.

Importing riverbed (``riverbed_cli`` or any of its modules) changes no environment variable and no process setting.
The ``riverbed`` program (the console script, ``python -m riverbed_cli``) runs every command inside
``Env(program=True)``. A program that imports riverbed and wants the settings the commands are measured with opts in::

    from riverbed_cli import match_pair
    from riverbed_cli.runtime import Env

    with Env():  # before the first match: OpenMP and NumPy read their settings when they start
        result = match_pair(left, right, sparse=sparse)

What :class:`Env` does, each left as it is where the user set their own (the variable named) and each measured on
fresh ``riverbed match`` processes of the 740 x 500 speed pair (docs/architecture.md, "The process"):

======================================  ==============================================================================
OpenMP workers sleep between regions    ``OMP_WAIT_POLICY=PASSIVE``, so the fusion's helper thread
                                        (:mod:`.helper_thread`) finds a core; a run with no thread beside the matcher
                                        lets them spin first (:func:`spin_between_regions`; :mod:`.openmp`)
no transparent huge pages for NumPy     ``NUMPY_MADVISE_HUGEPAGE=0``: first-touching the cost volumes was slower with
                                        them on a THP-madvise VM (:mod:`.heap`)
freed arrays kept in the process        glibc's ``mallopt`` thresholds (unless ``MALLOC_*`` or ``GLIBC_TUNABLES`` is
                                        set), and a match's heap faulted in while its kernels load
                                        (:func:`prefault_heap`; ``RIVERBED_PREFAULT=0``; :mod:`.heap`)
cached kernels load without Numba's     before a command runs (:func:`before_kernels`; ``RIVERBED_NUMBA_REFRESH=1``;
compiler start-up                       :mod:`.numba_cache`)
the kernels cached per sources' digest  ``NUMBA_CACHE_DIR`` in the user's cache folder, one folder per installed copy
                                        and version of the sources (an edited helper recompiles its callers); the
                                        other versions' folders removed (:func:`.numba_cache.cache_dir`)
the garbage collector (program only)    off while a command starts up, everything alive frozen for the exit
                                        (``RIVERBED_GC=default``; :mod:`.collector`)
the kernels' threads (when asked)       ``riverbed --threads N``: Numba's parallel loops and OpenCV run on ``N``
                                        threads instead of all ``NUMBA_NUM_THREADS`` while the command runs
                                        (:func:`.threads.threads`); the outputs are the same for any count
                                        (``tests/test_threads.py``)
======================================  ==============================================================================

The environment variables :class:`Env` set are restored when it exits; the child processes started inside it (dask
workers of ``riverbed block``) inherit them. Three settings last for the rest of the process, as the libraries read
them once: glibc's thresholds, Numba's cache loading, and the cache folder of the kernel modules imported inside the
``Env`` (enter it before importing riverbed's kernels).
"""

import contextlib
import os
import sys

from . import collector, heap, numba_cache, openmp

_ACTIVE = []


class Env:
    """riverbed's process settings for the ``with`` body (module docstring), in the manner of ``rasterio.Env``.

    Parameters
    ----------
    program : bool, keyword-only
        The ``riverbed`` program's own run: Python's garbage collector is also off while the command starts up
        (until :func:`start_up_done`) and everything alive is frozen for the exit. Programs that import riverbed
        leave it False: their collector is theirs.

    Nested ``Env`` blocks change nothing the outer one set.
    """

    def __init__(self, *, program=False):
        self.program = bool(program)
        self._saved = {}
        self._collector = None
        self._numba_cache_dir = None

    def set_environ(self, values):
        """Set environment variables for the rest of the block (restored when it exits). Returns True if any."""
        for key, value in values.items():
            self._saved.setdefault(key, os.environ.get(key))
            os.environ[key] = value
        return bool(values)

    def __enter__(self):
        _ACTIVE.append(self)
        self.set_environ(openmp.sleep_between_regions())
        if "NUMPY_MADVISE_HUGEPAGE" not in os.environ:
            self.set_environ({"NUMPY_MADVISE_HUGEPAGE": "0"})
        self.freed_memory_kept = heap.keep_freed_memory()
        self._use_kernel_cache()
        if self.program:
            self._collector = collector.program()
            self._collector.__enter__()
            collector.pause_for_start_up()
        return self

    def _use_kernel_cache(self):
        # read by Numba when it is imported (and by the child processes that inherit it); where it already is, its
        # config too, which it reads as each kernel module is imported
        if "NUMBA_CACHE_DIR" in os.environ:
            return
        folder = numba_cache.cache_dir()
        self.set_environ({"NUMBA_CACHE_DIR": str(folder)})
        numba = sys.modules.get("numba")
        if numba is not None:
            self._numba_cache_dir = numba.config.CACHE_DIR
            numba.config.CACHE_DIR = str(folder)
        numba_cache.prune_other_caches(folder)

    def __exit__(self, *exc):
        try:
            if self._collector is not None:
                self._collector.__exit__(*exc)
                self._collector = None
        finally:
            numba = sys.modules.get("numba")
            if numba is not None and self._numba_cache_dir is not None:
                numba.config.CACHE_DIR = self._numba_cache_dir
            for key, value in self._saved.items():
                if value is None:
                    os.environ.pop(key, None)
                else:
                    os.environ[key] = value
            self._saved = {}
            _ACTIVE.remove(self)
        return False


def active():
    """The innermost :class:`Env` in effect, or None (a program that imported riverbed and did not opt in)."""
    return _ACTIVE[-1] if _ACTIVE else None


def spin_between_regions():
    """For a run with no thread beside the matcher: the OpenMP workers spin a while before they sleep
    (:mod:`.openmp`). Only inside an :class:`Env`, before the first parallel kernel, and where the user did not
    choose; returns True when set."""
    env = active()
    return env is not None and env.set_environ(openmp.spin_between_regions())


def prefault_heap(nbytes):
    """A context that faults in ``nbytes`` of the heap in a thread while its body runs (:func:`.heap.prefault_heap`);
    a no-op unless an :class:`Env` keeps freed memory."""
    env = active()
    return heap.prefault_heap(nbytes) if env is not None and env.freed_memory_kept else contextlib.nullcontext()


def before_kernels():
    """Before a command's kernels load: Numba's cached kernels load without its compiler's start-up
    (:mod:`.numba_cache`). Only inside an :class:`Env`; returns True when in place."""
    return active() is not None and numba_cache.skip_refresh_on_cache_loads()


def start_up_done():
    """The command's modules and kernels are loaded: the program's collector on again (:mod:`.collector`)."""
    collector.start_up_done()
