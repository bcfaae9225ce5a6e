"""docs/method.md's table of the paper's variants is what benchmarks/bench_method_variants.py makes of the committed
benchmarks/results_method_variants.json, the conclusions drawn under it hold on those rows, and one scene is measured
again (data test)."""

import json
import sys

import pytest

from conftest import REPO

sys.path.insert(0, str(REPO / "benchmarks"))
import bench_method_variants as bmv  # noqa: E402

ROWS = json.loads((REPO / "benchmarks" / "results_method_variants.json").read_text())
DOC = (REPO / "docs" / "method.md").read_text()


def dev(variant, share):
    return bmv.figures(ROWS, variant, share)


def kitti(variant, share):
    return bmv.figures(ROWS, variant, share, kitti=True)


def test_the_doc_table_is_the_committed_results():
    assert DOC.split(bmv.BEGIN)[1].split(bmv.END)[0].strip() == bmv.tables(ROWS).strip()


@pytest.mark.parametrize("share", bmv.SHARES)
def test_additive_beats_the_product_and_eq3_as_printed_loses(share):
    for additive, product in (("Gauss, additive", "Gauss, product (paper)"), (bmv.DEFAULT, "riverbed, product walls")):
        a, p = dev(additive, share), dev(product, share)
        assert a[0] < p[0] and a[1] <= p[1]
    literal, default = dev("riverbed, eq. 3 as printed (W > gamma)", share), dev(bmv.DEFAULT, share)
    assert literal[0] > default[0] + 0.3 and literal[1] > default[1]


def test_the_window_target_is_the_compromise():
    # larger windows help the dev scenes at 5 % but not KITTI
    assert dev("riverbed, s = 25", 0.05)[0] < dev(bmv.DEFAULT, 0.05)[0]
    assert kitti("riverbed, s = 25", 0.05)[0] > kitti(bmv.DEFAULT, 0.05)[0]
    # four points per window: better than one on the dev scenes at 5 % and 1.23 %, KITTI within a few hundredths at
    # 5 %, the same on the dev scenes at 0.16 % (the window at its cap)
    for share in (0.05, 0.0123):
        assert dev(bmv.DEFAULT, share)[0] < dev("riverbed, s*s*p >= 1", share)[0]
    assert abs(kitti(bmv.DEFAULT, 0.05)[0] - kitti("riverbed, s*s*p >= 1", 0.05)[0]) <= 0.05
    for v in ("riverbed, s*s*p >= 1", "riverbed, s = 25"):
        assert dev(v, 0.0016) == dev(bmv.DEFAULT, 0.0016)


def test_the_sub_pixel_headline_holds_on_average_not_on_every_scene():
    assert dev(bmv.DEFAULT, 0.0016)[1] < 1.0
    per_scene = [r["score"][1] for r in ROWS if r["variant"] == bmv.DEFAULT and r["share"] == 0.0016
                 and r["scene"] != "KITTI"]
    assert max(per_scene) > 1.0


def test_a_scene_measured_again_is_the_committed_one(shared_data):
    rows = [{**r, "score": [round(v, 4) for v in r["score"]]} for r in bmv.scene_rows(shared_data, "Cones")]
    assert rows == [r for r in ROWS if r["scene"] == "Cones"]
