"""DSM rasterisation: points (world coordinates, float64) to a north-up height grid.

Grid convention: cell ``(row, col)`` covers ``[xmin + col * r, xmin + (col + 1) * r) x (ymax - (row + 1) * r, ymax - row
* r]``; the GeoTIFF transform is ``Affine(r, 0, xmin, 0, -r, ymax)`` (pixel corners, as GDAL). Heights are float32
in the units of the CRS; empty cells are ``nodata`` (NaN by default).
"""

import logging
import math
import re
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rasterio
from affine import Affine

from ..errors import RiverbedError
from ..geometry.rpc_geometry import rpc_disparity_points
from ..io.lidar import iter_lidar, lidar_info
from ..io.paths import require_file
from ..io.raster import write_geotiff
from ..runtime.kernel import kernel
from .dsm_holes import MAX_FILL_CELLS, check_fill_holes, close_lattice, fill_holes  # noqa: F401  (re-exported)

AGGREGATIONS = ("max", "mean", "median", "idw")


@dataclass
class Grid:
    """A north-up raster grid: origin at the top-left corner ``(xmin, ymax)``, square cells of ``resolution``."""

    xmin: float
    ymax: float
    resolution: float
    width: int
    height: int

    @property
    def transform(self):
        return Affine(self.resolution, 0.0, self.xmin, 0.0, -self.resolution, self.ymax)

    @property
    def bounds(self):
        r = self.resolution
        return self.xmin, self.ymax - self.height * r, self.xmin + self.width * r, self.ymax

    @classmethod
    def from_bounds(cls, xmin, ymin, xmax, ymax, resolution, max_cells=2_000_000_000, exact=False):
        """The grid of ``resolution`` covering the bounds, snapped outwards to multiples of the resolution.

        By default a point lying exactly on ``xmax`` or ``ymin`` still gets a cell (data extents); ``exact=True``
        gives the half-open grid of user bounds (``--bounds``), e.g. to match a reference DSM cell for cell.
        """
        r = float(resolution)
        if not r > 0 or not math.isfinite(r):
            raise RiverbedError(f"resolution must be a positive number, got {resolution}")
        if not (xmax >= xmin and ymax >= ymin):
            raise RiverbedError(f"empty bounds ({xmin}, {ymin}, {xmax}, {ymax})")
        x0 = math.floor(xmin / r) * r
        y1 = math.ceil(ymax / r) * r
        if y1 == ymax and ymax == ymin:
            y1 += r
        edge_x = 0 if exact else (1 if math.floor(xmax / r) * r == xmax else 0)
        edge_y = 0 if exact else (1 if math.floor(ymin / r) * r == ymin else 0)
        w = max(1, int(math.ceil((xmax - x0) / r - 1e-9)) + edge_x)
        h = max(1, int(math.ceil((y1 - ymin) / r - 1e-9)) + edge_y)
        if w * h > max_cells:
            raise RiverbedError(f"DSM grid {w}x{h} at {r} is too large; raise --resolution or give --bounds")
        return cls(x0, y1, r, w, h)


def _text(values):
    return " ".join(f"{float(v):.12g}" for v in values)


def check_bounds(bounds):
    """``(xmin, ymin, xmax, ymax)`` as floats, or a one-line :class:`RiverbedError`: four finite numbers with
    ``xmin < xmax`` and ``ymin < ymax``."""
    try:
        out = tuple(float(v) for v in bounds)
    except (TypeError, ValueError):
        raise RiverbedError(f"bounds must be four numbers XMIN YMIN XMAX YMAX, got {bounds!r}") from None
    if len(out) != 4:
        raise RiverbedError(f"bounds must be four numbers XMIN YMIN XMAX YMAX, got {len(out)}")
    if not all(math.isfinite(v) for v in out):
        raise RiverbedError(f"bounds {_text(out)} are not all finite numbers")
    if not (out[0] < out[2] and out[1] < out[3]):
        raise RiverbedError(f"bounds {_text(out)} are empty (XMIN YMIN XMAX YMAX with XMIN < XMAX and YMIN < YMAX)")
    return out


