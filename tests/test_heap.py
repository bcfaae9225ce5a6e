"""The heap a fresh process's match will use, faulted in beside the start-up (riverbed_cli/runtime/heap.py)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from riverbed_cli.runtime.heap import HEAP_PER_CELL, HEAP_PER_PIXEL, match_heap_bytes
from conftest import PYTHON

# A fresh process as the commands run: their memory settings, then a block of the heap prefaulted (or not), then the
# page faults of a 48 MiB array first touched afterwards, as a match's volumes are.
PROBE = """
import ctypes, json, resource
ctypes.CDLL(None).prctl(41, 1, 0, 0, 0)  # PR_SET_THP_DISABLE: 4 KiB pages whatever the system's THP setting
from riverbed_cli.runtime import Env, prefault_heap
Env().__enter__()  # the commands' memory settings
import numpy as np
with prefault_heap(96 << 20):
    pass
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
a = np.ones(48 << 20, np.uint8)
print(json.dumps({"faults": resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0, "sum": int(a[::4096].sum())}))
"""


def _probe(**env):
    e = {k: v for k, v in os.environ.items() if not k.startswith(("MALLOC_", "GLIBC_TUNABLES", "RIVERBED_PREFAULT"))}
    out = subprocess.run([*PYTHON, "-c", PROBE], env={**e, **env}, capture_output=True, text=True, check=True)
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


def test_riverbed_match_prefaults_what_its_match_will_take(tmp_path, cones, monkeypatch):
    # match_files sizes the prefault by the match's own volume: its pixels and mean tube width (with LiDAR), or the
    # nominal range (without)
    import contextlib
    from click.testing import CliRunner

    from riverbed_cli.cli.main import cli
    from riverbed_cli.io.disparity import write_disparity
    from riverbed_cli.products.simulate import simulate_lidar
    from riverbed_cli import runtime

    left, right, gt = cones
    sizes = []

    @contextlib.contextmanager
    def record(nbytes):
        sizes.append(nbytes)
        yield

    monkeypatch.setattr(runtime, "prefault_heap", record)
    data = Path(__file__).parent / "data" / "cones"
    write_disparity(tmp_path / "sparse.tif", simulate_lidar(gt, 0.05, seed=0))
    H, W = gt.shape
    for tile in ("auto", "0"):
        # the LiDAR check off: the points it drops would narrow the match's tubes after the plan sized the heap
        r = CliRunner().invoke(cli, ["match", f"{data}/im2.png", f"{data}/im6.png", "--sparse",
                                     str(tmp_path / "sparse.tif"), "-o", str(tmp_path / f"d{tile}.tif"), "--json",
                                     "--tile", tile, "--lidar-check", "off"])
        assert r.exit_code == 0, r.output
        width = json.loads(r.output)["tubes"]["mean_width"]
        assert abs(sizes[-1] - match_heap_bytes(H * W, width)) <= H * W * HEAP_PER_CELL * 0.01
    r = CliRunner().invoke(cli, ["match", f"{data}/im2.png", f"{data}/im6.png", "--max-disp", "63", "--tile", "0",
                                 "-o", str(tmp_path / "u.tif")])
    assert r.exit_code == 0, r.output
    assert sizes[-1] == match_heap_bytes(H * W, 64)
