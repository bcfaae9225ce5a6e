"""The real LiDAR case: a KITTI object frame (Velodyne scan, calibration, rectified pair) through the CLI.

The data stays outside the repository (KITTI is CC BY-NC-SA): it is read from RIVERBED_DATA (``.ci/run`` sets
it to ``../shared/data``). benchmarks/kitti_lidar_demo.py runs the same steps and writes the colourised maps
in docs/.
"""

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from gates import assert_within, off_gate
from riverbed_cli.cli.main import cli
from riverbed_cli.io.disparity import read_disparity
from riverbed_cli.geometry.pairfile import load_pairfile
from riverbed_cli.products.evaluate import evaluate_disparity

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from kitti_lidar_demo import MATCHES, held_out, pipeline

#: the committed figures of benchmarks/kitti_lidar_demo.py (docs/projection.md)
RESULT = json.loads((Path(__file__).resolve().parents[1] / "benchmarks" / "results_kitti_lidar.json").read_text())

pytestmark = pytest.mark.data


def run(args):
    r = CliRunner().invoke(cli, [str(a) for a in args])
    assert r.exit_code == 0, r.output
    return r.stdout


@pytest.fixture(scope="module")
def kitti(shared_data, tmp_path_factory):
    work = tmp_path_factory.mktemp("kitti")
    paths, summary = pipeline(shared_data, work)
    return paths, summary


def test_pair_file_from_kitti_calibration(kitti):
    paths, _ = kitti
    pair = load_pairfile(paths["pair"])
    assert pair.image_size == (375, 1242) and pair.left == paths["left"]
    assert pair.focal == 721.5377 and pair.baseline == pytest.approx(0.5327, abs=1e-4)
    assert not pair.exactly_rectified  # camera 3 is 2.7 mm off camera 2's baseline


def test_projection_counts_and_photometric_check(kitti):
    paths, summary = kitti
    s = summary["project"]
    assert s["points_read"] == 103344
    total = (s["filtered"]["class"] + s["filtered"]["outliers"] + s["behind_camera"] + s["outside"]
             + s["row_offset"] + sum(s["occluded"].values()) + s["kept"])
    assert total == s["points_read"]
    # the committed counts, exactly (the MANIFEST's d range: 4.8 .. 163.1)
    p = RESULT["project"]
    assert {k: s[k] for k in ("points_read", "behind_camera", "outside", "row_offset", "occluded", "kept", "window")} \
        == {k: p[k] for k in ("points_read", "behind_camera", "outside", "row_offset", "occluded", "kept", "window")}
    assert s["filtered"]["outliers"] == p["outliers"] and [round(v, 1) for v in s["d_range"]] == p["d_range"]
    assert s["lidar_share"] == pytest.approx(p["lidar_share"], abs=1e-9)
    assert s["row_offset_px"] == pytest.approx(p["row_offset_px"], abs=1e-9) and s["row_offset_px"]["max"] < 1.0
    sparse = read_disparity(paths["sparse"])
    assert np.isfinite(sparse).sum() == s["kept"]
    # The LiDAR disparities agree with the images: the right image sampled at x - d matches the left image
    # better than at x - d +- 3.
    ph = {k: round(v, 2) for k, v in summary["photometric"].items()}
    assert ph == RESULT["photometric"]
    assert ph["0"] < ph["-3"] - 1 and ph["0"] < ph["+3"] - 1


#: the held-out figures are deterministic on a machine like CI's: gated within 1 % (with gates.py's floors)
RELATIVE = 0.01


def _by_method(rows):
    return {r["method"]: {k: r[k] for k in ("bad1", "bad3", "avg", "n", "density")} for r in rows}


def test_held_out_figures_are_the_committed_ones_and_the_default_beats_unguided(kitti, tmp_path):
    """Half the LiDAR guides (or is interpolated), the other half scores: every method's figures are the committed
    ones (docs/projection.md reads them); the default beats unguided stereo on every figure."""
    paths, _ = kitti
    rows, check, done = held_out(paths, tmp_path)
    got, want = _by_method(rows), _by_method(RESULT["held_out"])
    assert_within(got, want, relative=RELATIVE)
    assert check == RESULT["check"]
    default = got[MATCHES[1][0]]
    assert all(default[k] < got[MATCHES[0][0]][k] for k in ("bad1", "bad3", "avg"))
    # and the suite's gate (tests/gates.py) catches a real regression: a 5 px window instead of the auto one
    run(["match", paths["left"], paths["right"], "--min-disp", done["lo"], "--max-disp", done["hi"], "--sparse",
         tmp_path / "half.tif", "--window", "5", "-o", tmp_path / "w5.tif"])
    worse = evaluate_disparity(read_disparity(tmp_path / "w5.tif"), done["truth"])
    assert off_gate({"default": worse}, {"default": {k: default[k] for k in ("bad1", "bad3", "avg")}})


def test_kitti_data_is_not_in_the_repository():
    repo = Path(__file__).resolve().parents[1]
    assert not list(repo.glob("tests/data/**/lidar.bin")) and not list(repo.glob("tests/data/**/kitti*"))
