"""Project a LiDAR point cloud into a rectified pair: the sparse disparities that ``match --sparse`` takes.

:func:`project_cloud` streams the cloud in chunks (:func:`riverbed_cli.io.lidar.iter_lidar`), so its memory is
bounded by the image size, not the cloud size:

1. class filter (default: drop ASPRS noise classes 7 and 18);
2. per point, in float64 (one Numba pass): LiDAR -> world by the registration, minus the pair's origin,
   project into both cameras; drop points behind the left camera or outside the left image (``round(x)``,
   ``round(y)`` off the ``W x H`` grid);
3. keep per left pixel the two nearest points (a two-layer z-buffer holding the points' coordinates): the
   second layer lets a true surface point take its pixel back when the nearer point turns out to be an
   outlier. Points behind the right camera, outside the right image or, for a pair whose right camera is
   slightly off the baseline (KITTI), whose right-image row is more than 1 px off, take part too (they still
   hide what is behind them in the left view) and are dropped at the end;
4. after the last chunk, statistical outlier removal (:mod:`~riverbed_cli.geometry.outliers`) on the kept
   candidates (at most two per pixel, neighbours from all chunks), then the nearest surviving point per pixel;
5. hidden point removal (:mod:`~riverbed_cli.geometry.visibility`) from the left camera and, with the same
   test, from the right camera (``side``);
6. ``d = x_left - x_right`` at ``(round(y_left), round(x_left))``.

Every point read is counted exactly once: filtered by class, behind a camera, outside the images, off the row
(``row_offset``), beaten by a nearer point in its pixel (``same_pixel``), an outlier, occluded in the left or
in the right view, or kept.
"""

import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np
from pyproj import CRS
from pyproj.exceptions import CRSError

from ..errors import RiverbedError
from ..io.images import read_image
from ..io.lidar import class_mask, iter_lidar, lidar_info, resolve_crs
from ..records import RecordMapping
from . import visibility as vis
from ..runtime.kernel import kernel
from .cameras import as_matrix, check_registration
from .coverage import lidar_share
from .outliers import SOR_K, SOR_SIGMA, layer_winners, sor_inliers_image
from .rpc_dem import height_transformer
from .rpc_geometry import project_cloud_rpc, triangulate_rpc

log = logging.getLogger(__name__)

VISIBILITY = ("zbuffer", "surface", "surface+zbuffer", "hpr", "none")
SIDES = ("left", "right", "both")
OUTLIERS = ("sor", "none")
#: Default ASPRS classes dropped: 7 (low noise) and 18 (high noise, LAS 1.4).
NOISE_CLASSES = (7, 18)
#: A point whose right-image row is this far (px) from its left-image row is dropped (pairs off the baseline).
MAX_ROW_OFFSET = 1.0
#: Most slots allocated at first (at most the header's point count or two per pixel; then grown by doubling).
#: ``np.empty`` does not touch the pages, so an allocation larger than what is used costs no memory.
_INITIAL_SLOTS = 1 << 26


@dataclass
class ProjectionStats(RecordMapping):
    """What :func:`project_cloud` did with the points (counts add up to ``points_read``).

    ``filtered``: dropped by class and as outliers; ``behind_camera``, ``outside`` (of either image),
    ``row_offset`` (right-image row too far from the left one's); ``occluded``: a nearer point on the same pixel,
    hidden in the left or right image; ``kept``: pixels with a disparity. ``lidar_share``: their share of the
    image (:func:`~riverbed_cli.geometry.coverage.lidar_share`); ``window``: the riverbed window that share gives,
    set by callers that match (None here); ``d_range``: [min, max] disparity (px); ``size``: [width, height];
    ``row_offset_px``: median and max row offset at the kept points, for pairs not exactly rectified; ``crs``;
    ``heights_converted`` (``from``, ``to``: the vertical datums) when the cloud's heights were converted to the
    pair's; ``seconds`` and ``stage_seconds``.
    """

    points_read: int
    filtered: dict
    behind_camera: int
    outside: int
    row_offset: int
    occluded: dict
    kept: int
    lidar_share: float
    window: int = None
    d_range: list = None
    size: list = None
    row_offset_px: dict = None
    crs: str = None
    heights_converted: dict = None
    seconds: float = 0.0
    stage_seconds: dict = field(default_factory=dict)

    _optional = ("row_offset_px", "heights_converted")


