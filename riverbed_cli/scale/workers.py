"""Numba's OpenMP workers between parallel regions: sleep (the default), or spin a while in a run that has no thread
beside the matcher.

``import riverbed_cli`` sets ``OMP_WAIT_POLICY=PASSIVE``: the workers sleep as soon as a parallel region ends, so
that the fusion's LiDAR side, in a thread beside the matcher, finds a core. Waking a sleeping worker costs about
0.12 ms per region, and a match runs some twenty regions: without the fusion (``--fusion none``) nothing needs the
core, and workers that spin 30 000 times before they sleep made the 4-path matcher on the speed pair 1.3-1.5 ms
faster in fresh ``riverbed match`` processes (19.3 -> 17.9 ms); with the fusion beside, they made it slower
(docs/tubes.md).
"""

import os

from numba.np.ufunc import parallel

import riverbed_cli

#: spins of an idle worker before it sleeps (libgomp's ``GOMP_SPINCOUNT``; roughly 100 000 a millisecond)
SPINS = 30_000


def spin_between_regions(spins=SPINS):
    """Let the OpenMP workers spin ``spins`` times before they sleep, for a run with no thread beside the matcher.

    Read by libgomp when it loads, at the first parallel kernel: nothing is changed once a parallel kernel has run
    in this process, nor when the user set ``OMP_WAIT_POLICY`` or ``GOMP_SPINCOUNT``. Returns True when set.
    """
    if riverbed_cli.OMP_WAIT_FROM_USER or getattr(parallel, "_is_initialized", True):
        return False
    os.environ["GOMP_SPINCOUNT"] = str(int(spins))
    return True