def grid_indices(grid, x, y):
    """Row and column (int64) of each point; -1 for points outside the grid."""
    col = np.floor((np.asarray(x, np.float64) - grid.xmin) / grid.resolution).astype(np.int64)
    row = np.floor((grid.ymax - np.asarray(y, np.float64)) / grid.resolution).astype(np.int64)
    bad = (col < 0) | (col >= grid.width) | (row < 0) | (row >= grid.height)
    col[bad] = -1
    row[bad] = -1
    return row, col


@kernel
def _accumulate(x, y, z, xmin, ymax, res, mode, counts, value, sums, weights, keys):
    # One pass per chunk: cell index, count and the aggregation state (mode 0 max, 1 mean, 2 idw, 3 median keys).
    H, W = counts.shape
    inv = 1.0 / res
    eps2 = (res / 4.0) ** 2
    for i in range(x.shape[0]):
        fc = np.floor((x[i] - xmin) * inv)
        fr = np.floor((ymax - y[i]) * inv)
        if not (fc >= 0 and fc < W and fr >= 0 and fr < H):  # also false for NaN
            if mode == 3:
                keys[i] = -1
            continue
        r = int(fr)
        c = int(fc)
        counts[r, c] += 1
        if mode == 0:
            if counts[r, c] == 1 or z[i] > value[r, c]:
                value[r, c] = z[i]
        elif mode == 1:
            sums[r, c] += z[i]  # the count is the weight
        elif mode == 2:
            dx = x[i] - (xmin + (c + 0.5) * res)
            dy = y[i] - (ymax - (r + 0.5) * res)
            w = 1.0 / (dx * dx + dy * dy + eps2)
            sums[r, c] += w * z[i]
            weights[r, c] += w
        else:
            keys[i] = r * W + c


@kernel
def _median_kernel(keys, heights, out):
    # Counting sort of the heights by cell (O(N)), then the median of each cell's bucket.
    n_cells = out.shape[0]
    starts = np.zeros(n_cells + 1, np.int64)
    for k in keys:
        starts[k + 1] += 1
    for i in range(n_cells):
        starts[i + 1] += starts[i]
    pos = starts[:-1].copy()
    buf = np.empty(heights.shape[0], np.float32)
    for i in range(keys.shape[0]):
        buf[pos[keys[i]]] = heights[i]
        pos[keys[i]] += 1
    for c in range(n_cells):
        a, b = starts[c], starts[c + 1]
        if b > a:
            out[c] = np.median(buf[a:b])


class Accumulator:
    """Streams point chunks into a grid, so clouds larger than memory rasterise in bounded memory.

    ``max``, ``mean`` and ``idw`` (weights ``1 / (d^2 + (r/4)^2)`` to the cell centre, ``d`` the horizontal distance)
    keep running per-cell state; ``median`` keeps the heights (float32) until :meth:`result`.
    """

    def __init__(self, grid, agg="max"):
        if agg not in AGGREGATIONS:
            raise RiverbedError(f"unknown aggregation '{agg}' (use one of {', '.join(AGGREGATIONS)})")
        self.grid, self.agg = grid, agg
        shape = (grid.height, grid.width)
        self.counts = np.zeros(shape, np.int32)
        if agg == "max":
            self.value = np.full(shape, np.nan, np.float64)
        elif agg in ("mean", "idw"):
            self.sums = np.zeros(shape, np.float64)
            self.weights = np.zeros(shape if agg == "idw" else (1, 1), np.float64)
        else:
            self.keys, self.heights = [], []

    def add(self, x, y, z):
        x = np.ascontiguousarray(x, np.float64)
        y = np.ascontiguousarray(y, np.float64)
        z = np.ascontiguousarray(z, np.float64)
        mode = {"max": 0, "mean": 1, "idw": 2, "median": 3}[self.agg]
        dummy = np.zeros((1, 1), np.float64)
        keys = np.empty(x.shape[0] if mode == 3 else 0, np.int64)
        _accumulate(x, y, z, float(self.grid.xmin), float(self.grid.ymax), float(self.grid.resolution), mode,
                    self.counts, self.value if mode == 0 else dummy, self.sums if mode in (1, 2) else dummy,
                    self.weights if mode in (1, 2) else dummy, keys)
        if mode == 3:
            ok = keys >= 0
            self.keys.append(keys[ok])
            self.heights.append(z[ok].astype(np.float32))

    def result(self):
        """(H, W) float32 heights, NaN where no point fell."""
        if self.agg == "max":
            return self.value.astype(np.float32)
        if self.agg in ("mean", "idw"):
            with np.errstate(invalid="ignore", divide="ignore"):
                return (self.sums / (self.counts if self.agg == "mean" else self.weights)).astype(np.float32)
        out = np.full(self.grid.height * self.grid.width, np.nan, np.float32)
        if self.keys:
            _median_kernel(np.concatenate(self.keys), np.concatenate(self.heights), out)
        return out.reshape(self.grid.height, self.grid.width)


