"""The README's main job, ``bash sample_data/run.sh OUTDIR``, run as the README runs it: the installed ``riverbed`` on
PATH, the bundled sample block, outputs in a temporary folder; the accuracy lines it prints must show riverbed-guided
matching beating unguided matching by the measured margins.

The full sample takes about 20 s on two cores once the Numba kernels are cached (about 70 s with the first-run JIT
compile), so the test runs the README's command itself, unchanged.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from gates import RELATIVE, assert_within, off_gate

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "sample_data" / "run.sh"

#: The headings run.sh prints before each ``riverbed evaluate`` table.
SECTIONS = {
    "disparity, riverbed-guided:": "guided",
    "disparity, unguided:": "unguided",
    "DSM, riverbed-guided (m):": "dsm_guided",
    "DSM, unguided (m):": "dsm_unguided",
}

#: Measured on the bundled block (720x540, seed 0) with the current code (guided: riverbed with the confidence fusion,
#: riverbed match's default, the LiDAR check on), 2 cores:
#:   disparity (px, % of the 365815 GT pixels without LiDAR)   guided   unguided
#:     bad1 %                                                  5.323    16.638
#:     bad2 %                                                  3.276     9.372
#:     bad3 %                                                  2.023     6.878
#:     avg px                                                  0.273     0.825
#:     rmse px                                                 0.972     1.976
#:   DSM against the ground-truth DSM (m, %)                   guided   unguided
#:     rmse m                                                  1.515     2.376
#:     nmad m                                                  0.091     0.509
#:     over_0.5 %                                             11.521    37.024
#:     over_1 %                                                7.265    20.047
#:     over_2 %                                                4.882    11.193
#:     over_3res %                                            10.048    31.292
#:     completeness % (higher is better)                      97.215    95.724
#: Each figure is gated within 2 % (small absolute floors: tests/gates.py), and so is guided matching's margin.
MEASURED = {
    "guided": {"bad1": 5.323, "bad2": 3.276, "bad3": 2.023, "avg": 0.273, "rmse": 0.972},
    "unguided": {"bad1": 16.638, "bad2": 9.372, "bad3": 6.878, "avg": 0.825, "rmse": 1.976},
    "dsm_guided": {"rmse": 1.515, "nmad": 0.091, "over_0.5": 11.521, "over_1": 7.265, "over_2": 4.882,
                   "over_3res": 10.048, "completeness": 97.215},
    "dsm_unguided": {"rmse": 2.376, "nmad": 0.509, "over_0.5": 37.024, "over_1": 20.047, "over_2": 11.193,
                     "over_3res": 31.292, "completeness": 95.724},
}
#: the guided figures the match without sub-pixel refinement takes off their gates (test_readme_gates_catch_a_real_
#: regression): the bad shares move by a few %, the mean error by about a fifth
REGRESSED_OFF = ["guided bad1", "guided bad2", "guided bad3", "guided avg"]
#: Files run.sh's last line promises in OUTDIR (and the unguided ones beside them).
OUTPUTS = ("sparse.tif", "disparity.tif", "disparity.png", "points.laz", "dsm.tif", "dsm_hillshade.png",
           "accuracy.txt", "disparity_unguided.tif", "dsm_unguided.tif", "disparity_errors.png", "dsm_errors.png",
           "lidar_mask.png", "change.tif", "earlier.txt")


def parse_accuracy(text):
    """The ``riverbed evaluate`` tables run.sh prints, by heading: ``{"guided": {"bad1": 5.395, ...}, ...}``."""
    tables, current = {}, None
    for line in text.splitlines():
        if line.strip() in SECTIONS:
            current = tables.setdefault(SECTIONS[line.strip()], {})
        elif line.startswith("== "):
            current = None
        elif current is not None and line.strip():
            name, value = line.split()[:2]
            current[name] = int(value) if name == "n" else float(value)
    return tables


def test_readme_gates_catch_a_real_regression(job):
    # the job's guided match again without its sub-pixel refinement (a regression of the selection stage): its
    # figures leave their gates
    out, _ = job
    block = REPO / "sample_data" / "block"
    bin_dir = Path(sys.executable).parent
    regressed = out.parent / "no_subpixel.tif"
    subprocess.run([str(bin_dir / "riverbed"), "match", str(block / "left.png"), str(block / "right.png"), "--sparse",
                    str(out / "sparse.tif"), "--no-subpixel", "-o", str(regressed)], check=True, capture_output=True)
    ev = subprocess.run([str(bin_dir / "riverbed"), "evaluate", str(regressed), str(block / "gt_disparity.tif"),
                         "--exclude", str(out / "sparse.tif")], check=True, capture_output=True, text=True).stdout
    got = parse_accuracy("disparity, riverbed-guided:\n" + ev)
    off = [line.split(":")[0] for line in off_gate(got, {"guided": MEASURED["guided"]})]
    assert off == REGRESSED_OFF, off


def test_parse_accuracy():
    text = ("== evaluate: ...\ndisparity, riverbed-guided:\nbad1           5.395 %   error > 1 px or no prediction\n"
            "n             365815 px  ground-truth pixels evaluated\n\nDSM, unguided (m):\n"
            "over_0.5           37.540 %\nn                  378086 \n\n== done: out/ holds ...\n")
    assert parse_accuracy(text) == {"guided": {"bad1": 5.395, "n": 365815},
                                    "dsm_unguided": {"over_0.5": 37.54, "n": 378086}}


@pytest.fixture(scope="module")
def job(tmp_path_factory):
    """Run the README's main job once: ``bash sample_data/run.sh OUTDIR`` with the installed riverbed on PATH."""
    bin_dir = Path(sys.executable).parent
    assert (bin_dir / "riverbed").is_file(), f"riverbed is not installed beside {sys.executable}"
    out = tmp_path_factory.mktemp("readme_job") / "out"
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}"}
    run = subprocess.run(["bash", str(SCRIPT), str(out)], cwd=REPO, env=env, capture_output=True, text=True,
                         timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    return out, run.stdout


def test_readme_job_writes_its_outputs(job):
    out, stdout = job
    assert sorted(p.name for p in out.iterdir() if p.name in OUTPUTS) == sorted(OUTPUTS)
    assert stdout.rstrip().endswith(f"== done: {out}/ holds sparse.tif, disparity.tif + .png, points.laz, dsm.tif, "
                                    "dsm_hillshade.png, accuracy.txt,\nand for the older LiDAR lidar_mask.png, "
                                    "change.tif, earlier.txt")
    # accuracy.txt is the tee of the printed tables.
    assert parse_accuracy((out / "accuracy.txt").read_text()) == parse_accuracy(stdout)


def test_readme_job_guided_beats_unguided(job):
    _, stdout = job
    got = parse_accuracy(stdout)
    assert set(got) == set(SECTIONS.values())
    # Every table covers the same pixels: the GT pixels without LiDAR, the GT DSM's cells (counts are exact).
    assert got["guided"]["n"] == got["unguided"]["n"] == 365815
    assert (got["dsm_guided"]["n"], got["dsm_unguided"]["n"]) == (379021, 373207)
    # the unguided match leaves the pixels without a possible match, beyond the LiDAR's coverage, invalid
    assert got["guided"]["density"] == 100.0 and got["unguided"]["density"] == 99.429
    assert_within(got, MEASURED)
    for a, b in (("guided", "unguided"), ("dsm_guided", "dsm_unguided")):
        for metric, expected in MEASURED[a].items():
            # The margin by which guided matching wins (completeness: guided covers more; the rest: lower errors).
            margin = MEASURED[b][metric] - expected
            assert got[b][metric] - got[a][metric] == pytest.approx(margin, rel=RELATIVE), (metric, margin)
            assert (got[a][metric] > got[b][metric]) if metric == "completeness" else (got[a][metric] < got[b][metric])


def test_readme_job_finds_the_older_lidars_offset_and_the_building_built_since(job):
    # sample_data/block/lidar_earlier.laz: the scan before a 7.42 m building was built, 2 m high and 0.15, -0.10 m
    # off (scene.json); measured: offset +2.03 m, one changed region of 134 points, change map median +6.19 m
    import json

    import numpy as np
    import rasterio

    out, stdout = job
    truth = json.loads((REPO / "sample_data" / "block" / "scene.json").read_text())["lidar_earlier"]
    lines = (out / "earlier.txt").read_text().splitlines()
    assert lines[0] == "height offset: estimated +2.03 m, true +2.00 m" and lines[0] in stdout
    check = json.loads((out / "match_earlier.json").read_text())["lidar_check"]
    assert check["regions"] == 1 and 120 <= check["changed"] <= 150 and check["outliers"] <= 5
    with rasterio.open(out / "change.tif") as ds:
        change = ds.read(1)
        rows, cols = np.nonzero(np.isfinite(change))
        xs, ys = rasterio.transform.xy(ds.transform, rows, cols)
    x0, y0, x1, y1 = truth["removed_building"]["bounds"]
    inside = (np.asarray(xs) >= x0 - 1) & (np.asarray(xs) <= x1 + 1) & (np.asarray(ys) >= y0 - 1) & \
        (np.asarray(ys) <= y1 + 1)
    assert len(rows) >= 120 and inside.mean() >= 0.95  # the change map finds the building, and nothing else
    assert 5.5 <= float(np.median(change[rows, cols])) <= 7.0  # its height (7.42 m) less the edges' points
