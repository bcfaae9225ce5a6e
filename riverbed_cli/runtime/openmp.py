"""How Numba's OpenMP workers wait between parallel regions: they sleep (the default under :class:`~.Env`), or spin
a while in a run that has no thread beside the matcher.

The fusion's LiDAR side runs in a thread beside the matcher (:mod:`.helper_thread`); workers that spin between parallel
regions took its core (the default fused match 16 % slower than with sleeping ones). :func:`sleep_between_regions`
sets ``OMP_WAIT_POLICY=PASSIVE``. Waking a sleeping worker costs about 0.12 ms per region, and a match runs some
twenty regions: without the fusion (``--fusion none``) nothing needs the core, and workers that spin 30 000 times
before they sleep (:func:`spin_between_regions`) made the 4-path matcher on the speed pair 1.3-1.5 ms faster in fresh
``riverbed match`` processes (19.3 -> 17.9 ms); with the fusion beside, they made it slower.

Both are read by libgomp when it loads, at the first parallel kernel: nothing changes once a parallel kernel has run
in the process, nor where the user set ``OMP_WAIT_POLICY`` or ``GOMP_SPINCOUNT``. riverbed's own default is marked
(``RIVERBED_OMP_DEFAULT``), so that a riverbed process started by another (a benchmark, a test, a dask worker), which
inherits it, tells it from a user's choice.
"""

import os
import sys

#: spins of an idle worker before it sleeps (libgomp's ``GOMP_SPINCOUNT``; roughly 100 000 a millisecond)
SPINS = 30_000
#: marks an ``OMP_WAIT_POLICY`` riverbed set (inherited by its child processes), as opposed to the user's
MARK = "RIVERBED_OMP_DEFAULT"


def user_chose_wait(environ=os.environ):
    """True when the user chose how OpenMP workers wait (``GOMP_SPINCOUNT``, or an ``OMP_WAIT_POLICY`` riverbed did
    not set)."""
    return "GOMP_SPINCOUNT" in environ or (
        "OMP_WAIT_POLICY" in environ and environ["OMP_WAIT_POLICY"] != environ.get(MARK))


def openmp_started():
    """True once Numba's threading layer has started (it has read the settings above)."""
    numba = sys.modules.get("numba")  # asking must not import Numba into a process that has not
    if numba is None:
        return False
    try:
        numba.threading_layer()
    except ValueError:  # "Threading layer is not initialized."
        return False
    return True


def sleep_between_regions(environ=os.environ):
    """The variables to set for workers that sleep as soon as a parallel region ends (``{}`` where the user chose).
    Returns them; the caller (:class:`~.Env`) sets and later restores them."""
    if "OMP_WAIT_POLICY" in environ or "GOMP_SPINCOUNT" in environ:  # the user's, or riverbed's inherited
        return {}
    return {"OMP_WAIT_POLICY": "PASSIVE", MARK: "PASSIVE"}


def spin_between_regions(spins=SPINS, environ=os.environ):
    """The variables to set for workers that spin ``spins`` times before they sleep, for a run with no thread beside
    the matcher (``{}`` where the user chose or once a parallel kernel has run)."""
    if user_chose_wait(environ) or openmp_started():
        return {}
    return {"GOMP_SPINCOUNT": str(int(spins))}
