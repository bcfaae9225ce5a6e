"""The committed benchmark expectations as a regression gate, on real data read from RIVERBED_DATA.

`benchmarks/expected_middlebury.json` and `benchmarks/expected_kitti.json` hold the full tables of
docs/benchmarks.md, reviewed and committed (`riverbed benchmark --write-expected`); a case is off when a metric
differs from its expectation, up or down, by more than 10 % and a small floor (0.03 points, 0.005 px; the tests'
gates). The gate covers every dev scene and share for the guides the docs make claims for.
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
    # riverbed ahead of diffusion on bad1, bad2, bad3 and mean error (Cones is the closest dev scene), both fused:
    # clearly with SGM; with AD-Census bad1 and bad3 are a near tie, bad2 and the mean error ahead (measured 1.87 vs
    # 1.95 %, 0.260 vs 0.274 px)
    rb, diff = rows["sgm", "riverbed"], rows["sgm", "diffusion"]
    assert all(rb[k] < 0.8 * diff[k] for k in ("bad1", "bad2", "bad3", "avg"))
    rb, diff = rows["adcensus", "riverbed"], rows["adcensus", "diffusion"]
    assert rb["bad2"] < diff["bad2"] and rb["avg"] < 0.97 * diff["avg"]
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


AERIAL = "aerial_dublincity_fusionx3"
BASELINES = ("--baselines", "nearest,linear,guided")


def beats_inputs(rows, scene, share, label, metric):
    """Mean over seeds of ``label`` (a fused guide) below the best mean of unguided SGM and the LiDAR-only rows.

    bad1 and bad3 count a pixel without a disparity as an error; a mean error is over the pixels an output predicts,
    so it is compared only with inputs that predict at least as many (the unguided match leaves the left edge whose
    match lies outside the right image invalid: its mean is over easier pixels)."""
    def mean(pred, key=metric):
        vals = [r[key] for r in rows if r["scene"] == scene and r["share"] == share and pred(r)]
        assert len(vals) == 3, (scene, share, label, len(vals))  # one per seed
        return sum(vals) / 3
    preds = [lambda r: r["matcher"] == "sgm" and r["guide"] == "none"]
    preds += [lambda r, m=m: r["matcher"] == "lidar" and r["guide"] == m for m in ("nearest", "linear", "guided")]
    mine_pred = lambda r: r["matcher"] == "sgm" and r["guide"] == label  # noqa: E731
    if metric == "avg":
        preds = [p for p in preds if mean(p, "density") >= mean(mine_pred, "density") - 0.01]
    return mean(mine_pred) < min(mean(p) for p in preds)


def gt_protocol(shared_data, tmp_path, folder, layout, guides, expected):
    """The fusion protocol of docs/benchmarks.md: shares of the GT pixels, 3 samplings, LiDAR-only baselines; every
    case (each seed: the worst seed is gated too) within 10 % of the committed expectation."""
    code, s = bench(shared_data / folder, "--layout", layout, "--guides", guides, *BASELINES, "--share-of", "gt",
                    "--seeds", "0,1,2", "-o", tmp_path, "--check", EXPECTED / expected)
    assert code == 0, s
    assert s["regressions"] == []
    return s, json.loads((tmp_path / "results.json").read_text())


def test_fused_default_beats_both_inputs_on_middlebury(shared_data, tmp_path):
    s, rows = gt_protocol(shared_data, tmp_path, MIDDLEBURY, "middlebury", "none,riverbed",
                          "expected_middlebury_gt.json")
    assert s["checked"] == 4 * 3 * 3 * (2 + 3)
    # every scene, share and metric but the two docs/fusion.md names (measured: Cones 5 % mean 0.263 vs the guided
    # interpolation's 0.256 px; Reindeer 0.16 % mean 1.78 vs 1.66 px)
    losses = {("cone", 0.05, "avg"), ("Reindeer", 0.0016, "avg")}
    for scene in ("cone", "Reindeer", "Cloth3", "Wood2"):
        for share in (0.05, 0.0123, 0.0016):
            for metric in ("bad1", "bad3", "avg"):
                assert beats_inputs(rows, scene, share, "riverbed", metric) == ((scene, share, metric) not in losses)


def test_fused_riverbed_plus_beats_both_inputs_on_the_aerial_pair(shared_data, tmp_path):
    s, rows = gt_protocol(shared_data, tmp_path, AERIAL, "middlebury", "none,riverbed,riverbed+",
                          "expected_aerial_gt.json")
    assert s["checked"] == 3 * 3 * (3 + 3)
    scene = rows[0]["scene"]
    for share in (0.05, 0.0123, 0.0016):
        for metric in ("bad1", "bad3", "avg"):
            assert beats_inputs(rows, scene, share, "riverbed+", metric)
    # the default (riverbed) loses one cell (measured: 0.16 % mean 3.22 vs 2.23 px); at 5 % its bad3 wins by a hair
    # (4.49 vs 4.51 %: without the LiDAR check 4.54)
    assert beats_inputs(rows, scene, 0.05, "riverbed", "bad3")
    assert not beats_inputs(rows, scene, 0.0016, "riverbed", "avg")
    assert beats_inputs(rows, scene, 0.0123, "riverbed", "bad1") and beats_inputs(rows, scene, 0.0123, "riverbed",
                                                                                   "avg")


def test_kitti_gt_protocol_and_table_3(shared_data, tmp_path):
    s, rows = gt_protocol(shared_data, tmp_path, KITTI + "/training", "kitti", "none,riverbed",
                          "expected_kitti_gt.json")
    assert s["checked"] == 3 * 3 * (2 + 3)
    for share in (0.05, 0.0123):
        assert all(beats_inputs(rows, "000046_10", share, "riverbed", m) for m in ("bad1", "bad3", "avg"))
    # at 0.16 % of the GT (88 points) the fused output loses to unguided matching (docs/fusion.md): bad1 / bad3
    # (measured 30.7 / 14.7 % vs 20.5 / 5.1 %) and the mean error (1.59 px over 99.4 % of the pixels vs 1.03 px over
    # 99.0 %)
    assert not any(beats_inputs(rows, "000046_10", 0.0016, "riverbed", m) for m in ("bad1", "bad3"))
    mean_avg = {g: sum(r["avg"] for r in rows if r["share"] == 0.0016 and r["matcher"] == "sgm" and r["guide"] == g)
                / 3 for g in ("none", "riverbed")}
    assert mean_avg["riverbed"] > 1.4 * mean_avg["none"]
    # the paper's Table 3 protocol (5 % of the GT): the mean error beats its 0.45 px; bad1 / bad3 do not reach its
    # 2.60 / 0.73 % (measured 6.12 / 1.28 %)
    fused = [r for r in rows if r["share"] == 0.05 and r["matcher"] == "sgm" and r["guide"] == "riverbed"]
    assert sum(r["avg"] for r in fused) / 3 < 0.45
    assert sum(r["bad1"] for r in fused) / 3 > 2.60 and sum(r["bad3"] for r in fused) / 3 > 0.73
