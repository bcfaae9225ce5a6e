"""The outputs do not depend on how many threads the kernels run on (1 to 4), and ``riverbed --threads``."""

import json
import os
import subprocess

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import DATA, PYTHON

from riverbed_cli.cli.main import cli

# One process started with 4 Numba threads (more than this machine's cores: Numba starts as many as it is told)
# matches the test Cones pair with every matcher x guide, with the LiDAR check and the fusion, whole and in tiles,
# on 1, 2, 3 and 4 threads, and prints, per case and count, a digest of the disparities and confidences.
_ALL_COUNTS = r"""
import hashlib, json, sys
import numba, numpy as np
from riverbed_cli.io.images import read_image
from riverbed_cli.io.disparity import read_disparity
from riverbed_cli.matching.pipeline import match_pair
from riverbed_cli.products.simulate import simulate_lidar
from riverbed_cli.scale.tiles import match_tiled

data = sys.argv[1]
left, right = read_image(data + "/im2.png"), read_image(data + "/im6.png")
sparse = simulate_lidar(read_disparity(data + "/disp2.png", scale=4), 0.05, seed=0)
guides = ("none", "gauss", "riverbed", "diffusion")
cases = [(m, g) for m in ("sgm", "adcensus") for g in guides] + [("sgm", "riverbed+")]
out = {}
for n in (1, 2, 3, 4):
    numba.set_num_threads(n)
    for m, g in cases:
        lidar = None if g == "none" else sparse
        r = match_pair(left, right, lidar, 0 if lidar is None else None, 64 if lidar is None else None, matcher=m,
                       guide=g)
        parts = [r.disparity] + ([r.confidence] if r.confidence is not None else [])
        out.setdefault(f"{m} {g}", []).append(hashlib.sha256(b"".join(p.tobytes() for p in parts)).hexdigest())
    t = match_tiled(left, right, sparse, tile=160, overlap=32)
    out.setdefault("tiled sgm riverbed", []).append(hashlib.sha256(t.disparity.tobytes()).hexdigest())
print(json.dumps(out))
"""


def test_every_matcher_and_guide_gives_the_same_bits_on_1_2_3_and_4_threads():
    env = {**os.environ, "NUMBA_NUM_THREADS": "4"}
    done = subprocess.run([*PYTHON, "-c", _ALL_COUNTS, str(DATA / "cones")], env=env, capture_output=True,
                          text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    digests = json.loads(done.stdout.strip().splitlines()[-1])
    assert len(digests) == 10
    for case, per_count in digests.items():
        assert len(per_count) == 4 and len(set(per_count)) == 1, case


def _match(tmp_path, *threads):
    out = tmp_path / f"d{'_'.join(threads) or 'default'}.tif"
    args = [*(("--threads", *threads) if threads else ()), "match", str(DATA / "cones" / "im2.png"),
            str(DATA / "cones" / "im6.png"), "-o", str(out), "--max-disp", "64", "--json"]
    return CliRunner().invoke(cli, args), out


def test_threads_option_gives_the_same_disparities(tmp_path):
    from riverbed_cli.io.disparity import read_disparity

    r1, one = _match(tmp_path, "1")
    assert r1.exit_code == 0, r1.output
    r0, default = _match(tmp_path)
    assert r0.exit_code == 0, r0.output
    np.testing.assert_array_equal(read_disparity(one), read_disparity(default))
    import numba

    assert numba.get_num_threads() == numba.config.NUMBA_NUM_THREADS  # the Env gave the threads back


@pytest.mark.parametrize("count", ["0", "-1", "999"])
def test_threads_out_of_range_is_one_line(tmp_path, count):
    import numba

    r, out = _match(tmp_path, count)
    assert r.exit_code == 1
    assert r.output.strip() == (f"riverbed: error: --threads: expected 1 to {numba.config.NUMBA_NUM_THREADS} (the "
                                "threads Numba starts with: NUMBA_NUM_THREADS, the machine's cores unless set), got "
                                f"{count}")
    assert not out.exists()


def test_the_thread_figures_are_the_committed_ones_and_the_structure_they_show():
    import sys

    from conftest import REPO

    sys.path.insert(0, str(REPO / "benchmarks"))
    import bench_threads

    rows = json.loads((REPO / "benchmarks" / "results_threads.json").read_text())
    doc = (REPO / "docs" / "architecture.md").read_text()
    assert doc.split(bench_threads.BEGIN)[1].split(bench_threads.END)[0].strip() == bench_threads.tables(rows).strip()
    assert {(r["scene"], r["run"].split(" ")[0]) for r in rows} == {("Cones", "default"), ("Dublin aerial", "default"),
                                                                     ("Dublin aerial", "unguided")}
    for r in rows:  # two threads are faster, by less than two; the projection grows with the cores, within them
        assert 1.05 < r["seconds_1"] / r["seconds_2"] < 2.0
        assert 0.3 < r["bound_2"] / r["seconds_2"] < 0.95
        assert 1.0 < bench_threads.projected(rows, r, 8) < bench_threads.projected(rows, r, 16) < 8.0
    passes = [r["pass_1"] / r["pass_2"] for r in rows if "pass_1" in r]
    assert len(passes) == 2 and all(1.1 < x < 2.0 for x in passes)  # a pass's rows on two threads: faster