"""The stages of one pair (plain functions; tasks on dask): project the LiDAR, match (whole or one tile), finish
(stitch, triangulate, DSM, ``done.json``)."""

import contextlib
import json
import math
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...errors import RiverbedError
from ...geometry.projection import project_cloud
from ...geometry.rpc_geometry import cloud_to_wgs84, output_crs
from ...io.atomic import atomic_output
from ...io.disparity import read_disparity, write_disparity
from ...io.images import check_pair, check_pixels, read_image, read_valid_area
from ...io.lidar import lidar_info, resolve_crs
from ...geometry.pairfile import load_pairfile, load_registration
from ...io.windowed import (WindowedRaster, image_bits, open_range_map, open_windowed, sparse_points_any,
                            valid_area_source)
from ...matching.lidar_input import resolve_disparity_range
from ...matching.pipeline import match_pair
from ...matching.tubes import ranges_from_disparity, spacing_window
from ...products.dsm import build_dsm
from ...products.dsm_files import RPC_HEIGHTS, write_dsm_outputs
from ...products.change_map import CHANGED_POINT
from ..match_plan import MatchPlan, Tile, plan_match, scan_range_map
from ..tiles import match_tile, prepare_lidar_whole
from .plan import (DONE, LIDAR_OUTPUT, OUTPUTS, WORK, clean_temps, rectify_rpc, riverbed_version, sha256_file,
                   write_json)
from .settings import match_params


class RectifyError(RiverbedError):
    """Bad input found while rectifying an ``rpc:`` entry's ROI (the project task's first step): reported as the
    ``rectify`` stage's failure."""

    stage = "rectify"


class PairFailure:
    """Bad input found by a stage: returned (not raised) so dask does not retry it; later stages pass it on."""

    def __init__(self, stage, message):
        self.stage, self.message = stage, message

    def __repr__(self):
        return f"PairFailure({self.stage!r}, {self.message!r})"


#: An RPC pair's cloud is read when its header box's corners project within this many pixels of the left image.
RPC_BOX_MARGIN_PX = 16


def _cloud_may_land(path, pair, reg, shape, crs=None):
    """False when the cloud's header box cannot project into the left image (all corners in front of the camera
    and their image hull outside it; for an RPC pair, the corners through the cloud's CRS and the RPC, with a
    margin of :data:`RPC_BOX_MARGIN_PX`): such a cloud is not read at all."""
    info = lidar_info(path)  # validates the header: a corrupt file fails here
    if info.point_count == 0:
        return False
    corners = np.array(np.meshgrid(*zip(info.mins, info.maxs))).T.reshape(-1, 3)
    margin = 0.0
    if getattr(pair, "kind", None) == "rpc":
        lon, lat, h = cloud_to_wgs84(resolve_crs(info, crs), path)(corners[:, 0], corners[:, 1], corners[:, 2])
        x, y, _, _ = pair.project(lon, lat, h)
        if not (np.isfinite(x).all() and np.isfinite(y).all()):
            return True
        margin = RPC_BOX_MARGIN_PX
    else:
        local = pair.lidar_to_local(corners, reg)
        x, y, _, depth = pair.project(local)
        if not (depth > 0).all():
            return True
    H, W = shape
    return not (x.max() < -0.5 - margin or x.min() >= W - 0.5 + margin or y.max() < -0.5 - margin
                or y.min() >= H - 0.5 + margin)


_EMPTY_CLOUD = ("no point lands in both images", "no point is left after")

def _image_source(path, shape, max_pixels):
    """The image as a windowed TIFF or an in-memory array, checked against the pair's size and the pixel limit."""
    H, W = shape
    check_pixels(path, H, W, max_pixels)
    src = open_windowed(path, "image")
    if tuple(src.shape[:2]) != (H, W):
        raise RiverbedError(f"image is {src.shape[1]}x{src.shape[0]} but the pair file says {W}x{H} (WxH)", path)
    return src