@kernel
def _project_chunk(xyz, keep, A, PL, PR, sl, sr, width, height, max_dy, idx0, idx1, store_xyz, store_z,
                   store_pix, store_code, n_used, start, counts):
    """Project points ``start..`` of a chunk and insert them into the two-layer z-buffer of the left image.

    ``A`` (3 x 4) maps LiDAR coordinates to world minus origin. ``idx0``/``idx1`` (H*W int32): slot of the
    nearest / second-nearest point of each pixel (-1: none). Slots hold world-minus-origin coordinates, depth,
    pixel and a code: 0 usable, 1 behind the right camera, 2 outside the right image, 3 right row off by more
    than ``max_dy``. Coded points stay in the z-buffer (they still hide what is behind them in the left view)
    and are dropped at the end. ``counts``: points behind the left camera, outside the left image. Returns
    ``(next_point, n_used)``; ``next_point < len(xyz)`` means the slot store is full (grow it and call again).
    """
    cap = store_z.shape[0]
    n = xyz.shape[0]
    for i in range(start, n):
        if not keep[i]:
            continue
        px = xyz[i, 0]
        py = xyz[i, 1]
        pz = xyz[i, 2]
        x = A[0, 0] * px + A[0, 1] * py + A[0, 2] * pz + A[0, 3]
        y = A[1, 0] * px + A[1, 1] * py + A[1, 2] * pz + A[1, 3]
        z = A[2, 0] * px + A[2, 1] * py + A[2, 2] * pz + A[2, 3]
        wl = PL[2, 0] * x + PL[2, 1] * y + PL[2, 2] * z + PL[2, 3]
        depth = wl * sl
        if not depth > 0.0:
            counts[0] += 1
            continue
        xl = (PL[0, 0] * x + PL[0, 1] * y + PL[0, 2] * z + PL[0, 3]) / wl
        yl = (PL[1, 0] * x + PL[1, 1] * y + PL[1, 2] * z + PL[1, 3]) / wl
        if not (-0.5 <= xl < width - 0.5 and -0.5 <= yl < height - 0.5):
            counts[1] += 1
            continue
        code = 0
        wr = PR[2, 0] * x + PR[2, 1] * y + PR[2, 2] * z + PR[2, 3]
        if not wr * sr > 0.0:
            code = 1
        else:
            xr = (PR[0, 0] * x + PR[0, 1] * y + PR[0, 2] * z + PR[0, 3]) / wr
            yr = (PR[1, 0] * x + PR[1, 1] * y + PR[1, 2] * z + PR[1, 3]) / wr
            if not (-0.5 <= xr < width - 0.5 and -0.5 <= yr < height - 0.5):
                code = 2
            elif abs(yr - yl) > max_dy:
                code = 3
        pix = np.int64(math.floor(yl + 0.5)) * width + np.int64(math.floor(xl + 0.5))
        a = idx0[pix]
        b = idx1[pix]
        if a >= 0 and depth >= store_z[a]:
            # Not the nearest: maybe the second nearest.
            if b >= 0:
                if depth >= store_z[b]:
                    continue
                s = b  # replaces the old second layer
            else:
                if n_used >= cap:
                    return i, n_used
                s = n_used
                n_used += 1
                idx1[pix] = s
        else:
            # The nearest so far: the old nearest becomes the second layer, the old second layer is dropped.
            if a >= 0 and b >= 0:
                s = b
            else:
                if n_used >= cap:
                    return i, n_used
                s = n_used
                n_used += 1
            if a >= 0:
                idx1[pix] = a
            idx0[pix] = s
        store_xyz[s, 0] = x
        store_xyz[s, 1] = y
        store_xyz[s, 2] = z
        store_z[s] = depth
        store_pix[s] = pix
        store_code[s] = code
    return n, n_used


