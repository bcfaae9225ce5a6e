"""Read LiDAR point clouds: LAS 1.0-1.4, LAZ (and COPC, which is LAZ 1.4), KITTI Velodyne ``.bin``; and a DSM
raster (``.tif``, ``.tiff``, ``.hgt``) as the points of its cells (:mod:`.dsm_cloud`).

Conventions
-----------
- Coordinates are ``float64`` real-world values, ``X * scale + offset`` exactly as laspy computes them
  (``las.x``); nothing is cast to ``float32`` here: subtract a local origin first (see DESIGN.md).
- Points are read in chunks (:func:`iter_lidar`), so a file larger than memory can be streamed.
- The CRS is the one the file states (WKT VLR/EVLR preferred over GeoTIFF keys, as laspy's
  ``parse_crs``), or None; :func:`resolve_crs` lets the caller override it (``--crs``). No reprojection.
- The format is chosen by extension, case-insensitively: ``.las``, ``.laz`` (``.copc.laz`` included) or
  ``.bin``; a ``.las`` that holds LAZ data (or the reverse) is read by what its header says.
- Classification is the LAS class code as laspy decodes it (5 bits, 0-31, for formats 0-5; 8 bits for
  6-10); 0/1 mean never classified / unclassified. KITTI scans have none (zeros).

Untrusted input
---------------
Files come from strangers, and laspy/lazrs trust their headers (a forged count can make laspy loop for ever or
lazrs abort the process). So before laspy sees a LAS/LAZ file, :func:`lidar_info` and :func:`iter_lidar` check
its header, VLRs, EVLRs and (LAZ) chunk table against the file size with plain byte parsing: see
:mod:`riverbed_cli.io.las_checks` for what is checked. Whatever laspy or lazrs still raise while reading
(including a Rust panic, which pyo3 raises as a ``BaseException``) becomes a one-line :class:`RiverbedError`
naming the file.
"""

import logging
from dataclasses import dataclass
from pathlib import Path

import laspy
import numpy as np
from pyproj import CRS
from pyproj.exceptions import CRSError

from ..errors import RiverbedError
from .dsm_cloud import DSM_SUFFIXES, dsm_info_fields, iter_dsm_points
from .las_checks import check_las_header, native_errors
from .paths import require_file

_log = logging.getLogger(__name__)

_RGB_FORMATS = {2, 3, 5, 7, 8, 10}
_KITTI_RECORD = 16  # float32 x, y, z, reflectance
_UNSUPPORTED = "unsupported point cloud format '{}' (use .las, .laz, KITTI .bin, or a DSM .tif/.hgt)"


@dataclass
class LidarInfo:
    """What the header of a point cloud says, after validation.

    Attributes
    ----------
    path : str
    point_count : int
    mins, maxs : ndarray of float64, shape (3,)
        Bounds ``x, y, z`` as stated in the LAS header (not recomputed from the points); for KITTI ``.bin``,
        computed from the points (the format has no header).
    crs : pyproj.CRS or None
        As stated by the file (laspy ``parse_crs``); None when there is none or it cannot be parsed.
    version : str
        ``"1.0"`` ... ``"1.4"``, or ``"kitti-bin"``.
    point_format : int
        LAS point data record format 0-10; -1 for KITTI ``.bin``.
    has_rgb : bool
        The point format carries red, green, blue.
    has_classification : bool
        The format has a classification field (every LAS format; not KITTI). Files that never classified
        their points store 0 or 1 there.
    scales, offsets : ndarray of float64, shape (3,), or None
        LAS coordinate scale and offset (``x = X * scale + offset``); None for KITTI ``.bin``.
    """

    path: str
    point_count: int
    mins: np.ndarray
    maxs: np.ndarray
    crs: object
    version: str
    point_format: int
    has_rgb: bool
    has_classification: bool
    scales: np.ndarray = None
    offsets: np.ndarray = None


# ---------------------------------------------------------------------------------------------------------
# Public API


def lidar_info(path):
    """Read and validate the header of a LAS/LAZ/COPC file or a KITTI ``.bin`` scan (no point decoding).

    Parameters
    ----------
    path : str or path-like
        ``.las``, ``.laz`` (including ``.copc.laz``) or ``.bin`` (KITTI Velodyne), case-insensitive.

    Returns
    -------
    LidarInfo

    Raises
    ------
    RiverbedError
        Missing, empty, unsupported or malformed file (:mod:`riverbed_cli.io.las_checks` lists what is checked).

    Notes
    -----
    LAS/LAZ: only the header, VLRs, EVLRs and (LAZ) the chunk table and layer sizes are read, so this is
    fast for any file size. KITTI ``.bin`` has no header: the file is read once, in chunks, for its bounds.
    """
    path, kind = _check_input(path)
    if kind == "bin":
        return _bin_info(path)
    if kind == "dsm":
        return LidarInfo(path=str(path), **dsm_info_fields(path), version="dsm", point_format=-1, has_rgb=False,
                         has_classification=False)
    header = check_las_header(path)
    return _las_info(path, header)


