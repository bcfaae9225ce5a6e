"""docs/benchmarks.md's tables are what benchmarks/benchmark_tables.py makes of the committed benchmarks/expected_*.json
(which tests/test_benchmark_real.py measures again), and the claims its text states hold on them."""

import json
import sys
from collections import defaultdict

from conftest import REPO

sys.path.insert(0, str(REPO / "benchmarks"))
import benchmark_tables as bt  # noqa: E402

DOC = (REPO / "docs" / "benchmarks.md").read_text()


def test_the_doc_tables_are_the_committed_results():
    for name, make in bt.BLOCKS.items():
        begin, end = f"<!-- benchmark_tables: {name} -->", f"<!-- benchmark_tables: {name} end -->"
        assert DOC.count(begin) == 1 and DOC.count(end) == 1, name
        assert DOC.split(begin)[1].split(end)[0].strip() == make().strip(), name


def test_the_tubes_excerpt_is_the_committed_run():
    tubes = (REPO / "docs" / "tubes.md").read_text()
    begin, end = "<!-- benchmark_tables: tubes -->", "<!-- benchmark_tables: tubes end -->"
    assert tubes.split(begin)[1].split(end)[0].strip() == bt.tubes_table().strip()
    rows = json.loads((REPO / "benchmarks" / bt.TUBES[0]).read_text())
    # the four dev scenes, three shares, the three baselines and four guided/unguided range modes, seed 0
    assert len(rows) == 4 * 3 * (3 + 4) and {r["seed"] for r in rows} == {0}


def test_the_commands_are_the_ones_the_tests_check():
    text = (REPO / "tests" / "test_benchmark_real.py").read_text()
    for name, (file, command) in bt.RUNS.items():  # each file's command run again with --check
        assert f'committed(shared_data, tmp_path, "{name}")' in text, name
        assert f"--write-expected benchmarks/{file}" in command


def _means(name):
    groups = defaultdict(list)
    for (scene, matcher, guide, share, window, seed), m in bt.cases(name).items():
        if window == "None":
            groups[scene, share, matcher, guide].append(m)
    return {k: {m: sum(x[m] for x in v) / len(v) for m in bt.METRICS} for k, v in groups.items()}


def test_the_fused_default_beats_both_inputs_on_bad1_and_bad3_on_every_middlebury_scene_and_share():
    means = _means("middlebury_gt")
    for scene in ("cone", "Reindeer", "Cloth3", "Wood2"):
        for share in bt.SHARES:
            fused = means[scene, share, "sgm", "riverbed"]
            inputs = [means[scene, share, "sgm", "none"]] + [means[scene, share, "lidar", g] for g in bt.LIDAR_ORDER]
            for metric in ("bad1", "bad3"):
                assert fused[metric] < min(i[metric] for i in inputs), (scene, share, metric)


def test_the_fused_default_loses_to_unguided_matching_on_kitti_at_0_16_percent_of_the_gt():
    means = _means("kitti_gt")
    fused, unguided = means["000046_10", "0.0016", "sgm", "riverbed"], means["000046_10", "0.0016", "sgm", "none"]
    assert fused["bad1"] > unguided["bad1"] and fused["bad3"] > unguided["bad3"]


def test_riverbed_plus_beats_every_input_on_every_cell_but_one():
    """docs/fusion.md: fused riverbed+ beats every input on every metric of every Middlebury and aerial cell but
    Cones 5 % mean (0.259 vs 0.256 px)."""
    losses = []
    for name in ("middlebury_gt", "aerial_gt"):
        means = _means(name)
        for scene, share, matcher, guide in means:
            if (matcher, guide) != ("sgm", "riverbed+"):
                continue
            fused = means[scene, share, matcher, guide]
            inputs = [means[scene, share, "sgm", "none"]] + [means[scene, share, "lidar", g] for g in bt.LIDAR_ORDER]
            for metric in ("bad1", "bad3", "avg"):
                best = min(i[metric] for i in inputs)
                if not fused[metric] < best:
                    losses.append((scene, share, metric, round(fused[metric], 3), round(best, 3)))
    assert losses == [("cone", "0.05", "avg", 0.259, 0.256)]
    assert "Cones 5 % mean, 0.259 vs 0.256 px" in (REPO / "docs" / "fusion.md").read_text()
