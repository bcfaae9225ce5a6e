"""The paper's protocol as a tool: matchers x guides x LiDAR shares on a Middlebury- or KITTI-layout folder.

LiDAR is simulated by seeded sampling of the ground truth (:func:`~riverbed_cli.products.simulate.simulate_lidar`),
every case is evaluated on the GT pixels that were not sampled, and each case's result is cached as a small JSON file,
so an interrupted run resumes where it stopped. The disparity range of a scene is ``[0, ceil(max GT) + 4]`` for every
method, so methods differ only in matching.
"""

import csv
import functools
import hashlib
import json
import logging
import math
import time
from dataclasses import dataclass
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import matplotlib
import numpy as np

from ..errors import RiverbedError
from ..io.atomic import atomic_output, output_group
from ..io.disparity import read_disparity
from ..io.images import read_image
from ..io.textfiles import load_text_data
from ..matching.pipeline import match_pair
from .densify import densify
from .evaluate import evaluate_disparity
from .simulate import simulate_lidar

matplotlib.use("Agg")  # headless: figures are only written to files
import matplotlib.pyplot as plt  # noqa: E402  (pyplot after the backend is chosen)

log = logging.getLogger(__name__)

METRICS = ("bad1", "bad2", "bad3", "avg", "rmse", "density", "d1", "n")
# Middlebury file name patterns: (left, right, ground truth, default GT scale for 8-bit PNG)
MIDDLEBURY_PATTERNS = (
    ("im0.png", "im1.png", "disp0GT.pfm", None),
    ("im0.png", "im1.png", "disp0.pfm", None),
    ("view1.png", "view5.png", "disp1.png", 2.0),  # 2005/2006 half size: d = value / 2
    ("im2.png", "im6.png", "disp2.png", 4.0),  # 2003 quarter size: d = value / 4
    ("left.png", "right.png", "gt.png", 256.0),  # 16-bit PNG ground truth, d = value / 256, 0 unknown (aerial pair)
)


@dataclass
class Scene:
    name: str
    left: np.ndarray
    right: np.ndarray
    gt: np.ndarray


def _middlebury_scene(folder, gt_scale):
    for lf, rf, gf, scale in MIDDLEBURY_PATTERNS:
        if all((folder / f).is_file() for f in (lf, rf, gf)):
            s = gt_scale if gt_scale is not None else scale
            return Scene(folder.name, read_image(folder / lf), read_image(folder / rf),
                         read_disparity(folder / gf, scale=s if gf.endswith(".png") else None))
    return None


def load_dataset(path, layout, gt_scale=None, scenes=None):
    """Scenes of a folder in Middlebury layout (one sub-folder per scene, or a scene folder itself) or KITTI layout
    (``image_2/``, ``image_3/``, ``disp_occ_0/`` with ``*_10.png``, possibly under ``training/``)."""
    path = Path(path)
    if not path.is_dir():
        raise RiverbedError("dataset folder not found", path)
    found = []
    if layout == "middlebury":
        one = _middlebury_scene(path, gt_scale)
        folders = [path] if one else sorted(p for p in path.iterdir() if p.is_dir())
        for f in folders:
            sc = one if f == path else _middlebury_scene(f, gt_scale)
            if sc is not None:
                found.append(sc)
    elif layout == "kitti":
        base = path / "training" if (path / "training").is_dir() else path
        for g in sorted((base / "disp_occ_0").glob("*_10.png")) if (base / "disp_occ_0").is_dir() else []:
            left, right = base / "image_2" / g.name, base / "image_3" / g.name
            if left.is_file() and right.is_file():
                found.append(Scene(g.stem, read_image(left), read_image(right),
                                   read_disparity(g, scale=gt_scale)))
    else:
        raise RiverbedError(f"unknown layout '{layout}' (use middlebury or kitti)")
    if not found:
        raise RiverbedError(f"no {layout} scenes found (left/right images with ground truth)", path)
    if scenes:
        missing = [n for n in scenes if n not in {s.name for s in found}]
        if missing:
            raise RiverbedError(f"no scene named {', '.join(missing)} (found: {', '.join(s.name for s in found)})",
                                path)
        found = [s for s in found if s.name in scenes]
    return found