def _grow(a, cap):
    out = np.empty((cap, *a.shape[1:]), a.dtype)
    out[: a.shape[0]] = a
    return out


def _check_crs(pair, cloud_crs, cloud_path):
    """Refuse a cloud whose CRS differs from the pair's horizontally (no reprojection here); return the conversion
    of its heights to the pair's vertical datum, or None. A compound CRS (horizontal + vertical, e.g. a DEM's
    projected CRS + EGM2008 heights) is compared by its horizontal part, and by its vertical part (a 3-D CRS's:
    ellipsoidal heights) only when the pair states one too: frame orientations carry no vertical datum, and their
    camera heights are then taken to be on the cloud's. Two datums that differ are converted by PROJ
    (:func:`~riverbed_cli.geometry.rpc_dem.height_transformer`: a missing geoid grid is a one-line error, never a
    silent shift of the DSM by the geoid's undulation)."""
    if pair.crs is None or cloud_crs is None:
        return None
    try:
        pair_crs = CRS.from_user_input(pair.crs)
    except CRSError:
        raise RiverbedError(f"crs: unknown CRS '{pair.crs}' in the pair file") from None
    if pair_crs.equals(cloud_crs, ignore_axis_order=True):
        return None
    (pair_h, _), (cloud_h, _) = crs_parts(pair_crs), crs_parts(cloud_crs)
    if not pair_h.equals(cloud_h, ignore_axis_order=True):
        raise RiverbedError(
            f"the cloud's CRS ({crs_label(cloud_crs)}) differs from the pair's ({crs_label(pair_crs)}); "
            "reproject the cloud, or pass --crs if the file states a wrong one", cloud_path)
    pair_v, cloud_v = vertical_datum(pair_crs), vertical_datum(cloud_crs)
    if cloud_v is not None and pair_v is None:
        log.info("%s: heights taken to be on the cloud's vertical datum (%s): the pair states none",
                 cloud_path, cloud_v)
    if pair_v is None or cloud_v is None or pair_v == cloud_v:
        return None
    heights = height_transformer(cloud_crs, pair_crs, cloud_path, what=f"{cloud_v} (the pair's: {pair_v})")
    log.info("%s: heights converted from %s to the pair's %s (PROJ: %s)", cloud_path, cloud_v, pair_v,
             heights.description)
    return HeightConversion(heights, cloud_v, pair_v)


@dataclass
class HeightConversion:
    """A cloud's heights converted to the pair's vertical datum (``source`` and ``target``: their names)."""

    transformer: object
    source: str
    target: str

    def __call__(self, xyz):
        """``xyz`` (N, 3) in the cloud's CRS with its heights on the pair's datum (in place)."""
        xyz[:, 2] = self.transformer.transform(xyz[:, 0], xyz[:, 1], xyz[:, 2])[2]
        return xyz


def vertical_datum(crs):
    """The name of a CRS's height datum: a compound CRS's vertical part, ``ellipsoidal`` for a 3-D CRS, None for a
    2-D one (heights on no stated datum)."""
    _, vertical = crs_parts(crs)
    if vertical is not None:
        return vertical.name
    return "ellipsoidal" if len(crs.axis_info) == 3 else None


def crs_parts(crs):
    """``(horizontal, vertical)`` parts of a pyproj CRS: a compound CRS's two sub-CRSs, a 3-D CRS's 2-D version and
    None, or the CRS itself and None."""
    if crs.is_compound:
        subs = crs.sub_crs_list
        vertical = next((c for c in subs if c.is_vertical), None)
        horizontal = next((c for c in subs if not c.is_vertical), subs[0])
        return horizontal, vertical
    if len(crs.axis_info) == 3:
        try:
            return crs.to_2d(), None
        except CRSError:
            return crs, None
    return crs, None