def _save_npy(src, path, rows=512):
    """Write an image (array or windowed raster) as ``.npy`` block by block, atomically."""
    with atomic_output(path, overwrite=True) as tmp:
        out = np.lib.format.open_memmap(tmp, mode="w+", dtype=src.dtype, shape=tuple(src.shape))
        for y in range(0, src.shape[0], rows):
            out[y:y + rows] = src[y:y + rows, 0:src.shape[1]]
        out.flush()
        del out


@dataclass
class PairPlan:
    """A projected pair's plan, handed from its project task to its match and finish tasks (plain values: dask sends
    it between processes as it is).

    ``match``: the :class:`~riverbed_cli.scale.plan.MatchPlan` (range, LiDAR shares, window, tiles), made as
    :func:`~riverbed_cli.scale.tiles.match_tiled` makes it; ``bits``: the images' bit depth when tiled (one 16-bit
    scale for all tiles), else None; ``stats``: what projection and the LiDAR's offset and check found (the pair's
    summary takes them); ``shape``: ``[H, W]``; ``range_map``: the pair's per-pixel ranges are in its ``.work``
    folder; ``rectify_seconds``: its ROI's rectification (RPC entries), None without one; ``seconds``: the project
    task's."""

    match: MatchPlan
    bits: object
    stats: dict
    shape: list
    range_map: bool = False
    rectify_seconds: float = None
    seconds: float = 0.0

    @property
    def tiled(self):
        return self.match.tiled


