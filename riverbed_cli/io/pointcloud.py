"""Point cloud output: LAS/LAZ (laspy, lazrs) with RGB and CRS, and binary PLY (plyfile)."""

from pathlib import Path

import laspy
import numpy as np
import pyproj
from plyfile import PlyData, PlyElement

from ..errors import RiverbedError
from .atomic import atomic_output

POINT_FORMATS = (".las", ".laz", ".ply")
CHUNK = 1_000_000  # points per LAS/LAZ write


def check_pointcloud_path(path):
    """Raise unless ``path`` ends in .las, .laz or .ply."""
    suffix = Path(path).suffix.lower()
    if suffix not in POINT_FORMATS:
        raise RiverbedError(f"unsupported point cloud format '{suffix}' (use .las, .laz or .ply)", path)
    return suffix


def las_scales_offsets(xyz, scale=0.001):
    """LAS offsets (the minimum, floored to whole units) and scales (``scale`` m, coarser when the extent needs it).

    int32 coordinates span +-2**31 units: at 1 mm that is +-2147 km from the offset, ample for a block.
    """
    xyz = np.asarray(xyz, np.float64)
    lo = np.floor(xyz.min(axis=0)) if len(xyz) else np.zeros(3)
    span = (xyz.max(axis=0) - lo) if len(xyz) else np.zeros(3)
    scales = np.full(3, float(scale))
    need = span / (2**31 - 2)
    scales = np.maximum(scales, 10.0 ** np.ceil(np.log10(np.maximum(need, 1e-300))))
    return lo, scales


def write_points(path, xyz, rgb=None, crs=None, classification=None, overwrite=False, scale=0.001):
    """Write points (world coordinates, float64) to ``.las``, ``.laz`` or binary little-endian ``.ply``.

    Parameters
    ----------
    xyz : (N, 3) float64
        Coordinates in the CRS units (the origin already added back).
    rgb : (N, 3) uint8 or uint16, optional
        Colours; 8-bit values are scaled to LAS's 16-bit range (``v * 257``). PLY keeps 8 bits.
    crs : str or pyproj.CRS, optional
        Written as a WKT VLR (LAS 1.4, point format 7 with RGB or 6 without). PLY has no CRS: it is written as a
        header comment.
    classification : (N,) uint8, optional
        ASPRS classes (LAS only).
    scale : float
        LAS coordinate resolution in CRS units (default 1 mm).
    """
    suffix = check_pointcloud_path(path)
    xyz = np.asarray(xyz, np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise RiverbedError(f"points must be (N, 3), got {xyz.shape}", path)
    if rgb is not None:
        rgb = np.asarray(rgb)
        if rgb.shape != xyz.shape:
            raise RiverbedError(f"colours {rgb.shape} do not match points {xyz.shape}", path)
    with atomic_output(path, overwrite) as tmp:
        if suffix == ".ply":
            _write_ply(tmp, xyz, rgb, crs)
        else:
            _write_las(tmp, xyz, rgb, crs, classification, scale, compress=suffix == ".laz")


def _write_las(path, xyz, rgb, crs, classification, scale, compress):
    header = laspy.LasHeader(point_format=7 if rgb is not None else 6, version="1.4")
    header.offsets, header.scales = las_scales_offsets(xyz, scale)
    if crs is not None:
        try:
            header.add_crs(pyproj.CRS.from_user_input(crs))
        except pyproj.exceptions.CRSError:
            raise RiverbedError(f"unknown CRS '{crs}'", path) from None
    backend = laspy.LazBackend.Lazrs if compress else None
    try:
        # written in chunks: the scaled integer records of a chunk, not of the whole cloud, are in memory at once
        with laspy.open(str(path), mode="w", header=header, do_compress=compress, laz_backend=backend) as writer:
            for i in range(0, len(xyz), CHUNK) if len(xyz) else [0]:
                sl = slice(i, i + CHUNK)
                rec = laspy.ScaleAwarePointRecord.zeros(len(xyz[sl]), header=header)
                rec.x, rec.y, rec.z = xyz[sl, 0], xyz[sl, 1], xyz[sl, 2]
                if rgb is not None:
                    c = rgb[sl].astype(np.uint16) * (257 if rgb.dtype == np.uint8 else 1)
                    rec.red, rec.green, rec.blue = c[:, 0], c[:, 1], c[:, 2]
                if classification is not None:
                    rec.classification = np.asarray(classification[sl], np.uint8)
                writer.write_points(rec)
    except (laspy.errors.LaspyException, OSError, ValueError) as e:
        raise RiverbedError(f"cannot write point cloud ({e})", path) from None


def _write_ply(path, xyz, rgb, crs):
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    if rgb is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    v = np.empty(len(xyz), dtype=fields)
    v["x"], v["y"], v["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    if rgb is not None:
        c = rgb if rgb.dtype == np.uint8 else (rgb // 257).astype(np.uint8)
        v["red"], v["green"], v["blue"] = c[:, 0], c[:, 1], c[:, 2]
    comments = [f"crs {crs}"] if crs is not None else []
    PlyData([PlyElement.describe(v, "vertex")], text=False, byte_order="<", comments=comments).write(str(path))