def crs_label(crs):
    """A CRS in one short phrase: its authority code (``EPSG:32632``) when it has one, else its name (quoted)."""
    code = crs.to_authority(min_confidence=90)
    return f"{code[0]}:{code[1]}" if code else f"'{crs.name}'"


def crs_name(crs):
    """What ``--json`` summaries call a CRS (any pyproj input, or None): its authority code when it has one
    (``EPSG:32632``), else its name (``Lo25 WGS84 + EGM2008 height``), else the string it was given (a PROJ
    string)."""
    if crs is None:
        return None
    given = crs
    if isinstance(crs, str) and len(crs) < 40:
        return crs
    try:
        crs = CRS.from_user_input(crs)
    except CRSError:
        return str(crs)
    code = crs.to_authority(min_confidence=90)
    if code:
        return f"{code[0]}:{code[1]}"
    if crs.name and crs.name != "unknown":
        return crs.name
    return given if isinstance(given, str) else crs.to_proj4()


def image_shape(pair):
    """``(H, W)`` of the pair's images: the pair file's ``width``/``height``, else the left image's size."""
    if pair.image_size is not None:
        return pair.image_size
    if pair.left is None:
        raise RiverbedError("the pair file gives neither width/height nor a left image to take the size from")
    img = read_image(pair.left)
    return img.shape[:2]


