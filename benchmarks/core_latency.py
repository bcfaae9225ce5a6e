"""How far apart this machine's first two CPUs are: the round trip of a cache line between two threads (ns).

On the dev VM (2 vCPUs) it is either about 100 ns or about 500 ns, in periods of ten seconds to minutes: the
hypervisor places the two vCPUs on cores that share their caches, or on cores far apart. Far apart, every cache
line one thread wrote and the other reads or writes crosses between them, and riverbed's stages that hand arrays
from thread to thread slow down (docs/tubes.md, Speed). ``bench_placement.py`` runs this before and
after each timed command to tell which placement the command ran in.

Usage: ``python core_latency.py [ROUND_TRIPS]`` prints the median round trip in ns of three runs of ROUND_TRIPS
(default 20000). Two Numba threads bounce a counter through two cache lines; it needs at least two CPUs.
"""

import sys
import time

import numpy as np
from numba import njit, prange

from riverbed_cli.matching.kernels.atomics import load_acquire, store_release


@njit(cache=True, parallel=True)
def _ping_pong(flag, n):
    # thread 0 writes i to flag[0] and waits for i in flag[8] (another cache line); thread 1 answers
    for t in prange(2):
        for i in range(1, n + 1):
            if t == 0:
                store_release(flag, 0, i)
                while load_acquire(flag, 8) != i:
                    pass
            else:
                while load_acquire(flag, 0) != i:
                    pass
                store_release(flag, 8, i)


def round_trip_ns(n=20000, runs=3):
    """Median over ``runs`` of the mean round trip (ns) of ``n`` exchanges between two threads."""
    flag = np.zeros(16, np.int64)
    _ping_pong(flag, 10)  # compiled or loaded, both threads started
    times = []
    for _ in range(runs):
        flag[:] = 0
        t = time.perf_counter()
        _ping_pong(flag, n)
        times.append((time.perf_counter() - t) / n * 1e9)
    return float(np.median(times))


if __name__ == "__main__":
    print(f"{round_trip_ns(int(sys.argv[1]) if len(sys.argv) > 1 else 20000):.0f}")
