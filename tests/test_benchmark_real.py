"""The committed benchmark expectations as a regression gate, on real data read from RIVERBED_DATA.

`benchmarks/expected_middlebury.json` and `benchmarks/expected_kitti.json` hold the full tables of
docs/benchmarks.md, reviewed and committed (`riverbed benchmark --write-expected`); a case regresses when a metric
exceeds its expectation by 10 % and by a small floor (0.05 points, 0.005 px). The gate covers every dev scene and
share for the guides the docs make claims for.
"""

import json
from pathlib import Path

from click.testing import CliRunner

from riverbed_cli.cli.main import cli

EXPECTED = Path(__file__).resolve().parent.parent / "benchmarks"
MIDDLEBURY = "middlebury_2003_2005_2006_ethanli/Data"
KITTI = "kitti2015_stereo_sttr/sample_data/KITTI_2015"


def bench(*args):
    r = CliRunner().invoke(cli, ["benchmark", "--baselines", "", *map(str, args), "--json"])
    return r.exit_code, (json.loads(r.output) if r.exit_code == 0 else r.output)


def test_middlebury_expectations_hold_on_cones(shared_data, tmp_path):
    code, s = bench(shared_data / MIDDLEBURY, "--layout", "middlebury", "--scenes", "cone", "--matchers",
                    "sgm,adcensus", "--guides", "none,diffusion,riverbed", "--shares", "0.05", "-o", tmp_path,
                    "--check", EXPECTED / "expected_middlebury.json")
    assert code == 0, s
    assert s["checked"] == 6 and s["regressions"] == []
    rows = {(r["matcher"], r["guide"]): r for r in json.loads((tmp_path / "results.json").read_text())}
    # riverbed ahead of diffusion on bad1, bad2, bad3 and mean error (Cones is the closest dev scene): clearly with
    # SGM; with AD-Census bad1 and bad3 are a near tie (measured 2.34 vs 2.35 %, 1.58 vs 1.59 %)
    rb, diff = rows["sgm", "riverbed"], rows["sgm", "diffusion"]
    assert all(rb[k] < 0.8 * diff[k] for k in ("bad1", "bad2", "bad3", "avg"))
    rb, diff = rows["adcensus", "riverbed"], rows["adcensus", "diffusion"]
    assert rb["bad2"] < diff["bad2"] and rb["avg"] < 0.95 * diff["avg"]
    assert rb["bad1"] <= diff["bad1"] + 0.1 and rb["bad3"] <= diff["bad3"] + 0.1


def test_middlebury_expectations_hold_on_every_dev_scene_and_share(shared_data, tmp_path):
    code, s = bench(shared_data / MIDDLEBURY, "--layout", "middlebury", "--matchers", "sgm,adcensus", "--guides",
                    "none,gauss,riverbed,diffusion,riverbed+", "-o", tmp_path, "--check",
                    EXPECTED / "expected_middlebury.json")
    assert code == 0, s
    assert s["checked"] == 4 * 3 * 2 * 5 and s["regressions"] == []


def test_kitti_expectations_hold(shared_data, tmp_path):
    code, s = bench(shared_data / KITTI, "--layout", "kitti", "--matchers", "sgm", "--guides", "riverbed",
                    "--shares", "0.05", "-o", tmp_path, "--check", EXPECTED / "expected_kitti.json")
    assert code == 0, s
    assert s["checked"] == 1 and s["regressions"] == []
    (row,) = json.loads((tmp_path / "results.json").read_text())
    # 5 % of the *image* pixels here (42 % of this frame's GT): not the paper's Table 3 protocol (5 % of the GT),
    # which riverbed does not beat (docs/benchmarks.md); these bounds are the Table 3 figures, kept as a sanity floor
    assert row["bad3"] < 0.73 and row["avg"] < 0.45