def project_cloud(cloud_path, pair, registration=None, classes=None, drop_classes=NOISE_CLASSES,
                  outliers="sor", side="both", visibility="zbuffer", footprint=vis.ZBUFFER_RADIUS,
                  tolerance=vis.ZBUFFER_TOLERANCE, slope=vis.ZBUFFER_SLOPE, hpr_gamma=vis.HPR_GAMMA, crs=None,
                  shape=None, chunk_size=1_000_000, progress=None, edge_reach=vis.ZBUFFER_EDGE_REACH,
                  surface_cell=vis.SURFACE_CELL, surface_closing=vis.SURFACE_CLOSING,
                  surface_fill=vis.SURFACE_FILL, surface_margin=vis.SURFACE_MARGIN):
    """Project a LiDAR cloud into the pair's left image as sparse disparities.

    Parameters
    ----------
    cloud_path : str or path-like
        LAS/LAZ/COPC or KITTI ``.bin``, read in chunks of ``chunk_size`` points.
    pair : PairGeometry or RPCPair
        An RPC pair (``kind == "rpc"``) goes to :func:`~riverbed_cli.geometry.rpc_geometry.project_cloud_rpc`
        (the cloud's CRS to WGS 84 by pyproj, visibility ``zbuffer`` or ``none``, no registration).
    registration : (4, 4) array, optional
        LiDAR -> world transform overriding the pair's.
    classes : iterable of int, optional
        Keep only these ASPRS classes (default: all).
    drop_classes : iterable of int
        Drop these classes (default 7 and 18, noise).
    outliers : {"sor", "none"}
        Statistical outlier removal on the points that land in the image.
    side : {"left", "right", "both"}
        Which views the hidden point test runs in (both: drop points hidden in either image).
    visibility : {"zbuffer", "surface", "surface+zbuffer", "hpr", "none"}
        Hidden point removal method (the nearest point per pixel is always kept, whatever the method). surface:
        ``visibility.surface_visible`` against a height grid of the inlier candidates (aerial / nadir frames,
        world z up); surface+zbuffer: then the z-buffer on the points it keeps.
    footprint : int or "auto"
        Z-buffer splat radius (px); auto: per point, from the density (``visibility.footprint_radii``).
    tolerance, slope : float
        Z-buffer disparity margin (px) and splat fall-off (px per px), see ``visibility.zbuffer_visible``.
    edge_reach : float
        Z-buffer one-sided splat reach, a fraction of the radius in [0, 1] (1: the whole disc hides), see
        ``visibility.zbuffer_visible``.
    surface_cell, surface_closing, surface_fill : float or "auto", int, float
        Height grid cell (m), closing radius (cells) and nearest fill (point spacings), see
        ``visibility.surface_grid``.
    surface_margin : float
        Height (m) a ray must pass below the grid to hide its point.
    hpr_gamma : float
        HPR flipping radius exponent (``R = max|p| * 10**gamma``).
    crs : str, optional
        CRS of the cloud when its file states none (or a wrong one); compared with the pair's CRS.
    shape : (H, W), optional
        Image size; default from the pair (see :func:`image_shape`).
    progress : callable, optional
        Called with the number of points of each chunk once it is processed.

    Returns
    -------
    sparse : (H, W) float32
        ``d = x_left - x_right`` (px) at LiDAR pixels, NaN elsewhere.
    stats : dict
        Counts (every point read lands in exactly one of them), ``lidar_share``, ``window`` (what
        ``match --window auto`` would use), ``d_range``, ``row_offset_px`` (pairs off the baseline), ``crs``,
        ``seconds`` and ``stage_seconds`` (stream: read + project + z-buffer; outliers; visibility; share).
    """
    if getattr(pair, "kind", None) == "rpc":  # satellite pair: the same steps through the RPCs (rpc_geometry)
        if registration is not None:
            raise RiverbedError("a registration does not apply to an RPC pair (the cloud's CRS places it)")
        if outliers not in OUTLIERS:
            raise RiverbedError(f"outliers must be one of {', '.join(OUTLIERS)}, got '{outliers}'")
        if side not in SIDES:
            raise RiverbedError(f"side must be one of {', '.join(SIDES)}, got '{side}'")
        sparse, fields = project_cloud_rpc(cloud_path, pair, classes, drop_classes, outliers, side, visibility,
                                           footprint, tolerance, slope, crs, shape, chunk_size, progress, edge_reach)
        return sparse, ProjectionStats(**fields)
    t0 = time.perf_counter()
    if outliers not in OUTLIERS:
        raise RiverbedError(f"outliers must be one of {', '.join(OUTLIERS)}, got '{outliers}'")
    if side not in SIDES:
        raise RiverbedError(f"side must be one of {', '.join(SIDES)}, got '{side}'")
    if visibility not in VISIBILITY:
        raise RiverbedError(f"visibility must be one of {', '.join(VISIBILITY)}, got '{visibility}'")
    if not 0.0 <= edge_reach <= 1.0:
        raise RiverbedError(f"edge_reach must be between 0 and 1, got {edge_reach}")
    if not surface_margin >= 0.0:
        raise RiverbedError(f"surface_margin must be at least 0 m, got {surface_margin}")
    info = lidar_info(cloud_path)
    cloud_crs = resolve_crs(info, crs)
    heights = _check_crs(pair, cloud_crs, cloud_path)
    H, W = shape if shape is not None else image_shape(pair)

    if registration is None:
        reg = pair.registration
    else:
        reg = as_matrix(registration, 4, 4, "registration")
        check_registration(reg)
    A = np.ascontiguousarray(np.hstack([reg[:3, :3], (reg[:3, 3] - pair.origin)[:, None]]))
    PL, PR = np.ascontiguousarray(pair.P_left), np.ascontiguousarray(pair.P_right)
    sl, sr = pair._depth_scale(PL), pair._depth_scale(PR)
    max_dy = np.inf if pair.exactly_rectified else MAX_ROW_OFFSET

    idx0 = np.full(H * W, -1, np.int32)
    idx1 = np.full(H * W, -1, np.int32)
    cap = max(1, min(2 * H * W, info.point_count, _INITIAL_SLOTS))
    store_xyz = np.empty((cap, 3), np.float64)
    store_z = np.empty(cap, np.float64)
    store_pix = np.empty(cap, np.int64)
    store_code = np.empty(cap, np.int8)
    n_used = 0
    counts = np.zeros(2, np.int64)
    n_read = n_class = 0
    for chunk in iter_lidar(cloud_path, chunk_size=chunk_size):
        xyz = np.ascontiguousarray(chunk["xyz"], np.float64)
        if heights is not None:
            heights(xyz)
        keep = class_mask(chunk["classification"], classes, drop_classes)
        n_read += xyz.shape[0]
        n_class += int(xyz.shape[0] - keep.sum())
        start = 0
        while True:
            start, n_used = _project_chunk(xyz, keep, A, PL, PR, sl, sr, W, H, max_dy, idx0, idx1, store_xyz,
                                           store_z, store_pix, store_code, n_used, start, counts)
            if start >= xyz.shape[0]:
                break
            cap = min(2 * cap, 2 * H * W)  # at most two slots per pixel are ever in use
            store_xyz, store_z = _grow(store_xyz, cap), _grow(store_z, cap)
            store_pix, store_code = _grow(store_pix, cap), _grow(store_code, cap)
        if progress is not None:
            progress(xyz.shape[0])
    n_behind, n_outside = (int(c) for c in counts)
    t_stream = time.perf_counter()
    n_inside = n_read - n_class - n_behind - n_outside  # in front of the left camera, inside the left image

    pix0 = np.flatnonzero(idx0 >= 0)
    pix1 = np.flatnonzero(idx1 >= 0)
    s0, s1 = idx0[pix0], idx1[pix1]
    n_cand = s0.size + s1.size
    same_pixel = n_inside - n_cand  # beaten by two nearer points of their pixel while streaming

    # Outliers among all candidates (both layers), then the nearest surviving point per pixel.
    inlier = np.ones(n_used, bool)
    if outliers == "sor" and n_cand:
        slots = np.concatenate([s0, s1])
        inlier[slots] = sor_inliers_image(slots, np.concatenate([pix0, pix1]), idx0, idx1, (H, W), store_xyz,
                                          store_z, pair.focal, SOR_K, SOR_SIGMA)
    n_outliers = int(n_cand - inlier[s0].sum() - inlier[s1].sum())
    t_sor = time.perf_counter()
    win, taken_back = layer_winners(s0, inlier, idx1, pix0)
    same_pixel += int(inlier[s1].sum()) - taken_back

    # Winners behind the right camera, outside the right image or off the row are dropped, but only after they
    # have hidden what lies behind them in the left view.
    code = store_code[win]
    n_behind += int((code == 1).sum())
    n_outside += int((code == 2).sum())
    n_row = int((code == 3).sum())
    usable = code == 0
    if not usable.any():
        raise RiverbedError(
            f"no point lands in both images ({n_read} read: {n_class} filtered by class, {n_behind} behind a "
            f"camera, {n_outside} outside the {W}x{H} images, {n_row} off the row, {n_outliers} outliers)",
            cloud_path)

    xyz = store_xyz[win]
    xl, yl, xr, _, yr, _ = pair.project(xyz, full=True)
    pix = store_pix[win]
    rows, cols = pix // W, pix % W
    d = xl - xr

    surface = None
    if visibility.startswith("surface"):  # the height grid of all inlier candidates (both layers)
        slots = np.concatenate([s0[inlier[s0]], s1[inlier[s1]]])
        surface = vis.surface_grid(store_xyz[slots], surface_cell, surface_closing, surface_fill)
    opts = (footprint, tolerance, slope, hpr_gamma, edge_reach, surface, surface_margin)
    def visible_at(r, c, m, view):
        return _visible(visibility, r, c, d[m], xyz[m], pair.centres[view], (H, W), *opts)

    visible, n_occ_left, n_occ_right = vis.visible_in_both(usable, rows, cols, xr, yr, code, side,
                                                           visible_at if visibility != "none" else None)
    t_vis = time.perf_counter()

    sparse = np.full((H, W), np.nan, np.float32)
    sparse[rows[visible], cols[visible]] = d[visible].astype(np.float32)
    kept = int(visible.sum())
    share = lidar_share(sparse)
    dv = d[visible]
    stats = ProjectionStats(
        points_read=n_read, filtered={"class": n_class, "outliers": n_outliers}, behind_camera=n_behind,
        outside=n_outside, row_offset=n_row,
        occluded={"same_pixel": same_pixel, "left": n_occ_left, "right": n_occ_right}, kept=kept,
        lidar_share=share, d_range=[float(dv.min()), float(dv.max())] if kept else None, size=[W, H])
    if not pair.exactly_rectified and kept:
        dy = np.abs(yr - yl)[visible]
        stats.row_offset_px = {"median": float(np.median(dy)), "max": float(dy.max())}
        log.warning("the pair's right camera is off the baseline: right-image rows differ by %.3f px "
                    "(median, max %.3f) at the kept points; %d points off by more than %.1f px dropped",
                    float(np.median(dy)), float(dy.max()), n_row, MAX_ROW_OFFSET)
    stats.crs = crs_name(cloud_crs) if cloud_crs is not None else pair.crs
    if heights is not None:
        stats.heights_converted = {"from": heights.source, "to": heights.target}
    t_end = time.perf_counter()
    stats.seconds = t_end - t0
    stats.stage_seconds = {"stream": t_stream - t0, "outliers": t_sor - t_stream,
                              "visibility": t_vis - t_sor, "share": t_end - t_vis}
    total = n_class + n_outliers + n_behind + n_outside + n_row + same_pixel + n_occ_left + n_occ_right + kept
    assert total == n_read, (total, n_read)
    if kept == 0:
        raise RiverbedError(f"no point is left after outlier and hidden point removal ({n_read} read)",
                            cloud_path)
    return sparse, stats


