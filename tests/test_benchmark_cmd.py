"""`riverbed benchmark`: the paper's protocol on a Middlebury-layout folder, cached, with a regression gate."""

import json
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

from riverbed_cli.cli.main import cli

CONES = Path(__file__).parent / "data" / "cones"


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("mb")
    shutil.copytree(CONES, root / "cones")  # im2.png, im6.png, disp2.png: the 2003 quarter-size layout
    return root


def run(*args):
    # the matcher cases only (the LiDAR-only baseline rows are tested in test_benchmark_baselines_and_winners)
    return CliRunner().invoke(cli, ["benchmark", "--baselines", "", *map(str, args)])


def test_benchmark_tables_figure_cache_and_check(dataset, tmp_path):
    out = tmp_path / "out"
    args = [dataset, "--layout", "middlebury", "-o", out, "--guides", "none,riverbed", "--shares", "0.05",
            "--windows", "5,13", "--json"]
    r = run(*args, "--write-expected", tmp_path / "exp.json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    assert s["cases"] == 4 and s["cached"] == 0 and s["regressions"] == []
    rows = json.loads((out / "results.json").read_text())
    by = {(x["guide"], x["window"]): x for x in rows}
    assert by["riverbed", 9]["bad3"] < 0.3 * by["none", None]["bad3"]  # the auto window at 5 % is 9
    assert (out / "figure5.png").stat().st_size > 10_000 and (out / "results.csv").is_file()
    assert "| 5.00 % | sgm | riverbed s=13 |" in (out / "results.md").read_text()
    # a finished run's tables are replaced only with --overwrite, and nothing runs without it
    r = run(*args, "--check", tmp_path / "exp.json")
    assert r.exit_code == 1
    assert r.output == f"riverbed: error: {out / 'results.csv'}: output exists; pass --overwrite to replace it\n"
    r = run(*args[:-1], "--write-expected", tmp_path / "exp.json")
    assert r.output == f"riverbed: error: {out / 'results.csv'}: output exists; pass --overwrite to replace it\n"
    # resume: every case comes from the cache, and the gate passes against its own expectations
    r = run(*args, "--check", tmp_path / "exp.json", "--overwrite")
    s = json.loads(r.output)
    assert r.exit_code == 0 and s["cached"] == 4 and s["regressions"] == []
    # a regression of 5 %: expectations 5 % better than reality (the tolerance is 2 %: the runs are deterministic)
    exp = json.loads((tmp_path / "exp.json").read_text())
    for case in exp["cases"]:
        case["bad3"] /= 1.05
    (tmp_path / "better.json").write_text(json.dumps(exp))
    r = CliRunner().invoke(cli, ["benchmark", "--baselines", "", *map(str, args[:-1]), "--check",
                                 str(tmp_path / "better.json"), "--overwrite"])
    assert r.exit_code == 1
    assert "riverbed: regression: cones|sgm|none|0.05|None|0: bad3" in r.output
    # the gate is two-sided: a figure much better than its expectation is a change to review too
    for case in exp["cases"]:
        case["bad3"] *= 1.05 * 1.05  # (from the lowered figures: 5 % above the measured ones)
    (tmp_path / "worse.json").write_text(json.dumps(exp))
    r = CliRunner().invoke(cli, ["benchmark", "--baselines", "", *map(str, args[:-1]), "--check",
                                 str(tmp_path / "worse.json"), "--overwrite"])
    assert r.exit_code == 1
    line = next(x for x in r.output.splitlines() if "cones|sgm|none|0.05|None|0: bad3" in x)
    case = next(c for c in exp["cases"] if c["key"] == "cones|sgm|none|0.05|None|0")
    assert line.endswith(f"outside {case['bad3']:.3f} +- {max(0.02 * case['bad3'], 0.01):.3f}")



def test_benchmark_bad_dataset(tmp_path):
    r = run(tmp_path, "--layout", "kitti", "-o", tmp_path / "o")
    assert r.exit_code == 1
    assert r.output == f"riverbed: error: {tmp_path}: no kitti scenes found (left/right images with ground truth)\n"


def test_benchmark_several_seeds(dataset, tmp_path):
    out = tmp_path / "out"
    r = run(dataset, "--layout", "middlebury", "-o", out, "--guides", "none,riverbed", "--shares", "0.05",
            "--seeds", "0,3", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["cases"] == 4
    rows = json.loads((out / "results.json").read_text())
    assert sorted({x["seed"] for x in rows}) == [0, 3]
    r0, r3 = ([x for x in rows if x["seed"] == s and x["guide"] == "riverbed"][0] for s in (0, 3))
    assert r0["bad3"] != r3["bad3"]  # two different LiDAR samplings, two results
    md = (out / "results.md").read_text()
    mean_avg = (r0["avg"] + r3["avg"]) / 2
    assert f"| cones | 5.00 % | sgm | riverbed | {r0['bad1'] / 2 + r3['bad1'] / 2:.2f} |" in md
    assert f"| {mean_avg:.3f} | {max(r0['avg'], r3['avg']):.3f} |" in md
    # the single-seed spelling still works, and a bad list is one line
    r = run(dataset, "--layout", "middlebury", "-o", tmp_path / "o2", "--guides", "none", "--shares", "0.05",
            "--seed", "x")
    assert r.exit_code == 1
    assert r.output == "riverbed: error: --seeds 'x' is not a comma-separated list of integers\n"


def test_benchmark_names_checked_before_running(dataset, tmp_path):
    out = tmp_path / "o"
    r = run(dataset, "--layout", "middlebury", "-o", out, "--guides", "none,riverbd")
    assert r.exit_code == 1
    assert r.output == ("riverbed: error: --guides 'none,riverbd': use a comma-separated list of none, gauss, "
                        "riverbed, diffusion, riverbed+\n")
    r = run(dataset, "--layout", "middlebury", "-o", out, "--scenes", "cones,teddy")
    assert r.exit_code == 1
    assert r.output == f"riverbed: error: {dataset}: no scene named teddy (found: cones)\n"
    assert not out.exists()  # nothing ran, nothing written


def test_benchmark_check_on_a_subset(dataset, tmp_path):
    """A CI job may gate on part of a full expectations file; cases outside its selection are not compared."""
    args = [dataset, "--layout", "middlebury", "--guides", "none,riverbed", "--shares", "0.05,0.0016"]
    r = run(*args, "-o", tmp_path / "full", "--write-expected", tmp_path / "exp.json", "--json")
    assert r.exit_code == 0, r.output
    r = run(dataset, "--layout", "middlebury", "--guides", "riverbed", "--shares", "0.05", "-o", tmp_path / "sub",
            "--check", tmp_path / "exp.json", "--json")
    s = json.loads(r.output)
    assert r.exit_code == 0 and s["checked"] == 1 and s["regressions"] == []
    # an expected case inside the selection that did not run is still a failure
    exp = json.loads((tmp_path / "exp.json").read_text())
    riverbed = next(c for c in exp["cases"] if c["key"] == "cones|sgm|riverbed|0.05|None|0")
    exp["cases"].append({**riverbed, "key": "cones|sgm|riverbed|0.05|None|7"})
    exp["tolerance"]["relative"] = 0.5  # another sampling of the LiDAR: another result, within half of seed 0's
    (tmp_path / "exp2.json").write_text(json.dumps(exp))
    r = run(dataset, "--layout", "middlebury", "--guides", "riverbed", "--shares", "0.05", "--seeds", "0", "-o",
            tmp_path / "sub", "--check", tmp_path / "exp2.json", "--overwrite")
    assert r.exit_code == 0  # seed 7 was not asked for
    r = run(dataset, "--layout", "middlebury", "--guides", "riverbed", "--shares", "0.05", "--seeds", "0,7", "-o",
            tmp_path / "sub", "--check", tmp_path / "exp2.json", "--json", "--overwrite")
    # seed 7 ran now, so it was compared
    assert r.exit_code == 0 and json.loads(r.output)["checked"] == 2
    # expectations of another dataset: nothing compared is a failure, not a pass
    other = {"tolerance": exp["tolerance"], "cases": [{**exp["cases"][0], "key": "teddy|sgm|riverbed|0.05|None|0"}]}
    (tmp_path / "other.json").write_text(json.dumps(other))
    r = CliRunner().invoke(cli, ["benchmark", "--baselines", "", str(dataset), "--layout", "middlebury", "--guides",
                                 "riverbed", "--shares", "0.05", "-o", str(tmp_path / "sub"),
                                 "--check", str(tmp_path / "other.json"), "--overwrite"])
    assert r.exit_code == 1
    assert "riverbed: regression: none of the 1 expected cases ran (expectations of another dataset or selection?)" \
        in r.output


def test_benchmark_baselines_and_winners(dataset, tmp_path):
    """Every table shows the LiDAR-only baselines beside the matchers, says what the shares are of, and names the
    best method per scene and metric."""
    r = CliRunner().invoke(cli, ["benchmark", str(dataset), "--layout", "middlebury", "--guides", "none,riverbed",
                                 "--shares", "0.05", "--share-of", "gt", "-o", str(tmp_path), "--json"])
    assert r.exit_code == 0, r.output
    rows = json.loads((tmp_path / "results.json").read_text())
    assert {(x["matcher"], x["guide"]) for x in rows} == {("sgm", "none"), ("sgm", "riverbed"), ("lidar", "nearest"),
                                                         ("lidar", "linear"), ("lidar", "guided")}
    md = (tmp_path / "results.md").read_text()
    assert md.startswith("LiDAR shares are of the GT pixels")
    assert "Best method per scene and LiDAR share" in md
    by = {x["guide"]: x for x in rows}
    # Cones at 5 % of the GT pixels: riverbed beats unguided matching and nearest-neighbour LiDAR on bad3
    assert by["riverbed"]["bad3"] < by["nearest"]["bad3"] < by["none"]["bad3"]


def test_the_cache_serves_only_the_code_and_the_scene_that_computed_it(dataset, tmp_path, monkeypatch):
    """A cached case is reused by the same code on the same scene; after a code change (another source fingerprint)
    or a change of the scene's pixels it is run again."""
    from riverbed_cli.products import benchmark as bm

    out = tmp_path / "out"
    args = [dataset, "--layout", "middlebury", "-o", out, "--guides", "none", "--shares", "0.05", "--json",
            "--overwrite"]
    assert json.loads(run(*args).output)["cached"] == 0
    assert json.loads(run(*args).output)["cached"] == 1
    monkeypatch.setattr(bm, "code_fingerprint", lambda: "another commit")
    assert json.loads(run(*args).output)["cached"] == 0
    monkeypatch.undo()
    assert json.loads(run(*args).output)["cached"] == 1
    changed = tmp_path / "mb"
    shutil.copytree(dataset, changed)
    import cv2

    im = cv2.imread(str(changed / "cones" / "im6.png"))
    im[0, 0] = 255 - im[0, 0]  # one pixel of the right image
    cv2.imwrite(str(changed / "cones" / "im6.png"), im)
    assert json.loads(run(changed, *args[1:]).output)["cached"] == 0


def test_a_metric_that_became_nan_or_zero_or_moved_5_percent_fails_the_gate():
    from riverbed_cli.products import benchmark as bm

    key = "cones|sgm|riverbed|0.05|None|0"
    row = {"key": key, "bad1": 3.2, "bad2": 2.0, "bad3": 1.5, "avg": 0.27, "rmse": 1.2}
    expected = bm.expectations([row])  # the committed files' tolerance: 2 %, floors 0.01 points and 0.001 px
    assert expected["tolerance"] == {"relative": 0.02, "floor": {"bad1": 0.01, "bad2": 0.01, "bad3": 0.01,
                                                                 "avg": 0.001, "rmse": 0.001}}
    assert bm.check([row], expected) == []
    assert bm.check([{**row, "avg": float("nan")}], expected) == [f"{key}: avg nan outside 0.270 +- 0.005"]
    assert bm.check([{**row, "bad3": 0.0}], expected) == [f"{key}: bad3 0.000 outside 1.500 +- 0.030"]
    assert bm.check([{**row, "bad3": 1.575}], expected) == [f"{key}: bad3 1.575 outside 1.500 +- 0.030"]
    # two-sided: much better is off its expectation too; within the tolerance either way passes
    assert bm.check([{**row, "bad3": 1.425}], expected) == [f"{key}: bad3 1.425 outside 1.500 +- 0.030"]
    assert bm.check([{**row, "bad3": 1.52, "avg": 0.274}], expected) == []
