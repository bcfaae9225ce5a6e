"""The accuracy tables of docs/benchmarks.md, made from the committed ``riverbed benchmark`` results.

The five ``benchmarks/expected_*.json`` files are ``riverbed benchmark --write-expected`` outputs (the commands are in
:data:`RUNS`; ``tests/test_benchmark_real.py`` runs them again with ``--check``). This script turns them into the
doc's tables, between the doc's ``<!-- benchmark_tables: NAME -->`` markers:

    python benchmarks/benchmark_tables.py --docs docs/benchmarks.md

``tests/test_benchmarks_doc.py`` checks that the committed doc is that rewrite.
"""

import argparse
import json
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from datasets import rewrite_block  # noqa: E402

HERE = Path(__file__).resolve().parent
METRICS = ("bad1", "bad2", "bad3", "avg", "rmse")
SHARES = ("0.05", "0.0123", "0.0016")
DATA = "$RIVERBED_DATA"
MB = f"{DATA}/middlebury_2003_2005_2006_ethanli/Data"
KITTI = f"{DATA}/kitti2015_stereo_sttr/sample_data/KITTI_2015"
GT = "--guides none,riverbed,riverbed+ --fusions auto,none --share-of gt --seeds 0,1,2"
#: name -> (expectations file, the command that wrote it)
RUNS = {
    "middlebury": ("expected_middlebury.json",
                   f"riverbed benchmark {MB} --layout middlebury --matchers sgm,adcensus "
                   "--guides none,gauss,riverbed,diffusion,riverbed+ --windows 5,9,15,25 -o OUT "
                   "--write-expected benchmarks/expected_middlebury.json"),
    "kitti": ("expected_kitti.json",
              f"riverbed benchmark {KITTI} --layout kitti --matchers sgm,adcensus "
              "--guides none,gauss,riverbed,diffusion,riverbed+ -o OUT --write-expected benchmarks/expected_kitti.json"),
    "middlebury_gt": ("expected_middlebury_gt.json",
                      f"riverbed benchmark {MB} --layout middlebury {GT} -o OUT "
                      "--write-expected benchmarks/expected_middlebury_gt.json"),
    "aerial_gt": ("expected_aerial_gt.json",
                  f"riverbed benchmark {DATA}/aerial_dublincity_fusionx3 --layout middlebury {GT} -o OUT "
                  "--write-expected benchmarks/expected_aerial_gt.json"),
    "kitti_gt": ("expected_kitti_gt.json",
                 f"riverbed benchmark {KITTI}/training --layout kitti {GT} -o OUT "
                 "--write-expected benchmarks/expected_kitti_gt.json"),
}
GUIDE_ORDER = ("none", "gauss", "diffusion", "riverbed", "riverbed:none", "riverbed+", "riverbed+:none")
LIDAR_ORDER = ("nearest", "linear", "guided")


def cases(name):
    """The expectations file's cases as ``{(scene, matcher, guide, share, window, seed): metrics}``."""
    data = json.loads((HERE / RUNS[name][0]).read_text())
    out = {}
    for case in data["cases"]:
        scene, matcher, guide, share, window, seed = case["key"].split("|")[:6]
        out[scene, matcher, guide, share, window, seed] = {m: case[m] for m in METRICS}
    return out


def _order(key):
    _, matcher, guide, _, window, _ = key
    if matcher == "lidar":
        return (2, "", LIDAR_ORDER.index(guide), 0)
    w = -1 if window == "None" else int(window)
    return (0 if matcher == "sgm" else 1, matcher, GUIDE_ORDER.index(guide), w)


def _label(matcher, guide, window):
    if matcher == "lidar":
        return f"LiDAR alone: `{guide}`"
    label = f"{matcher} {guide}"
    if guide.endswith(":none"):
        label = f"{matcher} {guide[:-5]}, no fusion"
    elif guide != "none":
        label += " (fused)"
    return label + (f", window {window}" if window != "None" else "")


def mean_table(name):
    """Per share, every method's mean over the file's scenes and seeds."""
    groups = defaultdict(list)
    for (scene, matcher, guide, share, window, seed), m in cases(name).items():
        groups[share, matcher, guide, window].append(m)
    lines = ["| LiDAR | method | bad1 % | bad2 % | bad3 % | mean px | RMSE px |",
             "|---:|---|---:|---:|---:|---:|---:|"]
    for share in SHARES:
        keys = sorted((k for k in groups if k[0] == share), key=lambda k: _order(("", *k[1:3], "", k[3], "")))
        for _, matcher, guide, window in keys:
            ms = groups[share, matcher, guide, window]
            avg = {m: sum(x[m] for x in ms) / len(ms) for m in METRICS}
            lines.append(f"| {float(share) * 100:.2f} % | {_label(matcher, guide, window)} | {avg['bad1']:.2f} | "
                         f"{avg['bad2']:.2f} | {avg['bad3']:.2f} | {avg['avg']:.3f} | {avg['rmse']:.2f} |")
    return "\n".join(lines)


def command(name):
    return f"`{RUNS[name][1]}`"


BLOCKS = {f"{name}": (lambda name=name: f"{command(name)}\n\n{mean_table(name)}") for name in RUNS}


#: docs/tubes.md's excerpt: a ``riverbed benchmark`` run over the search-range modes, its ``results.json`` committed
TUBES = ("results_benchmark_tubes.json",
         f"riverbed benchmark {MB} --layout middlebury --guides none,riverbed+ --ranges full,tube -o OUT")


def tubes_table():
    """The mean table ``riverbed benchmark`` writes (results.md) for the committed rows of :data:`TUBES`."""
    from riverbed_cli.products.benchmark import write_tables

    rows = [{**r, "window_set": None} for r in json.loads((HERE / TUBES[0]).read_text())]  # no --windows run
    with tempfile.TemporaryDirectory() as tmp:
        text = write_tables(rows, tmp).read_text()
    table = text.split("\n\n")[1]
    assert table.startswith("| LiDAR |"), table[:40]
    means = defaultdict(list)
    for r in rows:
        means[r["share"], r["guide"]].append(r["bad3"])
    gap = {share: abs(np.mean(means[share, "riverbed+@tube"]) - np.mean(means[share, "riverbed+@full"]))
           for share, _ in means}
    shares = sorted(gap, reverse=True)
    return (table + "\n\nriverbed+ with tubes is within " + ", ".join(f"{gap[s]:.2f}" for s in shares)
            + " bad3 points of the full range at " + ", ".join(f"{100 * s:.2f} %" for s in shares) + ".")


def write_docs(path):
    text = Path(path).read_text()
    for name, make in BLOCKS.items():
        begin = f"<!-- benchmark_tables: {name} -->"
        if begin in text:
            rewrite_block(path, begin, f"<!-- benchmark_tables: {name} end -->", make())
    if "<!-- benchmark_tables: tubes -->" in text:
        rewrite_block(path, "<!-- benchmark_tables: tubes -->", "<!-- benchmark_tables: tubes end -->", tubes_table())


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--docs", help="rewrite the tables of this Markdown file")
    a = ap.parse_args()
    if a.docs:
        write_docs(a.docs)
    for name, make in BLOCKS.items():
        print(f"## {name}\n\n{make()}\n")


if __name__ == "__main__":
    main()