def _visible(method, rows, cols, disp, xyz, centre, shape, footprint, tolerance, slope, gamma, edge_reach,
             surface, margin):
    if method == "hpr":
        return vis.hpr_visible(xyz, centre, gamma)
    visible = np.ones(disp.shape[0], bool)
    if method.startswith("surface"):
        visible = vis.surface_visible(xyz, centre, surface, margin)
    if method.endswith("zbuffer"):  # among the points the surface test keeps
        visible[visible] = vis.zbuffer_visible(rows[visible], cols[visible], disp[visible], shape, footprint,
                                               tolerance, slope, edge_reach)
    return visible


def disparity_offset_in_metres(geometry, rows, cols, values, offset, n=2000):
    """What a disparity ``offset`` (px, LiDAR minus images) of the LiDAR points means on the ground, through the
    pair's geometry: ``(vertical, along_rays)`` in metres, the medians over up to ``n`` of the points of the height
    change (world z; for an RPC pair, ellipsoidal height) and of the 3-D displacement's length when their disparity
    loses the offset. Positive ``vertical``: the LiDAR lies above the surface the images see."""
    step = max(1, -(-len(values) // n))
    x, y = np.asarray(cols[::step], np.float64), np.asarray(rows[::step], np.float64)
    d = np.asarray(values[::step], np.float64)
    if getattr(geometry, "kind", None) == "rpc":
        lon0, lat0, h0, _ = triangulate_rpc(geometry, x, y, d)
        lon1, lat1, h1, _ = triangulate_rpc(geometry, x, y, d - offset)
        dz = h0 - h1
        m = 111_320.0  # metres per degree of latitude
        moved = np.sqrt(((lon0 - lon1) * m * np.cos(np.radians(lat0))) ** 2 + ((lat0 - lat1) * m) ** 2 + dz ** 2)
    else:
        p0, p1 = geometry.triangulate(x, y, d), geometry.triangulate(x, y, d - offset)
        dz = p0[:, 2] - p1[:, 2]
        moved = np.linalg.norm(p0 - p1, axis=1)
    ok = np.isfinite(dz) & np.isfinite(moved)
    if not ok.any():
        return None, None
    return float(np.median(dz[ok])), float(np.median(moved[ok]))