def case_key(scene, matcher, guide, share, window, seed):
    return f"{scene}|{matcher}|{guide}|{share:g}|{window}|{seed}"


def _cache_name(key, scene_hash=""):
    # The riverbed version, the code (code_fingerprint) and the scene's pixels are part of the cache name: results
    # of other code, or of a scene whose files changed, are not reused.
    try:
        v = version("riverbed")
    except PackageNotFoundError:
        v = "dev"
    return hashlib.sha1(f"{v}|{code_fingerprint()}|{scene_hash}|{key}".encode()).hexdigest()[:16] + ".json"


@functools.lru_cache(maxsize=1)
def code_fingerprint():
    """A hash of riverbed's own source files (their paths and contents): a cached benchmark case is reused only by
    the code that computed it (a version number does not change from commit to commit)."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha1()
    for f in sorted(root.rglob("*.py")):
        h.update(f.relative_to(root).as_posix().encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()[:16]


def scene_fingerprint(scene):
    """A hash of a scene's images and ground truth (their shapes and pixels)."""
    h = hashlib.sha1()
    for a in (scene.left, scene.right, scene.gt):
        h.update(str(a.shape).encode() + np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]


#: Cache files larger than this are not read (one case's row is a few hundred bytes).
CACHE_MAX_BYTES = 100_000
#: What a cached row must hold to be used: the fields the tables read.
ROW_FIELDS = ("key", "scene", "matcher", "guide", "window", "window_set", "share", "seed", *METRICS, "seconds")


def _number(x):
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def cached_row(path, key):
    """The cached result row of case ``key`` in ``path``, or None with a warning when the file cannot be used
    (truncated, not JSON, not a row of this case): the case is then run again and the file replaced, so one bad
    cache file never stops a benchmark."""
    try:
        row, _ = load_text_data(path, "benchmark cache file", CACHE_MAX_BYTES, fmt="json")
    except RiverbedError as e:
        problem = str(e)
    else:
        missing = [k for k in ROW_FIELDS if k not in row] if isinstance(row, dict) else None
        if missing is None:
            problem = f"{path}: not a benchmark result row (a JSON {type(row).__name__})"
        elif missing:
            problem = f"{path}: incomplete benchmark result row (no {missing[0]})"
        elif row["key"] != key or not all(_number(row[m]) for m in METRICS):
            problem = f"{path}: not the result row of case {key}"
        else:
            return row
    log.warning("ignoring a cached case: %s; running it again", problem)
    return None


def lidar_sample(gt, share, seed, share_of="image"):
    """The benchmark's LiDAR: ``share`` of the image's pixels (``share_of="image"``) or of its GT pixels
    (``"gt"``, the density a sensor gives), sampled from the GT."""
    if share_of == "gt":
        n_gt = int(np.isfinite(gt).sum())
        share = min(1.0, share * n_gt / gt.size)
    elif share_of != "image":
        raise RiverbedError(f"LiDAR shares are of 'gt' or 'image' pixels, not '{share_of}'")
    return simulate_lidar(gt, share, seed=seed)


