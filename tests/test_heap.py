"""The heap a fresh process's match will use, faulted in beside the start-up (riverbed_cli/scale/heap.py)."""

import json
import os
import subprocess
import sys

import pytest

from riverbed_cli.scale.heap import HEAP_PER_CELL, HEAP_PER_PIXEL, match_heap_bytes

# A fresh process as the commands run: their memory settings, then a block of the heap prefaulted (or not), then the
# page faults of a 48 MiB array first touched afterwards, as a match's volumes are.
PROBE = """
import ctypes, json, resource
ctypes.CDLL(None).prctl(41, 1, 0, 0, 0)  # PR_SET_THP_DISABLE: 4 KiB pages whatever the system's THP setting
import riverbed_cli.cli  # the commands' memory settings
from riverbed_cli.scale.heap import prefault_heap
import numpy as np
with prefault_heap(96 << 20):
    pass
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
a = np.ones(48 << 20, np.uint8)
print(json.dumps({"faults": resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0, "sum": int(a[::4096].sum())}))
"""


def _probe(**env):
    e = {k: v for k, v in os.environ.items() if not k.startswith(("MALLOC_", "GLIBC_TUNABLES", "RIVERBED_PREFAULT"))}
    out = subprocess.run([sys.executable, "-c", PROBE], env={**e, **env}, capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc")
def test_prefaulted_heap_serves_the_next_arrays_without_faults():
    pages = (48 << 20) // 4096
    off = _probe(RIVERBED_PREFAULT="0")
    on = _probe()
    assert off["sum"] == on["sum"] == pages
    # without the prefault every page of the array is faulted in on first touch; with it, its pages are the heap's
    assert off["faults"] > 0.9 * pages
    assert on["faults"] < 0.05 * pages
    # the user's own malloc settings win: nothing is kept, so nothing is prefaulted
    assert _probe(MALLOC_TRIM_THRESHOLD_="131072")["faults"] > 0.9 * pages


def test_heap_estimate_counts_pixels_and_the_cells_searched():
    assert match_heap_bytes(1000, 0) == 1000 * HEAP_PER_PIXEL
    assert match_heap_bytes(370_000, 6.9) == int(370_000 * (HEAP_PER_PIXEL + HEAP_PER_CELL * 6.9))
