"""The committed benchmark expectations as a regression gate, on real data read from RIVERBED_DATA.

The five `benchmarks/expected_*.json` files hold the tables of docs/benchmarks.md, written by the commands
benchmarks/benchmark_tables.py names (`riverbed benchmark ... --write-expected`). Each test runs its file's command
again with `--check`: every committed case is compared, and a case is off when a metric differs from its expectation,
up or down, by more than 2 % and a small floor (0.01 points, 0.001 px: the runs are deterministic; the tests' gates,
tests/gates.py). The claims the docs make on the rows are asserted beside.
"""

import json
import shlex
import sys
from pathlib import Path

from click.testing import CliRunner

from riverbed_cli.cli.main import cli

EXPECTED = Path(__file__).resolve().parent.parent / "benchmarks"
sys.path.insert(0, str(EXPECTED))
import benchmark_tables as bt  # noqa: E402


def committed(shared_data, tmp_path, name):
    """Run the command that wrote ``bt.RUNS[name]``'s expectations again, checked against them: every committed case
    compared. Returns the results' rows."""
    file, command = bt.RUNS[name]
    args = shlex.split(command.replace("$RIVERBED_DATA", str(shared_data)))[2:]  # without "riverbed benchmark"
    at = args.index("--write-expected")
    del args[at:at + 2]
    args[args.index("OUT")] = str(tmp_path)
    r = CliRunner().invoke(cli, ["benchmark", *args, "--check", str(EXPECTED / file), "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    cases = json.loads((EXPECTED / file).read_text())["cases"]
    assert s["checked"] == len(cases) == s["cases"] and s["regressions"] == [], s
    return json.loads((tmp_path / "results.json").read_text())


def test_middlebury_expectations_hold_on_every_dev_scene_and_share(shared_data, tmp_path):
    committed(shared_data, tmp_path, "middlebury")
    # (the committed cases, which the run just matched; keyed by the default window "None", not the window used)
    at5 = {(matcher, guide): m for (scene, matcher, guide, share, window, _), m in bt.cases("middlebury").items()
           if (scene, share, window) == ("cone", "0.05", "None")}
    # riverbed ahead of diffusion on bad1, bad2, bad3 and mean error (Cones is the closest dev scene), both fused:
    # clearly with SGM; with AD-Census bad1 and bad3 are a near tie, bad2 and the mean error ahead
    rb, diff = at5["sgm", "riverbed"], at5["sgm", "diffusion"]
    assert all(rb[k] < 0.8 * diff[k] for k in ("bad1", "bad2", "bad3", "avg"))
    rb, diff = at5["adcensus", "riverbed"], at5["adcensus", "diffusion"]
    assert rb["bad2"] < diff["bad2"] and rb["avg"] < 0.97 * diff["avg"]
    assert rb["bad1"] <= diff["bad1"] + 0.1 and rb["bad3"] <= diff["bad3"] + 0.1


def test_kitti_expectations_hold(shared_data, tmp_path):
    committed(shared_data, tmp_path, "kitti")
    (row,) = [m for (_, matcher, guide, share, window, _), m in bt.cases("kitti").items()
              if (matcher, guide, share, window) == ("sgm", "riverbed", "0.05", "None")]
    # 5 % of the *image* pixels here (42 % of this frame's GT): not the paper's Table 3 protocol (5 % of the GT),
    # which riverbed does not beat (docs/benchmarks.md); these bounds are the Table 3 figures, kept as a sanity floor
    assert row["bad3"] < 0.73 and row["avg"] < 0.45


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


def test_fused_default_beats_both_inputs_on_middlebury(shared_data, tmp_path):
    rows = committed(shared_data, tmp_path, "middlebury_gt")
    # every scene, share and metric but the two docs/fusion.md names (measured: Cones 5 % mean 0.263 vs the guided
    # interpolation's 0.256 px; Reindeer 0.16 % mean 1.78 vs 1.66 px)
    losses = {("cone", 0.05, "avg"), ("Reindeer", 0.0016, "avg")}
    for scene in ("cone", "Reindeer", "Cloth3", "Wood2"):
        for share in (0.05, 0.0123, 0.0016):
            for metric in ("bad1", "bad3", "avg"):
                assert beats_inputs(rows, scene, share, "riverbed", metric) == ((scene, share, metric) not in losses)


def test_fused_riverbed_plus_beats_both_inputs_on_the_aerial_pair(shared_data, tmp_path):
    rows = committed(shared_data, tmp_path, "aerial_gt")
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
    rows = committed(shared_data, tmp_path, "kitti_gt")
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