def project_stage(job):
    """Project the pair's clouds into sparse disparities (``sparse.tif``) and plan the matching.

    Several clouds: each is projected alone and, per pixel, the larger disparity (the nearer point) is kept;
    clouds whose box misses the left image are not read, and a cloud with no point in the pair is ignored as
    long as another one has points. A pair larger than the tile is planned as :func:`match_tiled` plans it (tile
    size, LiDAR tile ranges, one riverbed window and one 16-bit scale for all tiles) and its images are copied
    to ``.work/*.npy`` for the tile tasks to read crops from. Returns the :class:`PairPlan`.
    """
    t0 = time.perf_counter()
    s = job.settings
    folder = Path(job.folder)
    folder.mkdir(parents=True, exist_ok=True)
    with contextlib.suppress(FileNotFoundError):
        (folder / DONE).unlink()  # from now on the folder is not a finished pair
    clean_temps(folder, ("sparse.tif",))
    clean_temps(folder / WORK, ("left.npy", "right.npy", "left_valid.npy", "right_valid.npy", "range_lo.npy",
                                "range_hi.npy", "changed.npy"))
    for name in ("changed.npy", "changed_points.npy"):  # an earlier run's check: this one writes its own, if any
        (folder / WORK / name).unlink(missing_ok=True)
    t_rectify = None
    if job.rpc is not None:  # an rpc: entry: its ROI rectified (unless done for the same inputs)
        try:
            rectify_rpc(job)
        except RiverbedError as e:
            raise RectifyError(str(e)) from None
        t_rectify = round(time.perf_counter() - t0, 4)
    pair = load_pairfile(job.pair, accept_rpc=True)
    reg = load_registration(s["registration"]) if s["registration"] else None
    H, W = job.shape if job.shape is not None else pair.image_size
    rpc = getattr(pair, "kind", None) == "rpc"
    if rpc and reg is not None:
        raise RiverbedError("registration does not apply to an RPC pair (the cloud's CRS places it)", job.pair)
    sparse, counts, used, empty = None, {"points_read": 0, "kept": 0, "crs": None}, [], []
    for cloud in job.clouds:
        if not _cloud_may_land(cloud, pair, pair.registration if reg is None else reg, (H, W), s["lidar_crs"]):
            empty.append(cloud)
            continue
        try:
            sp, st = project_cloud(cloud, pair, registration=reg, classes=s["classes"],
                                   drop_classes=s["drop_classes"], outliers=s["outliers"], side=s["side"],
                                   visibility=s["visibility"], footprint=s["footprint"], crs=s["lidar_crs"],
                                   shape=(H, W))
        except RiverbedError as e:
            if len(job.clouds) > 1 and any(m in str(e) for m in _EMPTY_CLOUD):
                empty.append(cloud)
                continue
            raise
        used.append(cloud)
        for k in ("points_read", "kept"):
            counts[k] += st[k]
        counts["crs"] = counts["crs"] or st.get("crs")
        sparse = sp if sparse is None else np.fmax(sparse, sp)  # the nearer point has the larger disparity
    if sparse is None and job.clouds:
        raise RiverbedError(f"no cloud has points in the pair's images ({len(job.clouds)} checked)", job.pair)
    p = pair_params(s, lidar=sparse is not None)
    srcs = [_image_source(getattr(pair, side), (H, W), s["max_pixels"]) for side in ("left", "right")]
    points, offset, check = None, None, None
    if sparse is None:  # no cloud: the images alone, over the pair's range
        d_min, d_max = _range_without_lidar(s, pair, job.pair, W)
        (folder / "sparse.tif").unlink(missing_ok=True)  # an earlier run's, with a cloud the manifest has no more
    else:
        lidar = _lidar_stage(s, p, srcs, sparse, folder)
        d_min, d_max, offset, check, sparse, points = (lidar.d_min, lidar.d_max, lidar.offset, lidar.check,
                                                       lidar.sparse, lidar.points)
        tags = {"riverbed_pair": job.pair, "riverbed_clouds": json.dumps(used), "riverbed_block_pair": job.name,
                "riverbed_lidar_offset": json.dumps(offset.to_dict())}
        write_disparity(folder / "sparse.tif", sparse, overwrite=True, tags=tags)

    rmap, dsm_stats = None, {}
    if job.range_map:
        d_min, d_max, rmap = _pair_range_map(job.range_map, (H, W), d_min, d_max, s, folder / WORK)
    elif s["range_dsm"]:
        lo, hi, dsm_stats = _dsm_ranges(s, pair, reg, (H, W))
        d_min, d_max, rmap = _pair_ranges(lo, hi, (H, W), d_min, d_max, s, folder / WORK, s["range_dsm"])
        del lo, hi
    # the matching plan, as match_tiled makes it
    plan = plan_match((H, W), points, d_min, d_max, p, sparse=sparse, tile=s["tile"], overlap=s["overlap"],
                      lidar_range=s["lidar_range"], scan=rmap)
    bits = None
    if plan.tiled:
        bits = image_bits(*srcs)
        work = folder / WORK
        work.mkdir(exist_ok=True)
        for side, src in zip(("left", "right"), srcs):
            _save_npy(src, work / f"{side}.npy")
        # the images' valid areas (a rectified frame's alpha), read once here as the images are
        for side, path in zip(("left", "right"), (pair.left, pair.right)):
            valid = valid_area_source(path)
            if valid is not None:
                _save_npy(valid, work / f"{side}_valid.npy")
    stats = {"clouds": len(used), "clouds_without_points": len(empty), "lidar_points_read": counts["points_read"],
             "lidar_points_kept": counts["kept"], "lidar_share": plan.share_all, "lidar_crs": counts["crs"],
             "tile": plan.tile if plan.tiled else None,
             **({"lidar_offset": offset.to_dict()} if offset is not None else {}),
             **({"lidar_check": check.report.to_dict()} if check is not None else {}), **dsm_stats}
    return PairPlan(plan, bits, stats, [H, W], rmap is not None, t_rectify, round(time.perf_counter() - t0, 4))


def pair_params(s, lidar=True):
    """The pair's :class:`~riverbed_cli.matching.config.MatchConfig`; without LiDAR, unguided (as ``riverbed match``
    without ``--sparse``)."""
    p = match_params(s)
    return p if lidar else p.replace(guide="none")


def _range_without_lidar(s, pair, path, width):
    # a pair without a cloud searches min_disp..max_disp, or its pair file's range (rectify's tie points, an RPC
    # pair's heights)
    d_min, d_max = s["min_disp"], s["max_disp"]
    if d_min is None or d_max is None:
        if pair.disparity is None:
            raise RiverbedError("no cloud and no disparity range: give the pair a cloud, min_disp and max_disp, or a "
                                "pair file with its range (riverbed rectify writes one)", path)
        d_min = math.floor(pair.disparity[0]) if d_min is None else d_min
        d_max = math.ceil(pair.disparity[1]) if d_max is None else d_max
    return resolve_disparity_range(d_min, d_max, None, width=width)


