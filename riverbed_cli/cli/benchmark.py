"""``riverbed benchmark``: matchers x guides x LiDAR shares on a dataset folder, the paper's protocol."""

import json
from pathlib import Path

import click

from ..errors import RiverbedError
from ..io.atomic import atomic_output, check_output, check_output_folder, output_group
from ..matching.config import FUSION_CHOICES, GUIDE_NAMES as GUIDES, MATCHER_NAMES as MATCHERS, RANGES
from ..products.densify import METHODS as DENSIFY_METHODS
from ..products import benchmark as bm
from .options import json_opt, overwrite_opt, print_json, progress_bar


def _floats(value, name):
    try:
        return tuple(float(v) for v in value.split(",") if v.strip())
    except ValueError:
        raise RiverbedError(f"--{name} '{value}' is not a comma-separated list of numbers") from None


def _names(value, name, allowed):
    # checked before anything runs, so a typo does not cost a half-finished benchmark
    out = tuple(v.strip() for v in value.split(",") if v.strip())
    bad = [v for v in out if v not in allowed]
    if bad or not out:
        raise RiverbedError(f"--{name} '{value}': use a comma-separated list of {', '.join(allowed)}")
    return out


def _ints(value, name):
    try:
        out = tuple(int(v) for v in value.split(",") if v.strip())
    except ValueError:
        raise RiverbedError(f"--{name} '{value}' is not a comma-separated list of integers") from None
    if not out:
        raise RiverbedError(f"--{name} is empty")
    return out


@click.command("benchmark")
@click.argument("dataset", type=click.Path(file_okay=False))
@click.option("--layout", type=click.Choice(["middlebury", "kitti"]), required=True, help="Folder layout.")
@click.option("-o", "--output", "outdir", required=True, type=click.Path(file_okay=False),
              help="Output folder: results.md/.csv/.json, figure5.png, cache/.")
@click.option("--matchers", default="sgm", show_default=True, help="Comma-separated matchers.")
@click.option("--guides", default="none,gauss,riverbed", show_default=True, help="Comma-separated guides.")
@click.option("--ranges", default="auto", show_default=True,
              help="Comma-separated search-range modes (auto, tube, tile, full; riverbed match --range): each guide "
                   "runs once per mode, labelled GUIDE@MODE (auto: plain GUIDE).")
@click.option("--fusions", default="auto", show_default=True,
              help="Comma-separated fusions (auto, confidence, none; riverbed match --fusion): each guided case runs "
                   "once per fusion, labelled GUIDE:FUSION (auto: plain GUIDE).")
@click.option("--shares", default="0.05,0.0123,0.0016", show_default=True, help="LiDAR shares of the pixels.")
@click.option("--share-of", type=click.Choice(["image", "gt"]), default="image", show_default=True,
              help="The shares are of the image's pixels or of its ground-truth pixels (a sensor's density).")
@click.option("--baselines", default="nearest,linear,guided", show_default=True,
              help="LiDAR-only interpolations run beside the matchers ('' for none; riverbed densify).")
@click.option("--windows", default="", help="Extra riverbed windows, e.g. 5,9,15,25 (Figure 5).")
@click.option("--seeds", "--seed", "seeds", default="0", show_default=True,
              help="Seeds of the LiDAR sampling, comma-separated: each case runs once per sampling.")
@click.option("--scenes", default="", help="Only these scenes (comma-separated names).")
@click.option("--gt-scale", type=float, default=None, help="GT value per pixel of disparity (8-bit PNG).")
@click.option("--figure-scene", default=None, help="Scene of Figure 5 [default: mean over scenes].")
@click.option("--check", "expected", type=click.Path(dir_okay=False), default=None,
              help="Compare with EXPECTED.json; exit 1 on a regression.")
@click.option("--write-expected", type=click.Path(dir_okay=False), default=None,
              help="Store these results as expectations (for a later --check).")
@json_opt
@overwrite_opt
def benchmark_cmd(dataset, layout, outdir, matchers, guides, ranges, fusions, shares, share_of, baselines, windows,
                  seeds, scenes, gt_scale, figure_scene, expected, write_expected, as_json, overwrite):
    """Run the paper's protocol on DATASET: seeded LiDAR sampled from the ground truth at each share, every
    matcher x guide, evaluated on the GT pixels not sampled. Cases are cached in OUTPUT/cache, so an interrupted run
    resumes; --check makes it a regression gate for CI."""
    out = Path(outdir)
    exp = bm.read_expectations(expected) if expected else None
    scene_list = bm.load_dataset(dataset, layout, gt_scale, [s for s in scenes.split(",") if s])
    ms = _names(matchers, "matchers", MATCHERS)
    gs = _names(guides, "guides", GUIDES)
    rs = _names(ranges, "ranges", RANGES)
    gs = tuple(g if r == "auto" else f"{g}@{r}" for g in gs for r in rs)
    fs = _names(fusions, "fusions", FUSION_CHOICES)
    # unguided matching has nothing to fuse with: it runs once
    gs = tuple(dict.fromkeys(g if f == "auto" or g.startswith("none") else f"{g}:{f}" for g in gs for f in fs))
    sh = _floats(shares, "shares")
    ws = tuple(int(w) for w in _floats(windows, "windows"))
    se = _ints(seeds, "seeds")
    # the tables, the figure and the expectations claimed before any work: a finished run's are replaced only with
    # --overwrite (a run interrupted before them resumes from OUTPUT/cache without it)
    check_output_folder(out, ("results.csv", "results.json", "results.md") + (("figure5.png",) if ws else ()),
                        overwrite, inputs=[expected])
    if write_expected:
        check_output(write_expected, overwrite, inputs=[expected])
    out.mkdir(exist_ok=True)
    bl = _names(baselines, "baselines", DENSIFY_METHODS) if baselines.strip() else ()
    total = bm.count_cases(scene_list, ms, gs, sh, ws, se, bl)
    with progress_bar(total, desc="benchmark", unit="case") as bar:
        rows = bm.run_benchmark(scene_list, ms, gs, sh, ws, se, out / "cache", progress=bar.update, baselines=bl,
                                share_of=share_of)
    fig = None
    with output_group():  # the tables, the figure and the expectations appear together (io/atomic.py)
        bm.write_tables(rows, out, share_of)
        if ws:
            fig = bm.figure5(rows, out / "figure5.png", figure_scene, ms[0])
        if write_expected:
            with atomic_output(write_expected, overwrite=True) as tmp:
                tmp.write_text(json.dumps(bm.expectations(rows), indent=1))
    failures = bm.check(rows, exp) if exp is not None else []
    summary = {"cases": len(rows), "cached": sum(r["cached"] for r in rows), "results": str(out / "results.md"),
               "figure": str(fig) if fig else None, "regressions": failures,
               "checked": bm.checked(rows, exp) if exp is not None else 0}
    if as_json:
        print_json(summary)
    else:
        click.echo((out / "results.md").read_text())
    if failures:
        for f in failures:
            click.echo(f"riverbed: regression: {f}", err=True)
        raise SystemExit(1)