def run_benchmark(scenes, matchers=("sgm",), guides=("none", "gauss", "riverbed"), shares=(0.05, 0.0123, 0.0016),
                  windows=(), seeds=(0,), cache_dir=None, progress=None, baselines=(), share_of="image"):
    """Run every case (cached per case in ``cache_dir``); returns a list of result rows (dicts).

    ``seeds``: one LiDAR sampling per seed (an int is one seed); every case runs once per sampling, so results can
    be reported as a mean and spread over samplings rather than one lucky or unlucky draw. ``baselines``: LiDAR-only
    interpolations (:mod:`.densify` methods) run beside the matchers as matcher ``lidar``. ``share_of``: the shares
    are of the image's pixels (``image``) or of its GT pixels (``gt``).
    """
    cache = Path(cache_dir) if cache_dir else None
    if cache:
        cache.mkdir(parents=True, exist_ok=True)
    seeds = (seeds,) if isinstance(seeds, int) else tuple(seeds)
    rows = []
    for sc in scenes:
        d_max = int(math.ceil(np.nanmax(sc.gt))) + 4
        scene_hash = scene_fingerprint(sc) if cache else ""
        for share, seed in ((sh, se) for sh in shares for se in seeds):
            sparse = lidar_sample(sc.gt, share, seed, share_of)
            for method in baselines:
                key = case_key(sc.name, "lidar", method, share, None, seed) + ("|gt" if share_of == "gt" else "")
                t = time.perf_counter()
                disp = densify(sparse, method, sc.left)
                m = evaluate_disparity(disp, sc.gt, exclude=sparse)
                rows.append({"key": key, "scene": sc.name, "matcher": "lidar", "guide": method, "window": None,
                             "window_set": None, "share": share, "seed": seed, **m,
                             "seconds": round(time.perf_counter() - t, 4), "range": None, "tube_width": None,
                             "cached": False})
                if progress:
                    progress(1)
            for matcher in matchers:
                cases = [(g, None) for g in guides] + [("riverbed", w) for w in windows]
                for guide, window in cases:
                    key = case_key(sc.name, matcher, guide, share, window, seed) + ("|gt" if share_of == "gt" else "")
                    f = cache / _cache_name(key, scene_hash) if cache else None
                    row = cached_row(f, key) if f is not None and f.is_file() else None
                    if row is not None:
                        row["cached"] = True
                    else:
                        # a guide label GUIDE[@MODE][:FUSION] runs GUIDE with --range MODE and --fusion FUSION
                        label, _, fus = guide.partition(":")
                        name, _, rng = label.partition("@")
                        kw = {"guide": name}
                        if rng:
                            kw["range"] = rng
                        if fus:
                            kw["fusion"] = fus
                        if matcher != "sgm":
                            kw["matcher"] = matcher
                        if window is not None:
                            kw["window"] = window
                        res = match_pair(sc.left, sc.right, sparse, 0, d_max, **kw)
                        m = evaluate_disparity(res.disparity, sc.gt, exclude=sparse)
                        row = {"key": key, "scene": sc.name, "matcher": matcher, "guide": guide,
                               "window": res.info.get("window") if window is None else window,
                               "window_set": window, "share": share, "seed": seed, **m,
                               "seconds": res.info["seconds"], "range": res.info.get("range", "full"),
                               "tube_width": (res.info.get("tubes") or {}).get("mean_width"),
                               "fusion": res.info.get("fusion", "none")}
                        if f is not None:
                            tmp = f.with_suffix(".tmp")
                            tmp.write_text(json.dumps(row))
                            tmp.replace(f)
                        row["cached"] = False
                    rows.append(row)
                    if progress:
                        progress(1)
    return rows


def count_cases(scenes, matchers, guides, shares, windows, seeds=(0,), baselines=()):
    return len(scenes) * len(shares) * len(seeds) * (len(matchers) * (len(guides) + len(windows)) + len(baselines))


def _label(r):
    return r["guide"] if r["window_set"] is None else f"riverbed s={r['window_set']}"


def method_means(rows, metrics=("bad1", "bad3", "avg")):
    """Means over seeds: ``{(scene, share): {(matcher, label): {metric: mean, ..., "fused": bool}}}``, methods in
    the order of the rows; ``fused`` is whether every row of the method was fused (``fusion`` recorded, not
    ``none``)."""
    per = {}
    for r in rows:
        per.setdefault((r["scene"], r["share"]), {}).setdefault((r["matcher"], _label(r)), []).append(r)
    return {key: {m: {**{k: float(np.mean([r[k] for r in rs])) for k in metrics},
                      "fused": all(r.get("fusion", "none") not in (None, "none") for r in rs)}
                  for m, rs in methods.items()}
            for key, methods in per.items()}


def winners(rows):
    """Per scene and share, the method with the best mean (over seeds) of each metric: ``{(scene, share): {metric:
    (label, value)}}``; labels are ``matcher guide``."""
    out = {}
    for key, methods in method_means(rows).items():
        out[key] = {}
        for metric in ("bad1", "bad3", "avg"):
            means = {f"{m} {g}": v[metric] for (m, g), v in methods.items()}
            best = min(means, key=means.get)
            out[key][metric] = (best, means[best])
    return out


