"""Ground <-> rectified pixels of an RPC pair: LiDAR -> sparse disparities, disparities -> ground (docs/rpc.md).

- :func:`project_points_rpc`: ground (WGS 84 lon, lat, ellipsoidal h) -> left rectified ``(x, y)`` and
  ``d = x_left - x_right`` through both RPCs and the rectification affinities (:meth:`RPCPair.project`).
- :func:`triangulate_rpc`: left rectified pixel + disparity -> ground, by intersecting the two RPC rays: the
  affinities undone to the raw pixels of both input images, then Gauss-Newton on ``(lon, lat, h)`` minimising the
  reprojection error in both images (float64, vectorised, at most :data:`TRI_MAX_ITER` iterations, a step test in
  metres); the residual is returned.
- :func:`project_cloud_rpc`: what ``riverbed project`` runs on an RPC pair file. The cloud's CRS -> WGS 84
  lon/lat/ellipsoidal h through pyproj (:func:`cloud_to_wgs84`), then the pinhole pipeline's steps
  (:mod:`riverbed_cli.geometry.projection`) fed with the projected pixels: a two-layer z-buffer per left pixel
  whose depth key is the height (higher = nearer to a satellite looking down), statistical outlier removal in a
  metric frame (the scene's UTM zone, neighbours searched in the image, the ground sample distance as the pixel
  angle), the z-buffer visibility test in the left and right rectified images, ``d`` at the rounded left pixel.
- :func:`rpc_disparity_points`: what ``riverbed dsm`` triangulates for an RPC pair: points in the pair's output
  CRS (:attr:`RPCPair.crs`, default the UTM zone of the scene, :func:`scene_utm`), heights ellipsoidal.
"""

import math
import time

import numpy as np
from pyproj import CRS, Transformer
from pyproj.exceptions import CRSError

from ..errors import RiverbedError
from ..io.lidar import class_mask, iter_lidar, lidar_info, resolve_crs
from . import visibility as vis
from .coverage import lidar_share
from .outliers import SOR_K, SOR_SIGMA, layer_winners, sor_inliers_image
from .rpc_dem import geoid_to_ellipsoid_transformer
from .rpc_rectify import apply_h

#: Gauss-Newton iterations of :func:`triangulate_rpc` at most, and the step (m) under which a point has converged.
TRI_MAX_ITER = 10
TRI_TOL_M = 1e-6
#: Forward-difference steps of the Jacobian: degrees of longitude/latitude, metres of height.
_STEP_DEG = 1e-6
_STEP_H = 0.1
_M_PER_DEG = 111_319.49
#: A point whose right-image row is this far (px) from its left one is dropped (as for pinhole pairs).
MAX_ROW_OFFSET = 1.0
#: The visibility tests that need only the rectified images (surface and HPR need a camera centre).
RPC_VISIBILITY = ("zbuffer", "none")


# ---------------------------------------------------------------------------------------------------------------
# coordinate systems


def cloud_to_wgs84(crs, path=None):
    """A function ``(x, y, z) -> (lon, lat, h)``: a cloud's coordinates to WGS 84 degrees and ellipsoidal metres.

    A 3D CRS (geographic or projected, ellipsoidal heights) goes through one pyproj transformation to EPSG:4979;
    a compound CRS (e.g. ``EPSG:32631+5773``, UTM + EGM96 heights) through its horizontal part to EPSG:4326, then
    its vertical datum to the ellipsoid as :func:`~riverbed_cli.geometry.rpc_dem.read_dem` does (PROJ's geoid grid
    needed, never the "ballpark" null transformation). A cloud without CRS, or with a 2D CRS (which says nothing
    of its heights), is a one-line :class:`RiverbedError` naming ``path``.
    """
    if crs is None:
        raise RiverbedError("the cloud states no CRS: give --crs with its heights' datum (e.g. EPSG:32631+5773 for "
                            "UTM 31N + EGM96, or a 3D CRS for ellipsoidal heights)", path)
    crs = CRS.from_user_input(crs)
    if crs.is_compound:
        horizontal, vertical = crs.sub_crs_list[0], crs.sub_crs_list[1]
        to_ll = Transformer.from_crs(horizontal, "EPSG:4326", always_xy=True)
        epsg = vertical.to_epsg()
        if epsg is None:
            raise RiverbedError(f"the cloud's vertical CRS ({vertical.name}) has no EPSG code", path)
        to_h = geoid_to_ellipsoid_transformer(f"EPSG:{epsg}", path)

        def convert(x, y, z):
            lon, lat = to_ll.transform(x, y)
            _, _, h = to_h.transform(lon, lat, z)
            return np.asarray(lon), np.asarray(lat), np.asarray(h)
        return convert
    if len(crs.axis_info) == 3 and (crs.is_geographic or crs.is_projected):
        tr = Transformer.from_crs(crs, "EPSG:4979", always_xy=True)

        def convert(x, y, z):
            return tuple(np.asarray(v) for v in tr.transform(x, y, z))
        return convert
    raise RiverbedError(f"the cloud's CRS ({crs.name}) is 2D: its heights' datum is unknown; give --crs with a "
                        f"vertical part (e.g. EPSG:{crs.to_epsg() or 'XXXX'}+5773 for EGM96 heights) or a 3D CRS",
                        path)


