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
    return CliRunner().invoke(cli, ["benchmark", *map(str, args)])


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
    # resume: every case comes from the cache, and the gate passes against its own expectations
    r = run(*args, "--check", tmp_path / "exp.json")
    s = json.loads(r.output)
    assert r.exit_code == 0 and s["cached"] == 4 and s["regressions"] == []
    # a regression: expectations better than reality by more than the tolerance
    exp = json.loads((tmp_path / "exp.json").read_text())
    for case in exp["cases"]:
        case["bad3"] -= 1.0
    (tmp_path / "better.json").write_text(json.dumps(exp))
    r = CliRunner().invoke(cli, ["benchmark", *map(str, args[:-1]), "--check", str(tmp_path / "better.json")])
    assert r.exit_code == 1
    assert "riverbed: regression: cones|sgm|none|0.05|None|0: bad3" in r.output


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