def _lidar_stage(s, p, srcs, sparse, folder):
    # The LiDAR's offset against the images, once for the pair (as match_tiled does for its tiles): sparse.tif holds
    # the corrected LiDAR, and the matching tasks take it as it is; then the LiDAR check, once for the pair too:
    # sparse.tif holds the points kept, .work/changed.npy the changed area
    lidar = prepare_lidar_whole(*srcs, sparse, sparse_points_any(sparse), s["min_disp"], s["max_disp"], p)
    check = lidar.check
    if check is not None and check.changed is not None:  # the changed area for the tiles, its points for the change map
        (folder / WORK).mkdir(exist_ok=True)
        _save_npy(check.changed, folder / WORK / "changed.npy")
        rr, cc = np.nonzero(check.dropped == 2)
        np.save(folder / WORK / "changed_points.npy",
                np.stack([rr, cc, lidar.corrected[rr, cc]], axis=1).astype(np.float64))
    return lidar


def _pair_range_map(path, shape, d_min, d_max, s, work):
    # The pair's range map (riverbed match --range-map), read by windows: no stage holds the whole map
    return _pair_ranges(*open_range_map(path), shape, d_min, d_max, s, work, path)


def _dsm_ranges(s, pair, reg, shape):
    # The pair's ranges from the range_dsm setting, as `riverbed project DSM` and `riverbed range-map --window auto
    # --margin range_dsm_margin` make them: the DSM's cells projected as the pair's clouds are, each pixel bounded
    # by those within their mean spacing. (lo, hi) (H, W) float32, and stats for the project stage's record.
    path = s["range_dsm"]
    sparse, st = project_cloud(path, pair, registration=reg, outliers=s["outliers"], side=s["side"],
                               visibility=s["visibility"], footprint=s["footprint"], crs=s["range_dsm_crs"],
                               shape=shape)
    try:
        window = spacing_window(sparse)
    except RiverbedError as e:
        raise RiverbedError(f"range_dsm: {e}", path) from None
    lo, hi = ranges_from_disparity(sparse, None, window, s["range_dsm_margin"])
    return lo, hi, {"range_dsm_points": int(st["kept"]), "range_dsm_window": int(window)}


def _pair_ranges(lo, hi, shape, d_min, d_max, s, work, source):
    # The pair's per-pixel ranges (a map, or made from a DSM): checked, the pair's range widened to hold them where
    # the manifest sets none, and copied by blocks of rows to float32 work/range_{lo,hi}.npy (NaN: none) that the
    # match tasks memory-map. Errors name source.
    try:
        scan = scan_range_map((lo, hi), shape)
        if scan.known:
            d_min = min(d_min, scan.span()[0]) if s["min_disp"] is None else d_min
            d_max = max(d_max, scan.span()[1]) if s["max_disp"] is None else d_max
        scan.check(d_min, d_max)
    except RiverbedError as e:
        raise RiverbedError(str(e), source) from None
    work.mkdir(exist_ok=True)
    for name, src in (("range_lo", lo), ("range_hi", hi)):
        _save_npy(src, work / f"{name}.npy")
    return d_min, d_max, scan


def _load_range_map(folder, plan):
    # the range map project_stage kept (memory-mapped: a tile reads its crop only), or None
    if not plan.range_map:
        return None
    return tuple(np.load(folder / WORK / f"range_{end}.npy", mmap_mode="r") for end in ("lo", "hi"))