def scene_centre(pair):
    """``(lon, lat, h)`` of the rectified left image's centre at the middle of the height range (degrees, m)."""
    h = 0.5 * (pair.heights[0] + pair.heights[1])
    x, y = apply_h(np.linalg.inv(pair.rectification.H_left), (pair.width - 1) / 2, (pair.height - 1) / 2)
    lon, lat = pair.rpc_left.localize(x, y, h)
    return float(lon), float(lat), h


def scene_utm(pair):
    """The UTM zone of the scene's centre, as ``"EPSG:326ZZ"`` (north) or ``"EPSG:327ZZ"`` (south)."""
    lon, lat, _ = scene_centre(pair)
    zone = int(math.floor((lon + 180.0) / 6.0)) % 60 + 1
    return f"EPSG:{32600 + zone if lat >= 0 else 32700 + zone}"


def output_crs(pair, crs=None, option="--crs"):
    """The CRS the triangulated points of an RPC pair are written in: ``crs`` or :func:`scene_utm`.

    A CRS pyproj does not know, or that is not projected (a DSM's cells are metres), is a one-line
    :class:`RiverbedError` (``--crs: ...``; ``option`` names the setting: ``crs`` in a block manifest).
    """
    if crs is None:
        return scene_utm(pair)
    try:
        parsed = CRS.from_user_input(crs)
    except (CRSError, TypeError, ValueError):
        raise RiverbedError(f"{option}: unknown CRS '{crs}'") from None
    if not parsed.is_projected:
        raise RiverbedError(f"{option}: {parsed.name} is not a projected CRS (an RPC pair's DSM is gridded in "
                            "metres)")
    return crs


def ground_sample_distance(pair):
    """Metres of ground per rectified left pixel at the scene's centre (mean of the two axes)."""
    lon, lat, h = scene_centre(pair)
    x, y, _ = project_points_rpc(pair, lon, lat, h)
    inv = np.linalg.inv(pair.rectification.H_left)
    c, r = apply_h(inv, np.array([x, x + 1.0, x]), np.array([y, y, y + 1.0]))
    lo, la = pair.rpc_left.localize(c, r, h)
    east = (lo - lo[0]) * _M_PER_DEG * math.cos(math.radians(lat))
    north = (la - la[0]) * _M_PER_DEG
    return float(0.5 * (math.hypot(east[1], north[1]) + math.hypot(east[2], north[2])))


# ---------------------------------------------------------------------------------------------------------------
# projection and triangulation


def project_points_rpc(pair, lon, lat, h):
    """Ground -> left rectified pixel and disparity: ``(x, y, d)`` with ``d = x_left - x_right`` (px, float64).

    Parameters
    ----------
    pair : RPCPair
    lon, lat : array_like
        WGS 84 longitude and latitude (degrees).
    h : array_like
        Height above the WGS 84 ellipsoid (m).
    """
    xl, yl, xr, _ = pair.project(lon, lat, h)
    return xl, yl, xl - xr


