"""Read LiDAR point clouds: LAS 1.0-1.4, LAZ (and COPC, which is LAZ 1.4), KITTI Velodyne ``.bin``.

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
Files come from strangers, and laspy/lazrs trust their headers: a forged VLR count makes laspy loop for
ever (PDAL's ``garbage_nVariableLength.las``), a forged chunk count or chunk size makes lazrs allocate
gigabytes (a failed allocation in Rust aborts the whole process, which no ``except`` can catch), and an old
LASzip 1.x "pointwise" file makes lazrs panic. So before laspy sees a file, :func:`lidar_info` checks the
header against the file size with plain byte parsing:

- header size, version 1.0-1.4, point format 0-10, record length >= the format's size;
- every VLR lies between the header and the point data, every EVLR inside the file (the walk is bounded
  by the bytes actually present, so no count can make it loop);
- uncompressed: ``offset + count * record_length <= file size`` (trailing bytes, e.g. EVLRs or
  waveform packets, are fine; a shortfall is not);
- LAZ: a LASzip VLR with a supported compressor (chunked, LASzip >= 2.0) whose items match the record
  length; a chunk table inside the file, with no more chunks than the compressed bytes can hold (each
  chunk starts with one raw point, >= 20 bytes), consistent with the header's point count, with byte
  counts that fit, and no chunk decompressing to more than :data:`MAX_CHUNK_BYTES`.

Whatever laspy or lazrs still raise while reading (including a Rust panic, which pyo3 raises as a
``BaseException``) becomes a one-line :class:`RiverbedError` naming the file.
"""

import logging
import math
import struct
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import laspy
import lazrs
import numpy as np
from pyproj import CRS
from pyproj.exceptions import CRSError

from ..errors import RiverbedError
from .paths import require_file

_log = logging.getLogger(__name__)

#: Largest decompressed LAZ chunk accepted (points x record length). LASzip writes 50,000-point chunks
#: (~2-3 MB) and COPC nodes are of the same order; lazrs allocates a whole chunk at once.
MAX_CHUNK_BYTES = 256 * 2**20

