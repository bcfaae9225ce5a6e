"""Start-up of a ``riverbed`` process: Numba's cached kernels loaded without re-initialising Numba's compiler.

Before it loads a cached kernel, Numba refreshes its CPU target context (``Cache.load_overload`` calls
``target_context.refresh()``): it imports all of its compiler's implementation modules - ``numba.np.arraymath``
among them, which imports ``scipy.linalg`` only to check for a BLAS - and installs their registries. That was 0.2-0.3 s
of a fresh ``riverbed match`` of the 740 x 500 speed pair (about 1.1 s of wall time, 0.15 s of it matching;
docs/tubes.md). A cached nopython kernel needs none of it: its machine code is linked as it was saved, and only
Numba's runtime (NRT, the allocator of the arrays a kernel creates) must be up. The refresh serves object-mode code
(numba/numba#9806), which riverbed has none of, and a compilation - a cache miss, a new signature - still refreshes
the context itself (``CompilerBase``), so nothing that compiles is affected.

:func:`skip_refresh_on_cache_loads` is called inside :class:`~riverbed_cli.runtime.Env` only
(:func:`~riverbed_cli.runtime.before_kernels`): the library does not change a process-wide setting of another package
for the programs that import it unless they opt in. ``RIVERBED_NUMBA_REFRESH=1`` in the environment keeps
Numba's own behaviour (a way out should a Numba release change what a cached kernel needs).
"""

import hashlib
import logging
import os
import shutil
import sys
from pathlib import Path

_DONE = []


def announce_compiling():
    """Say once, on a terminal, that this run compiles riverbed's kernels (a first run after installing, or after an
    upgrade, takes about a minute longer); in a pipe or a log it is an INFO line."""
    if _ANNOUNCED:
        return
    _ANNOUNCED.append(True)
    message = "compiling riverbed's kernels for this machine (the first run after installing; cached for the next)"
    if sys.stderr.isatty():
        print(f"riverbed: {message}", file=sys.stderr, flush=True)
    else:
        logging.getLogger(__name__).info(message)


_ANNOUNCED = []


def skip_refresh_on_cache_loads():
    """Make Numba load cached kernels with its runtime initialised but without the target context's refresh.

    Idempotent; returns True when the change is in place. Leaves Numba as it is (False) when
    ``RIVERBED_NUMBA_REFRESH=1`` is set or when this Numba lacks the methods the change relies on.
    """
    if _DONE:
        return True
    if os.environ.get("RIVERBED_NUMBA_REFRESH", "") == "1":
        return False
    from numba.core import caching
    from numba.core.runtime import rtsys

    cache = caching.Cache
    needed = ("load_overload", "_load_overload", "_guard_against_spurious_io_errors")
    if not all(hasattr(cache, name) for name in needed) or not hasattr(rtsys, "initialize"):
        return False

    def load_overload(self, sig, target_context):
        rtsys.initialize(target_context)  # what a cached kernel needs of the refresh: NRT for its allocations
        with self._guard_against_spurious_io_errors():
            loaded = self._load_overload(sig, target_context)
        if loaded is None:  # not cached yet: Numba compiles it now
            announce_compiling()
        return loaded

    load_overload.__doc__ = cache.load_overload.__doc__
    cache.load_overload = load_overload
    _DONE.append(True)
    return True


#: the package whose sources key the cache folder
PACKAGE = Path(__file__).resolve().parents[1]


def sources_digest(package=PACKAGE):
    """A digest of the ``.py`` files of ``package`` that use Numba (their paths and bytes): the kernels (``@kernel``,
    :mod:`.kernel`), the intrinsics and what they inline or call. An edit elsewhere (the command line, the docs)
    leaves the cached kernels as they are."""
    h = hashlib.sha256()
    for path, text in _kernel_files(package):
        h.update(path.relative_to(package).as_posix().encode())
        h.update(text)
    return h.hexdigest()[:16]


def kernel_sources(package=PACKAGE):
    """The ``.py`` files of ``package`` that use Numba, sorted: those that name it or import :func:`.kernel.kernel`."""
    return [path for path, _ in _kernel_files(package)]


def _kernel_files(package):
    # (path, bytes) of kernel_sources, each file read once (every command start-up digests them)
    for path in sorted(Path(package).rglob("*.py")):
        text = path.read_bytes()
        if b"numba" in text or b"runtime.kernel import kernel" in text:
            yield path, text


def cache_root():
    """The user's cache folder for riverbed's kernels (``$XDG_CACHE_HOME`` or ``~/.cache``, then ``riverbed/numba``)."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "riverbed" / "numba"


def cache_dir(package=PACKAGE, root=None):
    """Where :class:`~riverbed_cli.runtime.Env` has Numba cache riverbed's kernels: one folder per installed copy of
    the package (a digest of its path) and per version of its sources (:func:`sources_digest`).

    Numba keys a cached kernel on its own source file only (its path, modification time and size): a kernel that
    inlines or calls a function of another module keeps its old machine code after that module changes (the vector
    helpers of ``matching/lanes.py``, the row sharing of ``matching/volume.py``). A folder per sources' digest makes
    any edit of a module that uses Numba a fresh cache (constants a kernel takes from a module without Numba are not
    tracked, as Numba does not track them either).
    """
    where = hashlib.sha256(str(Path(package).resolve()).encode()).hexdigest()[:12]
    return Path(root or cache_root()) / f"{where}-{sources_digest(package)}"


def prune_other_caches(current):
    """Remove the cache folders of the same installed copy for other versions of its sources (their kernels are of
    no use once the sources changed). Returns the folders removed."""
    current = Path(current)
    where = current.name.split("-")[0]
    gone = [p for p in current.parent.glob(f"{where}-*") if p != current and p.is_dir()]
    for p in gone:
        shutil.rmtree(p, ignore_errors=True)
    return gone