def triangulate_rpc(pair, x, y, d, max_iter=TRI_MAX_ITER, tol_m=TRI_TOL_M):
    """Left rectified pixel + disparity -> ground, where the two RPC rays meet (least squares, float64).

    The rectification is undone to raw pixels of both input images (left ``H_left^-1 (x, y)``, right
    ``H_right^-1 (x - d, y)``), then Gauss-Newton on ``(lon, lat, h)`` minimises the four reprojection errors
    (forward-difference Jacobian), from the left ray at the middle of the pair's height range; points whose step
    is still above ``tol_m`` after ``max_iter`` iterations, or that leave the models' domain, come back NaN.

    Parameters
    ----------
    pair : RPCPair
    x, y : array_like
        Left rectified pixel (px, pixel centres at integers).
    d : array_like
        Disparity ``x_left - x_right`` (px).
    max_iter : int
    tol_m : float
        Convergence: the last step's length (m).

    Returns
    -------
    lon, lat, h : ndarray
        WGS 84 degrees, ellipsoidal metres.
    residual : ndarray
        Reprojection residual (px): the root of the summed squared errors in both raw images.
    """
    x, y, d = np.broadcast_arrays(*(np.asarray(v, np.float64) for v in (x, y, d)))
    shape = x.shape
    x, y, d = x.ravel(), y.ravel(), d.ravel()
    rect = pair.rectification
    cl, rl = apply_h(np.linalg.inv(rect.H_left), x, y)
    cr, rr = apply_h(np.linalg.inv(rect.H_right), x - d, y)
    obs = np.stack([cl, rl, cr, rr], axis=1)
    h = np.full(x.shape, 0.5 * (pair.heights[0] + pair.heights[1]))
    lon, lat = pair.rpc_left.localize(cl, rl, h)
    ground = np.stack([lon, lat, h], axis=1)
    steps = np.array([_STEP_DEG, _STEP_DEG, _STEP_H])

    def residual(g, idx=slice(None)):
        a = pair.rpc_left.project(g[:, 0], g[:, 1], g[:, 2])
        b = pair.rpc_right.project(g[:, 0], g[:, 1], g[:, 2])
        return np.stack([a[0], a[1], b[0], b[1]], axis=1) - obs[idx]

    done = ~np.isfinite(ground).all(axis=1)
    ground[done] = np.nan
    for _ in range(max_iter):
        todo = np.flatnonzero(~done)
        if todo.size == 0:
            break
        g = ground[todo]
        r = residual(g, todo)
        J = np.empty((todo.size, 4, 3))
        for k in range(3):
            gk = g.copy()
            gk[:, k] += steps[k]
            J[:, :, k] = (residual(gk, todo) - r) / steps[k]
        JT = np.transpose(J, (0, 2, 1))
        with np.errstate(all="ignore"):
            delta = np.linalg.solve(JT @ J, (JT @ r[:, :, None]))[:, :, 0]
        ground[todo] -= delta
        coslat = np.cos(np.radians(g[:, 1]))
        length = np.sqrt((delta[:, 0] * _M_PER_DEG * coslat) ** 2 + (delta[:, 1] * _M_PER_DEG) ** 2
                         + delta[:, 2] ** 2)
        conv = length < tol_m
        bad = ~np.isfinite(length)
        done[todo[conv | bad]] = True
        ground[todo[bad]] = np.nan
    ground[~done] = np.nan
    res = np.sqrt(np.sum(residual(ground) ** 2, axis=1))
    return (ground[:, 0].reshape(shape), ground[:, 1].reshape(shape), ground[:, 2].reshape(shape),
            res.reshape(shape))


def rpc_disparity_points(disp, pair, rows=None, image=None, confidence=None, min_confidence=None):
    """:func:`riverbed_cli.products.dsm.disparity_points` for an RPC pair: points in the pair's output CRS.

    Every valid disparity is triangulated (:func:`triangulate_rpc`) and converted to ``pair.crs`` (default:
    :func:`scene_utm`) by pyproj; heights stay ellipsoidal (m). Points that do not converge are NaN (dropped by the
    DSM). The second value is the ground sample distance (m per pixel) at each point, which
    :func:`~riverbed_cli.products.dsm.default_resolution` takes with a focal of 1.
    """
    rows = rows or slice(0, disp.shape[0])
    block = np.asarray(disp[rows], np.float64)
    valid = np.isfinite(block)
    if confidence is not None and min_confidence is not None:
        valid &= np.asarray(confidence[rows]) >= min_confidence
    r, c = np.nonzero(valid)
    r_img = r + (rows.start or 0)
    lon, lat, h, _ = triangulate_rpc(pair, c.astype(np.float64), r_img.astype(np.float64), block[r, c])
    tr = Transformer.from_crs("EPSG:4326", pair.crs or scene_utm(pair), always_xy=True)
    e, n = tr.transform(lon, lat)
    xyz = np.stack([np.asarray(e, np.float64), np.asarray(n, np.float64), h], axis=1)
    gsd = np.full(len(xyz), ground_sample_distance(pair) if len(xyz) else 0.0)
    rgb = None
    if image is not None:
        img = image[r_img, c]
        rgb = np.repeat(img[:, None], 3, axis=1) if img.ndim == 1 else img[:, :3]
    return xyz, gsd, rgb


