"""How Numba's OpenMP workers wait between parallel regions, chosen per run (riverbed_cli/runtime/openmp.py)."""

import json
import os
import subprocess
from pathlib import Path

from conftest import PYTHON

DATA = Path(__file__).parent / "data" / "cones"

# A fresh process running `riverbed match` as the command does, reporting the exit code, the spin count libgomp
# will read and whether the OpenMP library had loaded before (it reads the variable when it loads)
PROBE = """
import json, os, sys
from click.testing import CliRunner
from riverbed_cli.cli.main import cli
from riverbed_cli.runtime import Env
with Env():  # the program's settings (riverbed_cli.__main__)
    r = CliRunner().invoke(cli, sys.argv[1:])
    spins, policy = os.environ.get("GOMP_SPINCOUNT"), os.environ.get("OMP_WAIT_POLICY")
print(json.dumps({"exit": r.exit_code, "spins": spins, "policy": policy, "output": r.output[-300:]}))
"""


def _match(tmp_path, *args, **env):
    e = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT", "RIVERBED_OMP_DEFAULT")}
    cmd = [*PYTHON, "-c", PROBE, "match", str(DATA / "im2.png"), str(DATA / "im6.png"), "--max-disp", "63",
           "-o", str(tmp_path / "d.tif"), "--overwrite", *args]
    out = subprocess.run(cmd, env={**e, **env}, capture_output=True, text=True, check=True)
    res = json.loads(out.stdout.strip().splitlines()[-1])
    assert res["exit"] == 0, res["output"]
    return res


def test_workers_spin_only_where_nothing_runs_beside_the_matcher(tmp_path):
    from riverbed_cli.io.disparity import read_disparity, write_disparity

    gt = read_disparity(DATA / "disp2.png", scale=4)
    from riverbed_cli.products.simulate import simulate_lidar

    write_disparity(tmp_path / "s.tif", simulate_lidar(gt, 0.05, seed=0))
    sparse = ["--sparse", str(tmp_path / "s.tif")]
    # no fusion, so no LiDAR side in a thread beside the matcher: idle workers spin a while before they sleep
    assert _match(tmp_path, *sparse, "--fusion", "none")["spins"] == "30000"
    assert _match(tmp_path)["spins"] == "30000"  # no LiDAR at all
    # the fused default: they sleep at once, leaving the core to the LiDAR side
    fused = _match(tmp_path, *sparse)
    assert fused["spins"] is None and fused["policy"] == "PASSIVE"
    # riverbed's default inherited from a riverbed parent (a benchmark, this test) is not taken for the user's
    assert _match(tmp_path, *sparse, "--fusion", "none", OMP_WAIT_POLICY="PASSIVE",
                  RIVERBED_OMP_DEFAULT="PASSIVE")["spins"] == "30000"
    # the user's own choice wins
    assert _match(tmp_path, *sparse, "--fusion", "none", OMP_WAIT_POLICY="ACTIVE")["spins"] is None
    assert _match(tmp_path, *sparse, "--fusion", "none", GOMP_SPINCOUNT="7")["spins"] == "7"


def test_too_late_once_a_parallel_kernel_has_run():
    code = """
import os
from riverbed_cli.runtime import Env, spin_between_regions
from riverbed_cli.matching.census import census_transform
Env().__enter__()
import numpy as np
census_transform(np.zeros((20, 20), np.float32))  # a parallel kernel: libgomp has loaded and read its settings
print(spin_between_regions(), os.environ.get("GOMP_SPINCOUNT"))
"""
    e = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT", "RIVERBED_OMP_DEFAULT")}
    out = subprocess.run([*PYTHON, "-c", code], env=e, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "None"]
    code2 = code.replace('census_transform(np.zeros((20, 20), np.float32))  #', '#')
    out = subprocess.run([*PYTHON, "-c", code2], env=e, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["True", "30000"]