def rasterize(x, y, z, grid, agg="max"):
    """Rasterise points into ``grid`` with one aggregation per cell (see :class:`Accumulator`)."""
    acc = Accumulator(grid, agg)
    acc.add(x, y, z)
    return acc.result()


def hillshade(dsm, resolution, azimuth=315.0, altitude=45.0, z_factor=1.0):
    """Grey hillshade (uint8) of a DSM, GDAL's formula; NaN cells are black."""
    z = np.asarray(dsm, np.float64)
    zf = np.where(np.isnan(z), np.nanmean(z) if np.isfinite(z).any() else 0.0, z)
    gy, gx = np.gradient(zf * z_factor, resolution)
    slope = np.arctan(np.hypot(gx, gy))
    # GDAL / ESRI: aspect = atan2(dz/dy, -dz/dx) with dz/dy along the rows (southwards), dz/dx eastwards
    aspect = np.arctan2(gy, -gx)
    az = math.radians(360.0 - azimuth + 90.0)
    alt = math.radians(altitude)
    shade = np.sin(alt) * np.cos(slope) + np.cos(alt) * np.sin(slope) * np.cos(az - aspect)
    out = np.clip(255 * shade, 0, 255).astype(np.uint8)
    out[np.isnan(z)] = 0
    return out


# -- from disparities and LiDAR to a DSM ---------------------------------------------------------------------------

NOISE_CLASSES = (7, 18)  # ASPRS low and high noise


def disparity_points(disp, pair, rows=None, image=None, confidence=None, min_confidence=None):
    """Triangulate the valid disparities of a left-image disparity map (or a block of its rows).

    Parameters
    ----------
    disp : (H, W) float
        Disparity of the left image, ``d = x_left - x_right``, NaN invalid.
    pair : PairGeometry or RPCPair
        The rectified cameras (world minus origin -> pixels); an RPC pair goes to
        :func:`~riverbed_cli.geometry.rpc_geometry.rpc_disparity_points` (points in ``pair.crs``, ellipsoidal
        heights; the second value is then the ground sample distance, m).
    rows : slice, optional
        Only these rows (row indices are image rows; used to stream large maps in blocks).
    image : (H, W) or (H, W, 3) array, optional
        Left image whose colours go with the points.
    confidence : (H, W) float array, optional
        Per-pixel confidence (NaN: none); with ``min_confidence``, the pixels whose confidence is below it or NaN
        are left out.
    min_confidence : float, optional
        The lowest confidence kept (see :func:`check_min_confidence`).

    Returns
    -------
    xyz : (N, 3) float64
        World coordinates, the pair's origin added back (exact float64).
    depth : (N,) float64
        Depth along the left optical axis.
    rgb : (N, 3) array or None
        Colours of the left image at the points.
    """
    if getattr(pair, "kind", None) == "rpc":  # two RPC rays intersected, points in the pair's output CRS
        return rpc_disparity_points(disp, pair, rows, image, confidence, min_confidence)
    rows = rows or slice(0, disp.shape[0])
    block = np.asarray(disp[rows], np.float64)
    valid = np.isfinite(block)
    if confidence is not None and min_confidence is not None:
        valid &= np.asarray(confidence[rows]) >= min_confidence  # NaN compares False: dropped
    r, c = np.nonzero(valid)
    r_img = r + (rows.start or 0)
    local = pair.triangulate(c.astype(np.float64), r_img.astype(np.float64), block[r, c])
    depth = pair.project(local)[3]
    rgb = None
    if image is not None:
        img = image[r_img, c]
        rgb = np.repeat(img[:, None], 3, axis=1) if img.ndim == 1 else img[:, :3]
    return local + pair.origin, depth, rgb