def beats_inputs_table(rows):
    """Markdown lines: per scene and share, does each fused guided method (a guide label without ``:none``) beat
    both of its inputs — unguided matching (guide ``none``) and every LiDAR-only interpolation — on bad1, bad3 and
    mean error (means over seeds)? Empty when the rows hold no such comparison."""
    lines = []
    for (scene, share), methods in method_means(rows).items():
        inputs = {f"{m} {g}": v for (m, g), v in methods.items() if m == "lidar" or g == "none"}
        fused = {f"{m} {g}": v for (m, g), v in methods.items()
                 if m != "lidar" and g != "none" and not g.endswith(":none") and v["fused"]}
        if not inputs or not fused:
            continue
        for label, mine in fused.items():
            cells = []
            for metric in ("bad1", "bad3", "avg"):
                best_in = min(inputs, key=lambda n: inputs[n][metric])
                best_v = inputs[best_in][metric]
                mark = "yes" if mine[metric] < best_v else "**no**"
                cells.append(f"{mine[metric]:.3g} vs {best_v:.3g} ({best_in}): {mark}")
            lines.append(f"| {scene} | {share * 100:.2f} % | {label} | " + " | ".join(cells) + " |")
    if not lines:
        return []
    return ["", "Does the fused output beat both its inputs (unguided matching and the best LiDAR-only interpolation "
            "of each metric; mean over seeds)?", "",
            "| scene | LiDAR | method | bad1 % | bad3 % | avg px |", "|---|---:|---|---|---|---|", *lines]


