"""``riverbed --threads N``: the kernels' threads for a command (:func:`threads`), in the runtime's one place.

Numba and OpenCV load when a command runs with it, not when riverbed is imported or ``riverbed --help`` is asked.
"""

import contextlib

from ..errors import RiverbedError


@contextlib.contextmanager
def threads(n):
    """The kernels on ``n`` threads for the ``with`` body: Numba's parallel loops (``numba.set_num_threads``) and
    OpenCV's (``cv2.setNumThreads``), ``n`` from 1 to ``NUMBA_NUM_THREADS``; the counts before are restored after.
    Raises :class:`~riverbed_cli.errors.RiverbedError` for a count out of range, before any change."""
    import cv2
    import numba

    most = numba.config.NUMBA_NUM_THREADS
    if not 1 <= int(n) <= most:
        raise RiverbedError(f"--threads: expected 1 to {most} (the threads Numba starts with: NUMBA_NUM_THREADS, "
                            f"the machine's cores unless set), got {n}")
    before = numba.get_num_threads(), cv2.getNumThreads()
    numba.set_num_threads(int(n))
    cv2.setNumThreads(int(n))
    try:
        yield
    finally:
        numba.set_num_threads(before[0])
        cv2.setNumThreads(before[1])