def tile_stage(job, plan, index):
    """Match tile ``index`` of a tiled pair (crops read from disk), or the whole pair when it is not tiled.

    Tiled: :func:`~riverbed_cli.scale.tiles.match_tile`, the body of ``match_tiled``'s loop
    (``test_tile_tasks_are_match_tiled`` pins the two together). Not tiled: :func:`match_pair` on the whole
    images. Returns ``{"index", "disparity" (the tile's own pixels), "evaluations", "stages", "seconds"}``.
    """
    t0 = time.perf_counter()
    s = job.settings
    # sparse.tif holds the corrected and checked LiDAR, .work/changed.npy the check's changed area (project_stage)
    lidar = bool(plan.stats["clouds"])
    p = pair_params(s, lidar).replace(lidar_offset="none", lidar_check="off")
    folder = Path(job.folder)
    H, W = plan.shape
    at = folder / WORK / "changed.npy"
    changed = np.load(at, mmap_mode="r") if at.exists() else None
    if not plan.tiled:
        pair = load_pairfile(job.pair, accept_rpc=True)
        left = read_image(pair.left, s["max_pixels"])
        right = read_image(pair.right, s["max_pixels"])
        check_pair(left, right, pair.left, pair.right)
        if left.shape[:2] != (H, W):
            raise RiverbedError(f"image is {left.shape[1]}x{left.shape[0]} but the pair file says {W}x{H} (WxH)",
                                pair.left)
        sparse = read_disparity(folder / "sparse.tif") if lidar else None
        rmap = _load_range_map(folder, plan)
        valid = tuple(read_valid_area(path) for path in (pair.left, pair.right))
        ch = None if changed is None else np.asarray(changed)
        if rmap is None:  # with LiDAR, the range it gives (as project_stage found it); without, the pair's
            d0, d1 = (s["min_disp"], s["max_disp"]) if lidar else (plan.match.d_min, plan.match.d_max)
            res = match_pair(left, right, sparse, d0, d1, params=p, valid_areas=valid, changed_area=ch)
        else:  # the pair's range, widened to hold the map
            res = match_pair(left, right, sparse, plan.match.d_min, plan.match.d_max, params=p, range_map=rmap,
                             valid_areas=valid, changed_area=ch)
        n_d = res.info["d_max"] - res.info["d_min"] + 1
        return {"index": 0, "disparity": res.disparity, "evaluations": H * W * n_d, "stages": res.info["stages"],
                "seconds": round(time.perf_counter() - t0, 4)}
    p = p.replace(window=plan.match.window)
    tile = Tile(*plan.match.tiles[index])
    left = np.load(folder / WORK / "left.npy", mmap_mode="r")
    right = np.load(folder / WORK / "right.npy", mmap_mode="r")
    sparse = WindowedRaster(folder / "sparse.tif", "disparity") if lidar else None
    # the pair's LiDAR share and range: every tile takes the whole pair's tubes, as match_tiled does
    valid = tuple(np.load(f, mmap_mode="r") if f.exists() else None
                  for f in (folder / WORK / f"{side}_valid.npy" for side in ("left", "right")))
    disp, n, stages, _ = match_tile(left, right, sparse, tile, s["overlap"], p, plan.bits, plan.match.share_all,
                                    (plan.match.d_min, plan.match.d_max),
                                    _load_range_map(folder, plan), valid_areas=valid, changed=changed)
    return {"index": index, "disparity": disp, "evaluations": n, "stages": stages,
            "seconds": round(time.perf_counter() - t0, 4)}


def n_tasks(plan):
    """Number of matching tasks a projected pair needs (its tiles, or one)."""
    return len(plan.match.tiles) if plan.tiled else 1


