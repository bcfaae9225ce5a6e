"""Checks of an untrusted LAS/LAZ (and COPC) file before laspy or lazrs reads it.

Files come from strangers, and laspy/lazrs trust their headers: a forged VLR count makes laspy loop for
ever (PDAL's ``garbage_nVariableLength.las``), a forged chunk count or chunk size makes lazrs allocate
gigabytes (a failed allocation in Rust aborts the whole process, which no ``except`` can catch), and an old
LASzip 1.x "pointwise" file makes lazrs panic. So before laspy sees a file, :func:`check_las_header` (called by
:mod:`riverbed_cli.io.lidar`) checks the header against the file size with plain byte parsing:

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
``BaseException``) becomes, through :func:`native_errors`, a one-line :class:`RiverbedError` naming the file.
"""

import logging
import math
import struct
from contextlib import contextmanager
from dataclasses import dataclass

import lazrs
import numpy as np

from ..errors import RiverbedError

#: Largest decompressed LAZ chunk accepted (points x record length). LASzip writes 50,000-point chunks
#: (~2-3 MB) and COPC nodes are of the same order; lazrs allocates a whole chunk at once.
MAX_CHUNK_BYTES = 256 * 2**20

_HEADER_SIZE = {0: 227, 1: 227, 2: 227, 3: 235, 4: 375}  # by minor version
# Size of each point format's standard fields (the record may be longer: extra bytes).
_RECORD_SIZE = {0: 20, 1: 28, 2: 26, 3: 34, 4: 57, 5: 63, 6: 30, 7: 36, 8: 38, 9: 59, 10: 67}
log = logging.getLogger("riverbed_cli.io.lidar")  # the readers' logger: their warnings in one place

_VLR_HEADER = 54
_EVLR_HEADER = 60
_LASZIP_USER_ID = b"laszip encoded"
_LASZIP_RECORD_ID = 22204
_COMPRESSOR_NAMES = {0: "none", 1: "pointwise, LASzip 1.x", 2: "pointwise chunked", 3: "layered chunked"}
_MIN_CHUNK_BYTES = 20  # a LAZ chunk starts with its first point stored raw, and a point is >= 20 bytes
# Layers per LASzip item in layered chunks: point14 9, RGB14 1, RGBNIR14 2, wavepacket14 1, byte14 one
# per byte (lazrs las/point6.rs, rgb.rs, nir.rs, wavepacket.rs, extra_bytes.rs).
_LAYERS = {10: 9, 11: 1, 12: 2, 13: 1, 14: None}


@dataclass
class LasHeader:
    """What :func:`check_las_header` read from a LAS/LAZ header, once checked against the file size."""

    size: int
    minor: int
    point_format: int
    compressed: bool
    record_length: int
    point_count: int
    offset: int


def check_las_header(path):
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
            if pos == space:
                # The header overstates its VLR count: the VLRs it has end exactly where the point data starts.
                # laspy reads such a file (the points are where the header says); say so and read it.
                log.warning("%s: the LAS header declares %d VLRs but only %d fit before the point data (byte %d); "
                            "the points are read", path, n_vlr, i, offset)
                break
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

        header = LasHeader(size, minor, point_format, compressed, record_length, point_count, offset)
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
    with native_errors(path, "LAZ chunk table"):
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
def native_errors(path, what):
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
