"""Real stereo scenes with ground truth from the shared data folder (``RIVERBED_DATA`` or a path argument).

Middlebury dev scenes (dense GT) and, held out from development, the KITTI 2015 frame (sparse GT from accumulated
LiDAR). KITTI may not be copied into the repository; it is only read from the data folder.
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from riverbed_cli.io.disparity import read_disparity
from riverbed_cli.io.images import read_image

MIDDLEBURY = "middlebury_2003_2005_2006_ethanli/Data"
KITTI2015 = "kitti2015_stereo_sttr/sample_data/KITTI_2015/training"

# name -> (folder, left, right, gt, gt scale)
DEV_SCENES = {
    "Cones": ("cone", "im2.png", "im6.png", "disp2.png", 4),
    "Reindeer": ("Reindeer", "view1.png", "view5.png", "disp1.png", 2),
    "Cloth3": ("Cloth3", "view1.png", "view5.png", "disp1.png", 2),
    "Wood2": ("Wood2", "view1.png", "view5.png", "disp1.png", 2),
}


@dataclass
class Scene:
    name: str
    left: np.ndarray
    right: np.ndarray
    gt: np.ndarray  # float32, NaN = no GT
    held_out: bool = False


def middlebury(data_dir, name):
    folder, lf, rf, gf, scale = DEV_SCENES[name]
    base = Path(data_dir) / MIDDLEBURY / folder
    return Scene(name, read_image(base / lf), read_image(base / rf), read_disparity(base / gf, scale=scale))


def kitti2015(data_dir, frame="000046_10"):
    base = Path(data_dir) / KITTI2015
    return Scene(f"KITTI15-{frame[:6]}", read_image(base / "image_2" / f"{frame}.png"),
                 read_image(base / "image_3" / f"{frame}.png"), read_disparity(base / "disp_occ_0" / f"{frame}.png"),
                 held_out=True)


def all_scenes(data_dir, held_out=True):
    scenes = [middlebury(data_dir, n) for n in DEV_SCENES]
    if held_out and (Path(data_dir) / KITTI2015).is_dir():
        scenes.append(kitti2015(data_dir))
    return scenes


def speed_scene(data_dir):
    """The speed pair's images and whole-scene GT: Reindeer resized to 740x500, the GT scaled with it (up to 110 px,
    NaN unknown). Returns ``(left, right, gt)``."""
    import cv2

    sc = middlebury(data_dir, "Reindeer")
    left = cv2.resize(sc.left, (740, 500), interpolation=cv2.INTER_AREA)
    right = cv2.resize(sc.right, (740, 500), interpolation=cv2.INTER_AREA)
    return left, right, cv2.resize(sc.gt, (740, 500), interpolation=cv2.INTER_NEAREST) * (740 / sc.gt.shape[1])


def speed_pair(data_dir, seed=0, share=0.05, beyond=False):
    """The issue's speed case: Reindeer resized to 740x500 with 80 disparities (0..79) and LiDAR at ``share``.

    Returns ``(left, right, sparse)``. A third of the scene (the reindeer) lies beyond 79 px at this size: the GT is
    cut at 79 and the LiDAR sampled from the rest, so by default no LiDAR point lies outside the range. With
    ``beyond`` the LiDAR also holds points where the truth lies beyond 79 px, at the same density (the same points
    inside the range), as a real scan of the scene would: a user's ``--max-disp 79`` leaves them outside the range.
    """
    from riverbed_cli.products.simulate import simulate_lidar

    left, right, scene = speed_scene(data_dir)
    gt = scene.copy()
    gt[gt > 79] = np.nan
    sparse = simulate_lidar(gt, share, seed=seed)
    if beyond:
        far = np.flatnonzero(scene > 79)
        n = int(round(np.isfinite(sparse).sum() / np.isfinite(gt).sum() * far.size))
        idx = np.random.default_rng(seed + 1).choice(far, n, replace=False)
        sparse.flat[idx] = scene.flat[idx]
    return left, right, sparse


def cell(scores):
    """A table cell of ``[bad3 %, mean px]``: ``"1.50 / 0.269"``."""
    return f"{scores[0]:.2f} / {scores[1]:.3f}"


def rewrite_block(path, begin, end, body):
    """Replace the text between the markers ``begin`` and ``end`` of the file ``path`` by ``body`` (the generated
    tables of a doc page)."""
    text = Path(path).read_text()
    head, rest = text.split(begin)
    _, tail = rest.split(end)
    Path(path).write_text(f"{head}{begin}\n{body}\n{end}{tail}")


def rows_main(doc, run, tables, begin=None, end=None, options=()):
    """The command line of a benchmark whose rows make a doc page's tables: ``[DATA] [--write JSON] [--docs MD ...]
    [--rows JSON]``; ``run(data)`` measures the rows, ``tables(rows)`` makes the Markdown put between the markers
    ``begin`` and ``end`` of each ``--docs`` file; prints the tables. ``tables`` may also be a list of ``(tables,
    begin, end)``: each file gets the blocks whose markers it holds. ``options``: more ``(--name, help)`` options,
    passed to ``run`` by name."""
    import argparse
    import json
    import os

    blocks = [(tables, begin, end)] if begin is not None else list(tables)
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("data", nargs="?", default=os.environ.get("RIVERBED_DATA", "../shared/data"))
    ap.add_argument("--write", help="store the rows in this JSON file")
    ap.add_argument("--docs", action="append", default=[], help="rewrite the tables of this Markdown file")
    ap.add_argument("--rows", help="take the rows from this JSON file instead of running")
    for name, text in options:
        ap.add_argument(name, help=text)
    a = ap.parse_args()
    extra = {name.lstrip("-").replace("-", "_"): getattr(a, name.lstrip("-").replace("-", "_")) for name, _ in options}
    rows = json.loads(Path(a.rows).read_text()) if a.rows else run(a.data, **extra)
    if a.write:
        Path(a.write).write_text(json.dumps(rows, indent=1) + "\n")
    for path in a.docs:
        text = Path(path).read_text()
        for fn, b, e in blocks:
            if b in text:
                rewrite_block(path, b, e, fn(rows))
    for fn, _, _ in blocks:
        print(fn(rows))