# ---------------------------------------------------------------------------------------------------------------
# riverbed project on an RPC pair


def _two_highest(cand):
    """Per pixel the two highest candidates (a two-layer z-buffer, depth key ``-h``): ``(kept, rank)``."""
    order = np.lexsort((-cand["h"], cand["pix"]))
    pix = cand["pix"][order]
    first = np.r_[True, pix[1:] != pix[:-1]]
    start = np.maximum.accumulate(np.where(first, np.arange(pix.size), 0))
    rank = np.arange(pix.size) - start
    keep = rank < 2
    return {k: v[order][keep] for k, v in cand.items()}, rank[keep]


def project_cloud_rpc(cloud_path, pair, classes=None, drop_classes=(7, 18), outliers="sor", side="both",
                      visibility="zbuffer", footprint=vis.ZBUFFER_RADIUS, tolerance=vis.ZBUFFER_TOLERANCE,
                      slope=vis.ZBUFFER_SLOPE, crs=None, shape=None, chunk_size=1_000_000, progress=None,
                      edge_reach=vis.ZBUFFER_EDGE_REACH):
    """:func:`riverbed_cli.geometry.projection.project_cloud` for an RPC pair (the module docstring: the steps).

    The cloud's coordinates go to WGS 84 through :func:`cloud_to_wgs84` (its CRS from the file's VLRs, or
    ``crs``); ``visibility`` must be ``zbuffer`` or ``none`` (surface and HPR need a camera centre). Returns
    ``(sparse, stats)`` as the pinhole function does (``behind_camera`` is always 0; ``row_offset_px``: the
    right-image row minus the left one at the kept points, the rectification's affine error), ``stats`` a dict
    of :class:`~riverbed_cli.geometry.projection.ProjectionStats`'s fields (``project_cloud`` makes it one).
    """
    t0 = time.perf_counter()
    if visibility not in RPC_VISIBILITY:
        raise RiverbedError(f"visibility '{visibility}' needs a camera centre: an RPC pair takes "
                            f"{' or '.join(RPC_VISIBILITY)}")
    info = lidar_info(cloud_path)
    cloud_crs = resolve_crs(info, crs)
    to_wgs = cloud_to_wgs84(cloud_crs, cloud_path)
    H, W = shape if shape is not None else pair.image_size
    utm = Transformer.from_crs("EPSG:4326", scene_utm(pair), always_xy=True)
    cand = None
    n_read = n_class = n_outside = 0
    for chunk in iter_lidar(cloud_path, chunk_size=chunk_size):
        xyz = np.asarray(chunk["xyz"], np.float64)
        keep = class_mask(chunk["classification"], classes, drop_classes)
        n_read += xyz.shape[0]
        n_class += int(xyz.shape[0] - keep.sum())
        lon, lat, h = to_wgs(xyz[keep, 0], xyz[keep, 1], xyz[keep, 2])
        xl, yl, xr, yr = pair.project(lon, lat, h)
        inside = (xl >= -0.5) & (xl < W - 0.5) & (yl >= -0.5) & (yl < H - 0.5)   # False for NaN
        n_outside += int(inside.size - inside.sum())
        code = np.zeros(inside.sum(), np.int8)
        xr_i, yr_i, yl_i = xr[inside], yr[inside], yl[inside]
        code[~((xr_i >= -0.5) & (xr_i < W - 0.5) & (yr_i >= -0.5) & (yr_i < H - 0.5))] = 2
        code[(code == 0) & (np.abs(yr_i - yl_i) > MAX_ROW_OFFSET)] = 3
        e, n = utm.transform(lon[inside], lat[inside])
        new = {"pix": np.floor(yl_i + 0.5).astype(np.int64) * W + np.floor(xl[inside] + 0.5).astype(np.int64),
               "h": h[inside], "xl": xl[inside], "yl": yl_i, "xr": xr_i, "yr": yr_i, "code": code,
               "e": np.asarray(e, np.float64), "n": np.asarray(n, np.float64)}
        cand = new if cand is None else {k: np.concatenate([cand[k], new[k]]) for k in new}
        cand, _ = _two_highest(cand)
        if progress is not None:
            progress(xyz.shape[0])
    n_inside = n_read - n_class - n_outside
    if cand is None or cand["pix"].size == 0:
        raise RiverbedError(f"no point lands in both images ({n_read} read: {n_class} filtered by class, 0 behind a "
                            f"camera, {n_outside} outside the {W}x{H} images, 0 off the row, 0 outliers)", cloud_path)
    cand, rank = _two_highest(cand)
    n_cand = cand["pix"].size
    same_pixel = n_inside - n_cand
    t_stream = time.perf_counter()

    slot = np.arange(n_cand)
    first = rank == 0
    idx0 = np.full(H * W, -1, np.int32)
    idx1 = np.full(H * W, -1, np.int32)
    idx0[cand["pix"][first]] = slot[first]
    idx1[cand["pix"][~first]] = slot[~first]
    inlier = np.ones(n_cand, bool)
    if outliers == "sor":
        centre = np.array([cand["e"].mean(), cand["n"].mean(), cand["h"].mean()])
        metric = np.ascontiguousarray(np.stack([cand["e"], cand["n"], cand["h"]], axis=1) - centre)
        inlier = sor_inliers_image(slot, cand["pix"], idx0, idx1, (H, W), metric, np.ones(n_cand),
                                   1.0 / ground_sample_distance(pair), SOR_K, SOR_SIGMA)
    n_outliers = int(n_cand - inlier.sum())
    t_sor = time.perf_counter()
    # the highest inlier of each pixel wins; the second layer takes its pixel back from an outlier
    s0 = slot[first]
    win, taken_back = layer_winners(s0, inlier, idx1, cand["pix"][s0])
    same_pixel += int(inlier[slot[~first]].sum()) - taken_back
    w = {k: v[win] for k, v in cand.items()}
    code = w["code"]
    n_outside += int((code == 2).sum())
    n_row = int((code == 3).sum())
    usable = code == 0
    if not usable.any():
        raise RiverbedError(
            f"no point lands in both images ({n_read} read: {n_class} filtered by class, 0 behind a camera, "
            f"{n_outside} outside the {W}x{H} images, {n_row} off the row, {n_outliers} outliers)", cloud_path)
    rows, cols = w["pix"] // W, w["pix"] % W
    d = w["xl"] - w["xr"]
    def visible_at(r, c, m, view):
        return vis.zbuffer_visible(r, c, d[m], (H, W), footprint, tolerance, slope, edge_reach)

    visible, n_occ_left, n_occ_right = vis.visible_in_both(usable, rows, cols, w["xr"], w["yr"], code, side,
                                                           visible_at if visibility == "zbuffer" else None)
    t_vis = time.perf_counter()

    sparse = np.full((H, W), np.nan, np.float32)
    sparse[rows[visible], cols[visible]] = d[visible].astype(np.float32)
    kept = int(visible.sum())
    dv = d[visible]
    stats = dict(
        points_read=n_read, filtered={"class": n_class, "outliers": n_outliers}, behind_camera=0,
        outside=n_outside, row_offset=n_row,
        occluded={"same_pixel": same_pixel, "left": n_occ_left, "right": n_occ_right}, kept=kept,
        lidar_share=lidar_share(sparse), d_range=[float(dv.min()), float(dv.max())] if kept else None, size=[W, H])
    if kept:
        dy = np.abs(w["yr"] - w["yl"])[visible]
        stats["row_offset_px"] = {"median": float(np.median(dy)), "max": float(dy.max())}
    stats["crs"] = cloud_crs.to_string()
    t_end = time.perf_counter()
    stats["seconds"] = t_end - t0
    stats["stage_seconds"] = {"stream": t_stream - t0, "outliers": t_sor - t_stream, "visibility": t_vis - t_sor,
                           "share": t_end - t_vis}
    total = n_class + n_outliers + n_outside + n_row + same_pixel + n_occ_left + n_occ_right + kept
    assert total == n_read, (total, n_read)
    if kept == 0:
        raise RiverbedError(f"no point is left after outlier and hidden point removal ({n_read} read)", cloud_path)
    return sparse, stats