_HEADER_SIZE = {0: 227, 1: 227, 2: 227, 3: 235, 4: 375}  # by minor version
# Size of each point format's standard fields (the record may be longer: extra bytes).
_RECORD_SIZE = {0: 20, 1: 28, 2: 26, 3: 34, 4: 57, 5: 63, 6: 30, 7: 36, 8: 38, 9: 59, 10: 67}
_RGB_FORMATS = {2, 3, 5, 7, 8, 10}
_VLR_HEADER = 54
_EVLR_HEADER = 60
_LASZIP_USER_ID = b"laszip encoded"
_LASZIP_RECORD_ID = 22204
_COMPRESSOR_NAMES = {0: "none", 1: "pointwise, LASzip 1.x", 2: "pointwise chunked", 3: "layered chunked"}
_MIN_CHUNK_BYTES = 20  # a LAZ chunk starts with its first point stored raw, and a point is >= 20 bytes
# Layers per LASzip item in layered chunks: point14 9, RGB14 1, RGBNIR14 2, wavepacket14 1, byte14 one
# per byte (lazrs las/point6.rs, rgb.rs, nir.rs, wavepacket.rs, extra_bytes.rs).
_LAYERS = {10: 9, 11: 1, 12: 2, 13: 1, 14: None}
_KITTI_RECORD = 16  # float32 x, y, z, reflectance
_UNSUPPORTED = "unsupported point cloud format '{}' (use .las, .laz or KITTI .bin)"


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
        Missing, empty, unsupported or malformed file (see the module notes for what is checked).

    Notes
    -----
    LAS/LAZ: only the header, VLRs, EVLRs and (LAZ) the chunk table and layer sizes are read, so this is
    fast for any file size. KITTI ``.bin`` has no header: the file is read once, in chunks, for its bounds.
    """
    path, kind = _check_input(path)
    if kind == "bin":
        return _bin_info(path)
    header = _check_las(path)
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
    header = _check_las(path)
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
# LAS / LAZ: header validation before laspy sees the file


@dataclass
class _Header:
    size: int
    minor: int
    point_format: int
    compressed: bool
    record_length: int
    point_count: int
    offset: int


def _check_las(path):
    """Validate a LAS/LAZ header, its VLRs, EVLRs and (LAZ) chunk table against the file size."""
    size = path.stat().st_size
    with open(path, "rb") as f:
        head = f.read(375)
        if head[:4] != b"LASF":
            raise RiverbedError("not a LAS/LAZ file (it must start with 'LASF')", path)
        if len(head) < 227:
            raise RiverbedError(f"truncated LAS header ({size} bytes; a LAS header has at least 227)", path)
        major, minor = head[24], head[25]
        if major != 1 or minor > 4:
            raise RiverbedError(f"unsupported LAS version {major}.{minor} (1.0 to 1.4 are read)", path)
        header_size, offset, n_vlr = struct.unpack_from("<HII", head, 94)
        format_byte = head[104]
        (record_length,) = struct.unpack_from("<H", head, 105)
        (point_count,) = struct.unpack_from("<I", head, 107)
        # Bit 7 set and bit 6 clear marks LAZ (as laspy and LASzip read it); the format is the low 6 bits.
        compressed = (format_byte & 0xC0) == 0x80
        point_format = format_byte & 0x3F

        need = _HEADER_SIZE[minor]
        if header_size < need:
            raise RiverbedError(
                f"malformed LAS header: header size {header_size} is less than the {need} bytes "
                f"LAS 1.{minor} needs",
                path,
            )
        if len(head) < need:
            raise RiverbedError(f"truncated LAS header ({size} bytes; LAS 1.{minor} needs {need})", path)
        if offset < header_size:
            raise RiverbedError(
                f"malformed LAS header: point data offset {offset} is inside the {header_size}-byte header",
                path,
            )
        if offset > size:
            raise RiverbedError(
                f"truncated LAS: point data starts at byte {offset}, past the end of the file ({size} bytes)",
                path,
            )
        if point_format not in _RECORD_SIZE:
            raise RiverbedError(f"unsupported LAS point format {point_format} (0 to 10 are read)", path)
        if record_length < _RECORD_SIZE[point_format]:
            raise RiverbedError(
                f"malformed LAS header: point record length {record_length} is shorter than the "
                f"{_RECORD_SIZE[point_format]} bytes point format {point_format} needs",
                path,
            )
        scales = np.array(struct.unpack_from("<3d", head, 131))
        offsets = np.array(struct.unpack_from("<3d", head, 155))
        bounds = np.array(struct.unpack_from("<6d", head, 179))
        if not (np.all(np.isfinite(scales)) and np.all(scales != 0)):
            raise RiverbedError(f"malformed LAS header: coordinate scales {scales.tolist()}", path)
        if not np.all(np.isfinite(offsets)):
            raise RiverbedError(f"malformed LAS header: coordinate offsets {offsets.tolist()}", path)
        if not np.all(np.isfinite(bounds)):
            raise RiverbedError("malformed LAS header: the bounds are not finite", path)
        n_evlr, evlr_start = 0, 0
        if minor >= 4:
            evlr_start, n_evlr, point_count = struct.unpack_from("<QIQ", head, 235)

        # VLRs: all must lie between the header and the point data. Checking the count against the space
        # first bounds the walk (laspy itself would read a forged count of empty VLRs for ever).
        space = offset - header_size
        if n_vlr * _VLR_HEADER > space:
            raise RiverbedError(
                f"malformed LAS header: {n_vlr} VLRs declared, but only {space} bytes lie between the "
                f"header and the point data",
                path,
            )
        f.seek(header_size)
        vlr_bytes = f.read(space)
        laszip_vlr = None
        pos = 0
        for i in range(n_vlr):
            length = 0
            if pos + _VLR_HEADER <= space:
                user_id = vlr_bytes[pos + 2:pos + 18].split(b"\0")[0]
                record_id, length = struct.unpack_from("<HH", vlr_bytes, pos + 18)
            end = pos + _VLR_HEADER + length
            if end > space:
                raise RiverbedError(
                    f"malformed LAS header: VLR {i + 1} of {n_vlr} (at byte {header_size + pos}) does not "
                    f"fit before the point data (byte {offset})",
                    path,
                )
            if user_id == _LASZIP_USER_ID and record_id == _LASZIP_RECORD_ID:
                laszip_vlr = vlr_bytes[pos + _VLR_HEADER:end]
            pos = end

        if n_evlr:
            _check_evlrs(f, path, size, offset, evlr_start, n_evlr)

        header = _Header(size, minor, point_format, compressed, record_length, point_count, offset)
        if not compressed:
            needed = offset + point_count * record_length
            if needed > size:
                raise RiverbedError(
                    f"truncated LAS: the header declares {point_count} points of {record_length} bytes "
                    f"from byte {offset} ({needed} bytes), the file has {size}",
                    path,
                )
        elif point_count > 0:
            _check_laz(f, path, header, laszip_vlr)
    return header


def _check_evlrs(f, path, size, offset, start, count):
    if start < offset or start > size:
        raise RiverbedError(
            f"malformed LAS header: first EVLR at byte {start}, outside the point data end ({offset}) "
            f"to file end ({size}) range",
            path,
        )
    if count * _EVLR_HEADER > size - start:
        raise RiverbedError(
            f"malformed LAS header: {count} EVLRs declared, but only {size - start} bytes follow byte {start}",
            path,
        )
    pos = start
    for i in range(count):
        f.seek(pos)
        raw = f.read(_EVLR_HEADER)
        if len(raw) < _EVLR_HEADER:
            raise RiverbedError(f"truncated LAS: EVLR {i + 1} of {count} starts at byte {pos}, past the end",
                                path)
        (length,) = struct.unpack_from("<Q", raw, 20)
        if pos + _EVLR_HEADER + length > size:
            raise RiverbedError(
                f"truncated LAS: EVLR {i + 1} of {count} (at byte {pos}, {length} bytes) runs past the end "
                f"of the file ({size} bytes)",
                path,
            )
        pos += _EVLR_HEADER + length


def _check_laz(f, path, header, vlr):
    """Check the LASzip VLR and the chunk table, so that lazrs is only ever asked bounded work."""
    if vlr is None:
        raise RiverbedError("malformed LAZ: compressed point format but no LASzip VLR", path)
    if len(vlr) < 34:
        raise RiverbedError(f"malformed LAZ: LASzip VLR of {len(vlr)} bytes (at least 34 expected)", path)
    compressor, coder = struct.unpack_from("<HH", vlr, 0)
    (chunk_size,) = struct.unpack_from("<I", vlr, 12)
    (n_items,) = struct.unpack_from("<H", vlr, 32)
    if compressor not in (2, 3):
        name = _COMPRESSOR_NAMES.get(compressor, "unknown")
        raise RiverbedError(
            f"unsupported LAZ compressor {compressor} ({name}); re-compress it with LASzip 2 or later",
            path,
        )
    if coder != 0:
        raise RiverbedError(f"malformed LAZ: unknown LASzip coder {coder}", path)
    if len(vlr) != 34 + 6 * n_items:
        raise RiverbedError(f"malformed LAZ: LASzip VLR of {len(vlr)} bytes for {n_items} items", path)
    items = [struct.unpack_from("<HH", vlr, 34 + 6 * k) for k in range(n_items)]  # (type, size)
    item_bytes = sum(size for _, size in items)
    if item_bytes != header.record_length:
        raise RiverbedError(
            f"malformed LAZ: LASzip items total {item_bytes} bytes, the header's point record length is "
            f"{header.record_length}",
            path,
        )
    variable = chunk_size == 0xFFFFFFFF
    if not variable and (chunk_size == 0 or chunk_size * header.record_length > MAX_CHUNK_BYTES):
        raise RiverbedError(f"malformed LAZ: chunk size {chunk_size} points", path)

    # The chunk table: its offset is the first 8 bytes of the point data, or (a writer that could not
    # seek back) the last 8 bytes of the file, as lazrs reads it.
    data_start = header.offset + 8
    f.seek(header.offset)
    raw = f.read(8)
    if len(raw) < 8:
        raise RiverbedError("truncated LAZ: no room for the chunk table offset", path)
    (table,) = struct.unpack("<q", raw)
    if table <= header.offset:
        f.seek(header.size - 8)
        (table,) = struct.unpack("<q", f.read(8))
        if table <= header.offset:
            raise RiverbedError("malformed LAZ: no chunk table", path)
    if table + 8 > header.size:
        raise RiverbedError(
            f"truncated LAZ: chunk table at byte {table}, past the end of the file ({header.size} bytes)", path
        )
    if table < data_start:
        raise RiverbedError(f"malformed LAZ: chunk table at byte {table}, before the point data", path)
    f.seek(table)
    _, n_chunks = struct.unpack("<II", f.read(8))
    data_bytes = table - data_start
    if n_chunks == 0 or n_chunks > data_bytes // _MIN_CHUNK_BYTES:
        raise RiverbedError(
            f"malformed LAZ: chunk table lists {n_chunks} chunks for {data_bytes} compressed bytes", path
        )
    if not variable and n_chunks != math.ceil(header.point_count / chunk_size):
        raise RiverbedError(
            f"malformed LAZ: the header declares {header.point_count} points, but the chunk table lists "
            f"{n_chunks} chunk(s) of {chunk_size}",
            path,
        )

    # n_chunks is now bounded by the file size, so lazrs can decode the table without a huge allocation.
    f.seek(header.offset)
    with _native_errors(path, "LAZ chunk table"):
        entries = lazrs.read_chunk_table(f, lazrs.LazVlr(vlr))
    if len(entries) != n_chunks:
        raise RiverbedError("malformed LAZ: chunk table cannot be decoded", path)
    # Entries are decoded as i32 and widened, so a corrupt table shows up as huge counts.
    counts = np.array([e[0] for e in entries], dtype=np.uint64)
    sizes = np.array([e[1] for e in entries], dtype=np.uint64)
    total_bytes = int(sizes.sum(dtype=object))
    if total_bytes > data_bytes:
        raise RiverbedError(
            f"malformed LAZ: chunk table lists {total_bytes} compressed bytes, the file holds {data_bytes}",
            path,
        )
    if compressor == 3:
        _check_layers(f, path, header, items, data_start, sizes)
    if variable:
        if int(counts.max()) * header.record_length > MAX_CHUNK_BYTES:
            raise RiverbedError(f"malformed LAZ: a chunk of {int(counts.max())} points", path)
        total_points = int(counts.sum(dtype=object))
        if total_points != header.point_count:
            raise RiverbedError(
                f"malformed LAZ: the header declares {header.point_count} points, the chunk table holds "
                f"{total_points}",
                path,
            )


def _check_layers(f, path, header, items, data_start, sizes):
    """Layered chunks (LAZ 1.4, formats 6-10) state the byte size of each layer; lazrs allocates and
    zero-fills a buffer of that size before reading it, so a forged size costs up to 4 GiB per layer."""
    n_layers = 0
    for item_type, item_size in items:
        if item_type not in _LAYERS:
            raise RiverbedError(f"malformed LAZ: item type {item_type} in a layered-chunked file", path)
        n_layers += item_size if item_type == 14 else _LAYERS[item_type]
    # Each chunk: the first point raw, a u32 point count, one u32 size per layer, then the layers.
    fixed = header.record_length + 4 + 4 * n_layers
    start = data_start
    for i, size in enumerate(sizes.tolist()):
        f.seek(start + header.record_length + 4)
        raw = f.read(4 * n_layers)
        layers = sum(struct.unpack(f"<{n_layers}I", raw)) if len(raw) == 4 * n_layers else None
        if layers is None or fixed + layers > size:
            raise RiverbedError(
                f"malformed LAZ: the layers of chunk {i + 1} of {len(sizes)} overrun its {size} bytes", path
            )
        start += size


@contextmanager
def _native_errors(path, what):
    """Turn whatever laspy/lazrs/pyproj raise into a one-line RiverbedError naming the file."""
    try:
        yield
    except RiverbedError:
        raise
    except (MemoryError, KeyboardInterrupt, SystemExit, GeneratorExit):
        raise
    except BaseException as e:  # noqa: BLE001 - lazrs panics arrive as pyo3's PanicException (BaseException)
        text = " ".join(str(e).split()) or type(e).__name__
        if len(text) > 160:
            text = text[:157] + "..."
        if type(e).__name__ == "PanicException":
            text = f"lazrs panicked: {text}"
        raise RiverbedError(f"cannot read {what} ({text})", path) from None


# ---------------------------------------------------------------------------------------------------------
# LAS / LAZ: reading through laspy


def _open_laspy(path):
    with _native_errors(path, "LAS header"):
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
            with _native_errors(path, "point data"):
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