def iter_lidar(path, chunk_size=1_000_000, crs=None):
    """Read a point cloud chunk by chunk.

    The header is validated (and ``crs`` parsed) when this function is called, so a bad file or CRS
    raises here, before the first chunk is requested.

    Parameters
    ----------
    path : str or path-like
        ``.las``, ``.laz`` (including ``.copc.laz``) or KITTI ``.bin``.
    chunk_size : int
        Points per chunk (the last one may be shorter).
    crs : str or pyproj.CRS, optional
        Only validated (an unknown CRS raises :class:`RiverbedError`); the points are never reprojected.
        Use :func:`resolve_crs` to get the CRS that applies to them.

    Yields
    ------
    chunk : dict
        ``"xyz"``: float64 ``(N, 3)`` real-world coordinates; ``"classification"``: uint8 ``(N,)`` (zeros
        for KITTI); ``"intensity"``: uint16 ``(N,)`` (float32 reflectance for KITTI); ``"rgb"``: uint16
        ``(N, 3)`` or None when the format has no colour.

    Raises
    ------
    RiverbedError
        Malformed file (at call time), or corrupt point data (while iterating).
    """
    if int(chunk_size) != chunk_size or chunk_size < 1:
        raise ValueError(f"chunk_size must be a positive integer, got {chunk_size!r}")
    chunk_size = int(chunk_size)
    if crs is not None:
        _parse_crs(crs)
    path, kind = _check_input(path)
    if kind == "bin":
        count = _bin_count(path)
        return _iter_bin(path, count, chunk_size)
    if kind == "dsm":
        return iter_dsm_points(path, chunk_size)
    header = check_las_header(path)
    return _iter_las(path, header, chunk_size)


def read_lidar(path):
    """Read a whole point cloud into one chunk dict (see :func:`iter_lidar`); for small files and tests."""
    chunks = list(iter_lidar(path))
    if not chunks:  # empty LAS: keep the dtypes and the rgb/None distinction
        info = lidar_info(path)
        return _empty_chunk(info.point_format >= 0, info.has_rgb)
    if len(chunks) == 1:
        return chunks[0]
    rgb = None if chunks[0]["rgb"] is None else np.concatenate([c["rgb"] for c in chunks])
    return {
        "xyz": np.concatenate([c["xyz"] for c in chunks]),
        "classification": np.concatenate([c["classification"] for c in chunks]),
        "intensity": np.concatenate([c["intensity"] for c in chunks]),
        "rgb": rgb,
    }


def resolve_crs(info, override=None):
    """The CRS that applies to a point cloud: ``override`` if given, else the file's, else None.

    Parameters
    ----------
    info : LidarInfo
    override : str or pyproj.CRS, optional
        Anything pyproj understands: ``"EPSG:2154"``, WKT, a PROJ string, a CRS object.

    Returns
    -------
    pyproj.CRS or None
        None when neither gives one (a file without a CRS is accepted).

    Raises
    ------
    RiverbedError
        ``unknown CRS '...'`` when pyproj cannot parse ``override``.
    """
    if override is not None:
        return _parse_crs(override)
    return info.crs


# ---------------------------------------------------------------------------------------------------------
# Input checks shared by all formats


def _kind(path):
    name = path.name.lower()
    if name.endswith((".las", ".laz")):
        return "las"
    if name.endswith(".bin"):
        return "bin"
    if name.endswith(DSM_SUFFIXES):
        return "dsm"
    ext = path.suffix.lower()
    raise RiverbedError(_UNSUPPORTED.format(ext if ext else "(no extension)"), path)


def _check_input(path):
    kind = _kind(Path(path))
    path = require_file(path)
    if path.stat().st_size == 0:
        raise RiverbedError("empty file", path)
    return path, kind


def _parse_crs(value):
    if isinstance(value, CRS):
        return value
    try:
        return CRS.from_user_input(value)
    except (CRSError, TypeError, ValueError):
        raise RiverbedError(f"unknown CRS '{value}'") from None


# ---------------------------------------------------------------------------------------------------------
# LAS / LAZ: reading through laspy


def _open_laspy(path):
    with native_errors(path, "LAS header"):
        return laspy.open(str(path))


def _las_info(path, header):
    reader = _open_laspy(path)
    try:
        h = reader.header
        fmt = h.point_format
        info = LidarInfo(
            path=str(path),
            point_count=int(h.point_count),
            mins=np.array(h.mins, dtype=np.float64),
            maxs=np.array(h.maxs, dtype=np.float64),
            crs=_file_crs(path, h),
            version=f"{h.version.major}.{h.version.minor}",
            point_format=int(fmt.id),
            has_rgb=fmt.id in _RGB_FORMATS,
            has_classification=True,
            scales=np.array(h.scales, dtype=np.float64),
            offsets=np.array(h.offsets, dtype=np.float64),
        )
    finally:
        reader.close()
    if info.point_count != header.point_count or info.point_format != header.point_format:
        raise RiverbedError("cannot read LAS header (laspy and the header check disagree)", path)
    return info