def finish_stage(job, plan, tiles):
    """Stitch the tiles, triangulate, write ``disparity.tif``, ``points.laz``, ``dsm.tif`` and, last, ``done.json``.

    Returns the pair's summary (``points``, ``resolution``, ``crs``, per-stage ``seconds``).
    """
    t0 = time.perf_counter()
    s = job.settings
    folder = Path(job.folder)
    clean_temps(folder, (*OUTPUTS, DONE))
    (folder / "change.tif").unlink(missing_ok=True)  # a previous run's: this one writes its own, if any
    H, W = plan.shape
    tiled = plan.tiled
    if tiled:
        disp = np.full((H, W), np.nan, np.float32)
        for t in tiles:
            y0, y1, x0, x1 = plan.match.tiles[t["index"]][:4]
            disp[y0:y1, x0:x1] = t["disparity"]
    else:
        disp = tiles[0]["disparity"]
    stages = {}
    for t in tiles:
        for k, v in t["stages"].items():
            stages[k] = round(stages.get(k, 0.0) + v, 4)
    info = {"tiles": len(tiles) if tiled else 0,
            "disparity_evaluations": int(sum(t["evaluations"] for t in tiles)), "stages": stages}
    write_disparity(folder / "disparity.tif", disp, overwrite=True,
                    tags={"riverbed_guide": s["guide"], "riverbed_block_pair": job.name,
                          "riverbed_tiles": info["tiles"]})
    pair = load_pairfile(job.pair, accept_rpc=True)
    work = folder / WORK
    if tiled:
        image = np.load(work / "left.npy", mmap_mode="r")
    else:
        image = read_image(pair.left, s["max_pixels"])
    rpc = getattr(pair, "kind", None) == "rpc"
    if rpc:  # two RPC rays intersected: points in the block's crs, default the scene's UTM zone; heights ellipsoidal
        pair.crs = crs = output_crs(pair, s["crs"], option="crs")
    else:
        crs = s["crs"] or pair.crs or plan.stats["lidar_crs"]
    # triangulated once, the points kept for points.laz: riverbed dsm's DSM of the pair
    result = build_dsm([(disp, pair, image)], resolution=s["resolution"], agg=s["agg"], keep_points=True)
    del image
    changes, change_out = None, None
    if (work / "changed_points.npy").exists():  # where the surface left the LiDAR's: the pair's change map
        changes, change_out = [_changed(disp, np.load(work / "changed_points.npy"), pair)], folder / "change.tif"
    change_stats = write_dsm_outputs(result, crs, folder / "dsm.tif", points=folder / "points.laz", changes=changes,
                                     change_out=change_out, overwrite=True,
                                     tags={"riverbed_aggregation": s["agg"], "riverbed_block_pair": job.name,
                                           **({"riverbed_heights": RPC_HEIGHTS} if rpc else {})})
    if change_stats is not None:
        change_stats.pop("lidar_offset_px", None)
    grid, xyz = result.grid, result.points[0]
    t_match = sum(t["seconds"] for t in tiles)
    seconds = {"project": plan.seconds, "match": round(t_match, 4), "dsm": round(time.perf_counter() - t0, 4)}
    if plan.rectify_seconds is not None:  # included in "project"
        seconds["rectify"] = plan.rectify_seconds
    summary = {"points": len(xyz), "resolution": grid.resolution, "crs": crs,
               **({"heights": RPC_HEIGHTS, "roi": list(pair.roi)} if rpc else {}),
               "bounds": list(grid.bounds), **plan.stats, **info, "d_min": plan.match.d_min,
               "d_max": plan.match.d_max, **({"change_map": change_stats} if change_stats else {}), "seconds": seconds}
    outputs = {name: {"size": (folder / name).stat().st_size, "sha256": sha256_file(folder / name)}
               for name in OUTPUTS if name != LIDAR_OUTPUT or plan.stats["clouds"]}
    record = {"name": job.name, "pair": job.pair, "clouds": job.clouds, "settings_hash": job.settings_hash,
              "settings": s, "inputs": job.inputs, "outputs": outputs, "stats": summary,
              "riverbed": riverbed_version(), "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
    write_json(folder / DONE, record)
    shutil.rmtree(work, ignore_errors=True)
    return summary


def _changed(disp, points, pair):
    # the pair's change_map input from the points its LiDAR check dropped in changed regions (rows, cols,
    # disparities of the corrected LiDAR)
    rr, cc = points[:, 0].astype(np.intp), points[:, 1].astype(np.intp)
    then = np.full(disp.shape, np.nan, np.float32)
    then[rr, cc] = points[:, 2]
    mask = np.zeros(disp.shape, np.uint8)
    mask[rr, cc] = CHANGED_POINT
    return disp, then, mask, pair


def run_pair(job, progress=None):
    """The whole pair in this process, stage after stage (what the dask tasks do); returns the summary dict.

    Raises :class:`RiverbedError` on bad input.
    """
    plan = project_stage(job)
    tiles = []
    for i in range(n_tasks(plan)):
        tiles.append(tile_stage(job, plan, i))
        if progress:
            progress("tile", job.name)
    return finish_stage(job, plan, tiles)