def write_tables(rows, outdir, share_of="image"):
    """results.md (paper-style: mean over scenes per share, then per scene), results.csv, results.json.

    With several seeds the first table is the mean over scenes and seeds, a second one gives each scene's mean over
    seeds with the worst seed's mean error (is a claim true for every sampling, not only on average?), and the
    per-case table lists every seed.
    """
    out = Path(outdir)
    keys = ["scene", "matcher", "guide", "window", "share", "seed", *METRICS, "seconds"]
    with output_group():  # the three tables appear together (io/atomic.py), replacing a previous run's
        with atomic_output(out / "results.csv", overwrite=True) as tmp, open(tmp, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(keys)
            for r in rows:
                w.writerow([r[k] for k in keys])
        with atomic_output(out / "results.json", overwrite=True) as tmp:
            tmp.write_text(json.dumps([{k: r[k] for k in keys} for r in rows], indent=1))
        with atomic_output(out / "results.md", overwrite=True) as tmp:
            tmp.write_text(_results_markdown(rows, share_of))
    return out / "results.md"


def _results_markdown(rows, share_of):
    of = "GT pixels" if share_of == "gt" else "image pixels"
    lines = [f"LiDAR shares are of the {of}; matcher `lidar` rows are LiDAR-only interpolations (no matching).", "",
             "| LiDAR | matcher | guide | bad1 % | bad2 % | bad3 % | avg px | rmse px |",
             "|---:|---|---|---:|---:|---:|---:|---:|"]
    groups = {}
    for r in rows:
        groups.setdefault((r["share"], r["matcher"], _label(r)), []).append(r)
    for (share, matcher, label), rs in groups.items():
        mean = {k: float(np.mean([r[k] for r in rs])) for k in ("bad1", "bad2", "bad3", "avg", "rmse")}
        lines.append(f"| {share * 100:.2f} % | {matcher} | {label} | {mean['bad1']:.2f} | {mean['bad2']:.2f} | "
                     f"{mean['bad3']:.2f} | {mean['avg']:.2f} | {mean['rmse']:.2f} |")
    seeds = sorted({r["seed"] for r in rows})
    if len(seeds) > 1:
        lines += ["", f"Per scene, mean over {len(seeds)} LiDAR samplings (seeds {', '.join(map(str, seeds))}):", "",
                  "| scene | LiDAR | matcher | guide | bad1 % | bad3 % | avg px | avg px, worst seed |",
                  "|---|---:|---|---|---:|---:|---:|---:|"]
        per_scene = {}
        for r in rows:
            per_scene.setdefault((r["scene"], r["share"], r["matcher"], _label(r)), []).append(r)
        for (scene, share, matcher, label), rs in per_scene.items():
            lines.append(f"| {scene} | {share * 100:.2f} % | {matcher} | {label} | "
                         f"{np.mean([r['bad1'] for r in rs]):.2f} | {np.mean([r['bad3'] for r in rs]):.2f} | "
                         f"{np.mean([r['avg'] for r in rs]):.3f} | {max(r['avg'] for r in rs):.3f} |")
    lines += beats_inputs_table(rows)
    win = winners(rows)
    lines += ["", "Best method per scene and LiDAR share (mean over seeds):", "",
              "| scene | LiDAR | bad1 % | bad3 % | avg px |", "|---|---:|---|---|---|"]
    for (scene, share), best in win.items():
        lines.append(f"| {scene} | {share * 100:.2f} % | " + " | ".join(
            f"{best[m][0]} ({best[m][1]:.2f})" if m != "avg" else f"{best[m][0]} ({best[m][1]:.3f})"
            for m in ("bad1", "bad3", "avg")) + " |")
    lines += ["", "| scene | LiDAR | seed | matcher | guide | window | bad1 % | bad2 % | bad3 % | avg px | density % |",
              "|---|---:|---:|---|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['share'] * 100:.2f} % | {r['seed']} | {r['matcher']} | {_label(r)} | "
                     f"{r['window'] or ''} | {r['bad1']:.2f} | {r['bad2']:.2f} | {r['bad3']:.2f} | {r['avg']:.2f} | "
                     f"{r['density']:.1f} |")
    return "\n".join(lines) + "\n"


def figure5(rows, path, scene=None, matcher="sgm"):
    """The paper's Figure 5: mean error against riverbed window size, one line per LiDAR share (matplotlib PNG)."""
    sel = [r for r in rows if r["guide"] == "riverbed" and r["window_set"] is not None and r["matcher"] == matcher
           and (scene is None or r["scene"] == scene)]
    if not sel:
        raise RiverbedError("Figure 5 needs riverbed runs at several windows (--windows)")
    fig, ax = plt.subplots(figsize=(6, 4), dpi=120)
    for share in sorted({r["share"] for r in sel}, reverse=True):
        pts = {}
        for r in sel:
            if r["share"] == share:
                pts.setdefault(r["window_set"], []).append(r["avg"])
        ws = sorted(pts)
        ax.plot(ws, [np.mean(pts[w]) for w in ws], marker="o", label=f"{share * 100:g} % LiDAR")
    ax.set_xlabel("riverbed window s (px)")
    ax.set_ylabel("mean error (px)")
    ax.set_title(f"Mean error vs window ({scene or 'mean over scenes'}, {matcher})")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    with atomic_output(path, overwrite=True) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return path


#: Relative tolerance of an expectation, and the absolute floor per metric (% points, px) below which a change is
#: noise (the tests' gates, tests/gates.py): a metric is off its expectation when it differs from it, up or down, by
#: more than ``relative * expected`` and more than the floor. 2 %: a run is deterministic (seeded LiDAR, integer
#: costs and paths, per-pixel float arithmetic), so on a machine like the one that wrote the expectations a figure
#: moves only when the code does; a 5 % regression fails.
RELATIVE = 0.02
FLOORS = {"bad1": 0.01, "bad2": 0.01, "bad3": 0.01, "avg": 0.001, "rmse": 0.001}
#: Decimals an expectation keeps (% points and px): below the floors, above the noise of re-runs.
DECIMALS = 4


def expectations(rows, relative=RELATIVE, floors=None):
    """An EXPECTED.json document from results: each case's metrics (rounded to :data:`DECIMALS`), with a relative
    tolerance and absolute floors."""
    floors = {**FLOORS, **(floors or {})}
    return {"tolerance": {"relative": relative, "floor": floors},
            "cases": [{"key": r["key"], **{k: round(float(r[k]), DECIMALS) for k in floors}} for r in rows]}


#: Expectation files larger than this are refused before parsing.
EXPECTATIONS_MAX_BYTES = 20_000_000


def read_expectations(path):
    """An EXPECTED.json document (:func:`expectations`) read and checked, so that :func:`check` cannot fail on it;
    :class:`RiverbedError` naming the file for anything else (oversized, not UTF-8, invalid or too deeply nested
    JSON, another shape).

    The tolerance is ``{"relative": r, "floor": {metric: x}}``; ``cases`` is a
    list of ``{"key": str, metric: number, ...}``. Metrics are those of :data:`METRICS`.
    """
    data, _ = load_text_data(path, "benchmark expectations file", EXPECTATIONS_MAX_BYTES, fmt="json")

    def refuse(problem):
        raise RiverbedError(f"not a benchmark expectations file ({problem})", path)

    if not isinstance(data, dict):
        refuse(f"a JSON {_json_kind(data)}, expected an object with tolerance and cases")
    tol = data.get("tolerance", {})
    if not isinstance(tol, dict):
        refuse("tolerance: expected an object")
    if not _number(tol.get("relative")):
        refuse("tolerance.relative: expected a number")
    limits = tol.get("floor")
    if not isinstance(limits, dict):
        refuse("tolerance.floor: expected an object of metric: number")
    for metric, value in limits.items():
        if metric not in METRICS or not _number(value):
            refuse(f"tolerance: '{metric}' is not a metric with a number (metrics: {', '.join(METRICS)})")
    cases = data.get("cases", [])
    if not isinstance(cases, list):
        refuse("cases: expected a list")
    for i, case in enumerate(cases):
        if not isinstance(case, dict) or not isinstance(case.get("key"), str):
            refuse(f"cases[{i}]: expected an object with a key string")
        bad = [m for m in limits if m in case and not _number(case[m])]
        if bad:
            refuse(f"cases[{i}].{bad[0]}: expected a number")
    return data


def _json_kind(value):
    return {list: "list", str: "string", bool: "boolean", type(None): "null"}.get(type(value), "number")


def _tolerance(value, metric, tol):
    """The largest distance of ``metric`` from an expectation of ``value`` that passes: relative, with a floor."""
    return max(tol["relative"] * abs(value), tol["floor"].get(metric, 0.0))


def check(rows, expected):
    """Compare results with expectations: a metric is off when it differs from the expected value, up or down, by
    more than its tolerance (a figure that got much better is a change to review too: write the expectations again).

    Returns a list of one-line failure messages (empty: all good). Expectations outside what was asked for (another
    scene, matcher, guide, share, window or seed than any run) are not compared, so a CI job may gate on a subset of
    a full expectations file; an expected case inside that selection that did not run is a failure.
    """
    tol = expected.get("tolerance", {})
    by_key = {r["key"]: r for r in rows}
    asked = [set() for _ in range(6)]  # scene, matcher, guide, share, window, seed (the parts of case_key)
    for key in by_key:
        for part, value in zip(asked, key.split("|")):
            part.add(value)
    failures = []
    for case in expected.get("cases", []):
        r = by_key.get(case["key"])
        if r is None:
            parts = case["key"].split("|")
            if len(parts) == 6 and all(v in a for v, a in zip(parts, asked)):
                failures.append(f"{case['key']}: expected but not run")
            continue
        for metric in tol["floor"]:
            if metric not in case:
                continue
            t = _tolerance(case[metric], metric, tol)
            # not (>): a metric that became NaN fails too
            if not abs(r[metric] - case[metric]) <= t:
                failures.append(f"{case['key']}: {metric} {r[metric]:.3f} outside {case[metric]:.3f} +- {t:.3f}")
    cases = expected.get("cases", [])
    if cases and not any(case["key"] in by_key for case in cases):
        failures.append(f"none of the {len(cases)} expected cases ran (expectations of another dataset or selection?)")
    return failures


def checked(rows, expected):
    """How many expected cases ``check`` compared (the ones that ran)."""
    keys = {r["key"] for r in rows}
    return sum(case["key"] in keys for case in expected.get("cases", []))