def _file_crs(path, h):
    try:
        crs = h.parse_crs()
    except Exception as e:  # noqa: BLE001 - pyproj and laspy's GeoTIFF parser raise many types
        _log.warning("%s: cannot parse the CRS stated in the file (%s); treating it as having none",
                     path, " ".join(str(e).split())[:160])
        return None
    if crs is None:
        # GeoTIFF keys with a user-defined CRS: only the citation text names it (the IGN LiDAR HD sample
        # says "RGF93 / Lambert-93", i.e. EPSG:2154). Guessing from free text is not safe: say it instead.
        citations = [s.split("|")[0] for v in h.vlrs if type(v).__name__ == "GeoAsciiParamsVlr"
                     for s in v.strings if s.split("|")[0]]
        if citations:
            _log.warning("%s: the GeoTIFF keys name no CRS pyproj knows (citation '%s'); give one explicitly",
                         path, citations[0])
    return crs


def _iter_las(path, header, chunk_size):
    reader = _open_laspy(path)
    try:
        n = reader.header.point_count
        fmt = reader.header.point_format.id
        scales = np.array(reader.header.scales, dtype=np.float64)
        offsets = np.array(reader.header.offsets, dtype=np.float64)
        rgb = fmt in _RGB_FORMATS
        done = 0
        while done < n:
            want = min(chunk_size, n - done)
            with native_errors(path, "point data"):
                pts = reader.read_points(want)
                if len(pts) != want:
                    raise RiverbedError(f"point data ended after {done + len(pts)} of {n} points", path)
                chunk = _las_chunk(pts, scales, offsets, rgb)
            done += want
            yield chunk
    finally:
        reader.close()


def _las_chunk(pts, scales, offsets, rgb):
    xyz = np.empty((len(pts), 3), dtype=np.float64)
    # Same arithmetic as laspy's scaled views (int32 * float64 + float64), so results are bit-identical.
    for k, name in enumerate("XYZ"):
        xyz[:, k] = pts[name] * scales[k] + offsets[k]
    return {
        "xyz": xyz,
        "classification": np.asarray(pts.classification, dtype=np.uint8),
        "intensity": np.asarray(pts.intensity, dtype=np.uint16),
        "rgb": np.stack([pts.red, pts.green, pts.blue], axis=1).astype(np.uint16) if rgb else None,
    }


def _empty_chunk(las, rgb):
    return {
        "xyz": np.empty((0, 3), np.float64),
        "classification": np.empty(0, np.uint8),
        "intensity": np.empty(0, np.uint16 if las else np.float32),
        "rgb": np.empty((0, 3), np.uint16) if rgb else None,
    }


# ---------------------------------------------------------------------------------------------------------
# KITTI Velodyne .bin: float32 x, y, z, reflectance per point, no header, no CRS


def _bin_count(path):
    size = path.stat().st_size
    if size % _KITTI_RECORD:
        raise RiverbedError(
            f"not a KITTI Velodyne scan: {size} bytes is not a multiple of 16 (float32 x, y, z, reflectance)",
            path,
        )
    return size // _KITTI_RECORD


def _iter_bin(path, count, chunk_size):
    with open(path, "rb") as f:
        done = 0
        while done < count:
            want = min(chunk_size, count - done)
            raw = np.fromfile(f, dtype="<f4", count=want * 4)
            if raw.size != want * 4:
                raise RiverbedError(f"point data ended after {done + raw.size // 4} of {count} points", path)
            raw = raw.reshape(want, 4)
            xyz = raw[:, :3].astype(np.float64)
            if not np.all(np.isfinite(xyz)):
                bad = done + int(np.flatnonzero(~np.all(np.isfinite(xyz), axis=1))[0])
                raise RiverbedError(f"non-finite coordinates at point {bad}", path)
            done += want
            yield {
                "xyz": xyz,
                "classification": np.zeros(want, np.uint8),
                "intensity": raw[:, 3].copy(),
                "rgb": None,
            }


def _bin_info(path):
    count = _bin_count(path)
    mins = np.full(3, np.inf)
    maxs = np.full(3, -np.inf)
    for chunk in _iter_bin(path, count, 1_000_000):
        mins = np.minimum(mins, chunk["xyz"].min(axis=0))
        maxs = np.maximum(maxs, chunk["xyz"].max(axis=0))
    return LidarInfo(
        path=str(path),
        point_count=count,
        mins=mins,
        maxs=maxs,
        crs=None,
        version="kitti-bin",
        point_format=-1,
        has_rgb=False,
        has_classification=False,
        scales=None,
        offsets=None,
    )


def class_mask(cls, classes, drop_classes):
    """Points to keep by their ASPRS classification: in ``classes`` (all when None) and not in ``drop_classes``."""
    keep = np.ones(cls.shape[0], bool)
    if classes is not None:
        keep &= np.isin(cls, np.asarray(sorted(classes), np.uint8))
    if drop_classes:
        keep &= ~np.isin(cls, np.asarray(sorted(drop_classes), np.uint8))
    return keep