def default_resolution(depths, focal):
    """Ground sample distance of the left image at the median depth: ``median(depth) / focal``, 3 significant digits."""
    gsd = float(np.median(depths)) / float(focal)
    if not gsd > 0 or not math.isfinite(gsd):
        raise RiverbedError("cannot derive a DSM resolution from the depths; give --resolution")
    return float(f"{gsd:.3g}")


def check_min_confidence(value, name="min_confidence"):
    """``value`` as a float in [0, 1], or a one-line :class:`RiverbedError` naming ``name`` (e.g. the option)."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise RiverbedError(f"{name} must be a number from 0 to 1, got {value!r}") from None
    if not 0.0 <= x <= 1.0:  # also False for NaN
        raise RiverbedError(f"{name} must be a number from 0 to 1, got {x:g}")
    return x


def read_confidence(path, shape=None):
    """A per-pixel confidence map: band 1 of a single-band float TIFF/GeoTIFF, values in [0, 1], NaN (or the
    nodata value) where there is none; ``riverbed match --confidence`` writes them.

    Parameters
    ----------
    path : str or path-like
        ``.tif`` / ``.tiff``, one band, float32 (float64 is read too).
    shape : (H, W), optional
        The disparity map's shape, which the confidence map must have.

    Returns
    -------
    conf : (H, W) float32, NaN where there is no confidence
    """
    path = require_file(path)
    if path.suffix.lower() not in (".tif", ".tiff"):
        raise RiverbedError("confidence map must be a single-band float32 TIFF/GeoTIFF (.tif)", path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        try:
            ds = rasterio.open(path)
        except Exception:  # noqa: BLE001 - GDAL drivers raise many types; any of them means "cannot read"
            raise RiverbedError("cannot read confidence map (not a TIFF rasterio reads)", path) from None
        with ds:
            if ds.count != 1:
                raise RiverbedError(f"confidence map must have one band, has {ds.count}", path)
            if not ds.dtypes[0].startswith("float"):
                raise RiverbedError(f"confidence map must be float32 (values 0 to 1), got {ds.dtypes[0]}", path)
            if shape is not None and tuple(ds.shape) != tuple(shape):
                raise RiverbedError(f"confidence map is {ds.width}x{ds.height} but the disparity map is "
                                    f"{shape[1]}x{shape[0]} (W x H)", path)
            try:
                conf = ds.read(1).astype(np.float32)
            except Exception:  # noqa: BLE001 - as above
                raise RiverbedError("cannot read confidence map (corrupt or truncated data)", path) from None
            nodata = ds.nodata
    if nodata is not None and not np.isnan(nodata):
        conf[conf == np.float32(nodata)] = np.nan
    outside = ~np.isnan(conf) & ~((conf >= 0) & (conf <= 1))
    if outside.any():
        n = int(outside.sum())
        raise RiverbedError(f"confidence values must lie in [0, 1] (NaN: none), found {float(conf[outside][0]):g} "
                            f"({n} pixel{'s' if n > 1 else ''} outside)", path)
    return conf


class _GdalMessages(logging.Handler):
    # rasterio logs GDAL's warnings on "rasterio._env" as ("%s in %s", code, message)
    def __init__(self):
        super().__init__(logging.WARNING)
        self.messages = []

    def emit(self, record):
        args = record.args if isinstance(record.args, tuple) else ()
        self.messages.append(str(args[1]) if len(args) == 2 else record.getMessage())


def check_creation_options(options, bands=1, nodata=float("nan")):
    """Refuse GDAL COG creation options that GDAL would not honour, before any work: ``BLOCKSIZE`` a multiple of 16
    from 128 to 4096 (others hang or crash GDAL's COG driver), then a trial write of a small float32 raster in 128 px
    tiles (so it has an overview), whose GDAL warnings and errors become one line (``--co: <GDAL's message>``)."""
    co = {str(k).upper(): str(v) for k, v in (options or {}).items()}
    if not co:
        return
    if "BLOCKSIZE" in co:
        size = co["BLOCKSIZE"]
        if not (size.isdigit() and 128 <= int(size) <= 4096 and int(size) % 16 == 0):
            raise RiverbedError(f"--co BLOCKSIZE={size}: the tile size must be a multiple of 16 from 128 to 4096")
    gdal_log = logging.getLogger("rasterio._env")
    collect = _GdalMessages()
    propagate = gdal_log.propagate
    gdal_log.addHandler(collect)
    gdal_log.propagate = False  # the messages become the error below, not log lines
    failure = None
    try:
        with tempfile.TemporaryDirectory(prefix="riverbed-co-") as tmp:
            write_geotiff(Path(tmp) / "trial.tif", np.zeros((bands, 144, 144), np.float32),
                          Affine(1.0, 0.0, 0.0, 0.0, -1.0, 144.0), None, nodata, {**co, "BLOCKSIZE": "128"})
    except RiverbedError as e:
        failure = str(e)[len(e.path) + 2:] if e.path else str(e)
        failure = re.sub(r"^cannot write GeoTIFF \((.*)\)$", r"\1", failure)  # GDAL's own message is the one shown
    except Exception as e:  # noqa: BLE001 - GDAL raises its own error types (CPLE_*), not only RasterioError
        failure = str(e)
    finally:
        gdal_log.removeHandler(collect)
        gdal_log.propagate = propagate
    # GDAL's word on an option first (the error it leads to may be vague), then the error; other warnings pass
    about = [m for m in collect.messages if re.search(r"option|not recognised|invalid value", m, re.IGNORECASE)]
    found = about + ([failure] if failure is not None else [])
    if found:
        message = re.sub(r"^\S*trial\S*: ", "", (found[0] or "GDAL error").splitlines()[0])
        message = re.sub(r",\s*ignoring\.?$", "", message).rstrip(". ")
        raise RiverbedError(f"--co: {message}")


@dataclass
class DsmResult:
    dsm: np.ndarray  # (H, W) float32, NaN empty
    grid: Grid
    filled: np.ndarray  # (H, W) uint8: 1 where --fill-holes filled a cell
    stats: dict
    points: tuple = None  # keep_points: the image points (N x 3 float64) and their colours (N x 3 uint8, or None)


def _no_points(bounds, lo, hi):
    return RiverbedError(f"bounds {_text(bounds)} hold none of the points (they span {_text(lo[:2])} to "
                         f"{_text(hi[:2])})")


def build_dsm(sources=(), lidar=(), resolution=None, agg="max", bounds=None, fill=0, block_rows=256,
              point_sink=None, lidar_registration=None, drop_classes=NOISE_CLASSES, progress=None,
              confidence=None, min_confidence=None, lattice=True, keep_points=False):
    """Merge the points of several disparity maps (and optionally LiDAR clouds) into one DSM.

    Parameters
    ----------
    sources : sequence of (disp, pair, image)
        Left-image disparity maps with their :class:`PairGeometry` (and left images for colours, or None).
    lidar : sequence of paths
        LAS/LAZ/KITTI-bin clouds (read in chunks). LiDAR coordinates go to the world through
        ``lidar_registration`` (4 x 4; default: the first pair's registration, identity without pairs).
    resolution : float, optional
        Cell size in CRS units; default the ground sample distance of the first pair's left image at the median
        depth (LiDAR alone: twice the mean point spacing).
    agg : {"max", "mean", "median", "idw"}
        Per-cell aggregation, applied to image points and LiDAR points separately.
    bounds : (xmin, ymin, xmax, ymax), optional
        Default: the extent of all points.
    fill : int
        Fill enclosed gaps up to this many cells across (:func:`fill_holes`).
    lattice : bool
        Close the image points' sampling lattice (:func:`~riverbed_cli.products.dsm_holes.close_lattice`; the
        count is ``stats["cells_closed"]``).
    point_sink : callable, optional
        Called as ``point_sink(xyz, rgb)`` with every block of image points (to write a point cloud).
    confidence : sequence of (H, W) float arrays (or None), optional
        One per source: the per-pixel confidence of its disparity map in [0, 1], NaN none (:func:`read_confidence`).
    min_confidence : float, optional
        With ``confidence``: the points whose pixel's confidence is below this (or NaN) are dropped before they
        reach the point sink and the DSM; ``stats["confidence_dropped"]`` counts them (valid disparities dropped).
    keep_points : bool
        Triangulate once and keep the image points (with their colours) in memory, in the result's ``points``,
        instead of triangulating again to rasterise them: faster, for maps whose points fit in memory.

    Notes
    -----
    Merging rule: where a cell has LiDAR points its height comes from the LiDAR only ("LiDAR wins": it measures
    heights directly, to a few cm); the image points fill the cells LiDAR does not reach.
    """
    sources = list(sources)
    lidar = list(lidar)
    if not sources and not lidar:
        raise RiverbedError("nothing to rasterise: give DISP PAIR couples or --lidar clouds")
    if bounds is not None:
        bounds = check_bounds(bounds)
    if fill < 0:
        raise RiverbedError(f"hole filling size must be 0 or more cells, got {fill}")
    confs = [None] * len(sources) if confidence is None else list(confidence)
    if len(confs) != len(sources):
        raise RiverbedError(f"give one confidence map per disparity map ({len(sources)} disparity maps, "
                            f"{len(confs)} confidence maps)")
    if min_confidence is None and any(c is not None for c in confs):
        raise RiverbedError("confidence maps need a minimum confidence (min_confidence)")
    if min_confidence is not None:
        min_confidence = check_min_confidence(min_confidence)
        if all(c is None for c in confs):
            raise RiverbedError("a minimum confidence needs confidence maps")
    for i, ((disp, _, _), conf) in enumerate(zip(sources, confs)):
        if conf is not None and np.shape(conf) != np.shape(disp):
            raise RiverbedError(f"confidence map {i + 1} is {np.shape(conf)[1]}x{np.shape(conf)[0]} but its "
                                f"disparity map is {disp.shape[1]}x{disp.shape[0]} (W x H)")
    reg = lidar_registration
    if reg is None:
        reg = sources[0][1].registration if sources else np.eye(4)

    def lidar_chunks(path):
        for ch in iter_lidar(path):
            keep = ~np.isin(ch["classification"], drop_classes)
            xyz = ch["xyz"][keep]
            yield xyz @ reg[:3, :3].T + reg[:3, 3]

    # Pass 1: extent, depths (for the default resolution) and counts.
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    depths = []
    n_img = n_dropped = 0
    kept = [] if keep_points else None  # per source, its blocks of (points, colours)
    for (disp, pair, image), conf in zip(sources, confs):
        if keep_points:
            kept.append([])
        for r0 in range(0, disp.shape[0], block_rows):
            rows = slice(r0, r0 + block_rows)
            xyz, depth, rgb = disparity_points(disp, pair, rows, image if keep_points else None, conf, min_confidence)
            if conf is not None:
                n_dropped += int(np.count_nonzero(np.isfinite(disp[rows]) & ~(conf[rows] >= min_confidence)))
            ok = np.isfinite(xyz).all(axis=1)
            xyz = xyz[ok]
            if keep_points:
                kept[-1].append((xyz, None if rgb is None else rgb[ok]))
            if len(xyz):
                lo, hi = np.minimum(lo, xyz.min(axis=0)), np.maximum(hi, xyz.max(axis=0))
                depths.append(depth[:: max(1, len(depth) // 2000)])
                n_img += len(xyz)
    n_lidar_total = 0
    for path in lidar:
        info = lidar_info(path)
        n_lidar_total += info.point_count
        if info.point_count:
            corners = np.array(np.meshgrid(*zip(info.mins, info.maxs))).T.reshape(-1, 3)
            w = corners @ reg[:3, :3].T + reg[:3, 3]
            lo, hi = np.minimum(lo, w.min(axis=0)), np.maximum(hi, w.max(axis=0))
    if not np.isfinite(lo).all():
        why = "invalid or below the minimum confidence" if n_dropped else "invalid"
        raise RiverbedError(f"no valid points to rasterise (all disparities {why} and no LiDAR points)")
    if resolution is None:
        if depths:
            rpc = getattr(sources[0][1], "kind", None) == "rpc"  # its "depths" are ground sample distances
            resolution = default_resolution(np.concatenate(depths), 1.0 if rpc else sources[0][1].focal)
        else:
            area = max((hi[0] - lo[0]) * (hi[1] - lo[1]), 1e-12)
            resolution = float(f"{2 * math.sqrt(area / max(n_lidar_total, 1)):.2g}")
    if bounds is not None:
        if bounds[0] > hi[0] or bounds[2] < lo[0] or bounds[1] > hi[1] or bounds[3] < lo[1]:
            raise _no_points(bounds, lo, hi)  # early: off the extent (the count after pass 2 catches the rest)
        grid = Grid.from_bounds(*bounds, resolution, exact=True)
    else:
        grid = Grid.from_bounds(lo[0], lo[1], hi[0], hi[1], resolution)

    # Pass 2: rasterise image points, then LiDAR points, each into its own accumulator.
    img_acc = Accumulator(grid, agg)
    for k, ((disp, pair, image), conf) in enumerate(zip(sources, confs)):
        for b, r0 in enumerate(range(0, disp.shape[0], block_rows)):
            if keep_points:
                xyz, rgb = kept[k][b]
            else:
                xyz, _, rgb = disparity_points(disp, pair, slice(r0, r0 + block_rows), image, conf, min_confidence)
                ok = np.isfinite(xyz).all(axis=1)
                xyz, rgb = xyz[ok], None if rgb is None else rgb[ok]
            img_acc.add(xyz[:, 0], xyz[:, 1], xyz[:, 2])
            if point_sink is not None:
                point_sink(xyz, rgb)
            if progress:
                progress(min(block_rows, disp.shape[0] - r0))
    dsm = img_acc.result() if sources else np.full((grid.height, grid.width), np.nan, np.float32)
    n_closed = 0
    if sources and lattice:  # before the LiDAR's cells: the lattice is the image points' sampling
        dsm, n_closed = close_lattice(dsm)
    n_lidar = 0
    in_grid = int(img_acc.counts.sum())
    if lidar:
        lid_acc = Accumulator(grid, agg)
        for path in lidar:
            for xyz in lidar_chunks(path):
                lid_acc.add(xyz[:, 0], xyz[:, 1], xyz[:, 2])
                n_lidar += len(xyz)
        in_grid += int(lid_acc.counts.sum())
        lid = lid_acc.result()
        has = np.isfinite(lid)
        dsm = np.where(has, lid, dsm)  # LiDAR wins where both exist
    if bounds is not None and not in_grid:
        raise _no_points(bounds, lo, hi)
    filled = np.zeros(dsm.shape, np.uint8)
    if fill:
        dsm, filled = fill_holes(dsm, fill)
    stats = {"resolution": grid.resolution, "width": grid.width, "height": grid.height,
             "bounds": list(grid.bounds), "image_points": int(n_img), "lidar_points": int(n_lidar),
             "cells_with_data": float(100.0 * np.isfinite(dsm).mean()), "cells_filled": int(filled.sum()),
             "cells_closed": n_closed,
             "aggregation": agg, "confidence_dropped": None if min_confidence is None else n_dropped}
    points = None
    if keep_points:
        blocks = [b for source in kept for b in source]
        xyz = np.concatenate([b[0] for b in blocks]) if blocks else np.zeros((0, 3))
        rgb = np.concatenate([b[1] for b in blocks]) if blocks and all(b[1] is not None for b in blocks) else None
        points = (xyz, rgb)
    return DsmResult(dsm.astype(np.float32), grid, filled, stats, points)
