"""Blocks: every pair of an aerial block through ``project -> match -> dsm``, merged into one DSM, on dask.distributed.

The manifest (YAML, read with ``yaml.safe_load`` only; paths relative to the manifest's folder)::

    defaults:                  # optional; settings for every pair
      resolution: 0.5          # block-wide (defaults only): DSM cell size in CRS units
      crs: EPSG:32632          # block-wide: CRS of the DSMs and point clouds (default: the pairs')
      agg: max                 # block-wide: per-cell aggregation, max | mean | median | idw
      guide: riverbed          # matcher: guide window census paths p1 p2 subpixel median lr_check
      min_disp: 0              #          min_disp max_disp max_pixels
      tile: auto               # tiling: tile (px, or auto as match_tiled) overlap lidar_range
      drop_classes: [7, 18]    # projection: outliers visibility side footprint classes drop_classes
                               #             registration (a 4x4 file) lidar_crs
    pairs:
      - raw: {left: raw/f0.png, left_orientation: raw/f0.yaml,   # or raw frames with their orientations
              right: raw/f1.png, right_orientation: raw/f1.yaml}   # (riverbed rectify's inputs): rectified into
        cloud: lidar.laz                                           # OUTDIR/pairs/NAME/rectified/ first; optional
                                                                   # alpha (0..1, -1) and size (WxH) as rectify's
      - pair: a/pair.yaml      # a pair file naming the rectified left and right images
        cloud: lidar/*.laz     # a path, a glob or a list of them (several clouds: per pixel the nearer point)
        name: a                # optional; default the pair file's path without suffix, '/' -> '_' (a_pair)
        window: 7              # per-pair override of any setting except the block-wide ones

Outputs (``OUTDIR``)::

    block.json                 marker (the manifest's path) and the record of the last merge
    dsm.tif                    merged DSM of all finished pairs (cloud-optimised GeoTIFF)
    pairs/NAME/sparse.tif      projected LiDAR disparities
    pairs/NAME/disparity.tif   dense disparity (d = x_left - x_right, NaN invalid)
    pairs/NAME/points.laz      triangulated points, RGB from the left image, CRS
    pairs/NAME/dsm.tif         the pair's DSM, on the block's grid when ``resolution`` is given
    pairs/NAME/done.json       written last: size and sha256 of each output, hash of the settings and inputs

Rules
-----
- *Skipping*: a pair is skipped when its ``done.json`` verifies: every output present with the recorded size and
  sha256, and the recorded hash equal to the hash of the pair's effective settings, its inputs (pair file, images,
  clouds, registration: path, size, mtime) and the riverbed version. Anything else re-runs the pair.
- *Overwriting*: ``OUTDIR`` may be new (its parent must exist), empty, or the output of the same manifest (its
  ``block.json`` names it); the block then replaces its own files (the per-pair outputs of the pairs it runs, the
  merged DSM, ``block.json``) without ``--overwrite``. A folder holding anything else, or another manifest's
  block, needs ``--overwrite``. Nothing outside ``pairs/NAME/`` of the manifest's pairs, ``dsm.tif`` and
  ``block.json`` is ever written or removed. Every file is written under a temporary name and renamed.
- *Failures*: a pair that fails is reported (name, stage, one-line error) and the others go on; the merged DSM is
  built from the pairs that finished (this run or before). Bad input (:class:`RiverbedError`) is not retried; any
  other exception is retried up to ``retries`` times (dask ``retries``), and a task whose worker died is rerun
  elsewhere up to ``retries`` times (``distributed.scheduler.allowed-failures``, set on the local cluster; an
  existing cluster keeps its scheduler's setting).
- *Merging*: the merged DSM is rasterised from the per-pair LAZ files, streamed in chunks into one
  :class:`~riverbed_cli.products.dsm.Accumulator` on one grid snapped to multiples of the resolution, so every
  aggregation (median and mean included) is exact over the union of the points, not a mosaic of per-pair rasters.
  Its heights are those of the LAZ files (1 mm quantisation). Without ``resolution`` each pair's DSM takes its own
  ground sample distance and the merged DSM the median of those.

Task graph (dask.distributed, one set per pair to run)::

    project(pair) ──► tile(pair, 0) ──┐
                 ├──► tile(pair, 1) ──┼──► finish(pair)   (stitch, disparity.tif, points.laz, dsm.tif, done.json)
                 └──► ...           ──┘
    all finish ───────────────────────────► merge (OUTDIR/dsm.tif)

``project`` projects the clouds, writes ``sparse.tif`` and plans the matching as
:func:`~riverbed_cli.scale.tiles.match_tiled` would (tile size, ``"auto"`` included, LiDAR tile ranges, one riverbed
window, one 16-bit scale); for a pair larger than the tile it copies the images to ``pairs/NAME/.work/*.npy``. The
client submits every project task at once and, as each one finishes, that pair's tile tasks (they take the project
future as an argument, so the scheduler knows the dependency and recomputes it if its worker dies) and its finish
task (depends on the project and all its tiles). Each tile task reads its crops from disk (memory-mapped images, a
window of ``sparse.tif``) and returns the tile's disparities, computed with the arithmetic of ``match_tiled``'s loop;
a pair no larger than the tile is one task running :func:`~riverbed_cli.matching.pipeline.match_pair` on the whole
images. ``workers=0`` runs the same task functions in order, without dask.

Numba: each task sets its thread's Numba threads to ``CPUs // (workers * threads_per_worker)`` on a local cluster
(on an existing cluster: the worker host's CPUs // the worker's threads).
"""

import contextlib
import glob
import hashlib
import inspect
import json
import logging
import math
import os
import re
import shutil
import statistics
import time
import uuid
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..errors import RiverbedError
from ..io.textfiles import parse_yaml, read_text
from ..io.atomic import atomic_output

log = logging.getLogger(__name__)

#: Manifests larger than this are refused before parsing.
MANIFEST_MAX_BYTES = 10_000_000
TOP_KEYS = ("defaults", "pairs")
PAIR_KEYS = ("pair", "raw", "cloud", "name")
RAW_KEYS = ("left", "left_orientation", "right", "right_orientation")
#: Optional rectification settings of a ``raw:`` entry (as ``riverbed rectify --alpha / --size``).
RAW_OPTIONS = ("alpha", "size")
#: Settings that shape the merged DSM: one value for the whole block, given under ``defaults`` only.
BLOCK_KEYS = ("resolution", "crs", "agg")
OUTPUTS = ("sparse.tif", "disparity.tif", "points.laz", "dsm.tif")
DONE = "done.json"
MARKER = "block.json"
WORK = ".work"
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}")
_GLOB = re.compile(r"[*?\[]")


# -- settings -------------------------------------------------------------------------------------------------------

class _Bad(Exception):
    """A setting's value is wrong; the message says what was expected."""


def _show(v):
    return repr(v) if not isinstance(v, str) else f"'{v}'"


def _int(lo=None, hi=None, none=False):
    desc = "an integer" + (f" >= {lo}" if lo is not None and hi is None else "")
    if lo is not None and hi is not None:
        desc = f"an integer from {lo} to {hi}"
    if none:
        desc += " or null"

    def check(v):
        if v is None and none:
            return None
        if isinstance(v, bool) or not isinstance(v, int) or (lo is not None and v < lo) or (hi is not None and v > hi):
            raise _Bad(f"expected {desc}, got {_show(v)}")
        return int(v)
    return check


def _choice(options):
    def check(v):
        if v not in options:
            raise _Bad(f"expected one of {', '.join(map(str, options))}, got {_show(v)}")
        return v
    return check


def _bool(v):
    if not isinstance(v, bool):
        raise _Bad(f"expected true or false, got {_show(v)}")
    return v


def _resolution(v):
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0):
        raise _Bad(f"expected a positive number (CRS units) or null, got {_show(v)}")
    return float(v)


def _crs(v):
    if v is None:
        return None
    if isinstance(v, int) and not isinstance(v, bool):
        v = f"EPSG:{v}"
    if not isinstance(v, str) or not v.strip():
        raise _Bad(f"expected a CRS such as EPSG:32632, got {_show(v)}")
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    try:
        CRS.from_user_input(v)
    except CRSError:
        raise _Bad(f"unknown CRS '{v}'") from None
    return v


def _window(v):
    if v == "auto":
        return v
    if isinstance(v, bool) or not isinstance(v, int) or v < 1 or v % 2 == 0:
        raise _Bad(f"expected 'auto' or an odd positive integer, got {_show(v)}")
    return v


def _census(v):
    from ..matching.census import parse_census_window

    if not isinstance(v, str) and not (isinstance(v, list) and len(v) == 2
                                       and all(isinstance(x, int) and not isinstance(x, bool) for x in v)):
        raise _Bad(f"expected WIDTHxHEIGHT such as 9x7, got {_show(v)}")
    try:
        w, h = parse_census_window(v)
    except RiverbedError as e:
        raise _Bad(str(e)) from None
    return f"{w}x{h}"


def _tile(v):
    if v == "auto":
        return v
    if isinstance(v, bool) or not isinstance(v, int) or v < 16:
        raise _Bad(f"expected 'auto' or an integer >= 16 (px), got {_show(v)}")
    return v


def _footprint(v):
    if v == "auto":
        return v
    if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 50:
        raise _Bad(f"expected 'auto' or an integer from 0 to 50 (px), got {_show(v)}")
    return v


def _classes(none):
    def check(v):
        if v is None and none:
            return None
        if v is None:
            return []
        if not isinstance(v, list) or not all(isinstance(c, int) and not isinstance(c, bool) and 0 <= c <= 255
                                              for c in v):
            raise _Bad(f"expected a list of class numbers 0..255{' or null' if none else ''}, got {_show(v)}")
        return sorted(set(v))
    return check


def _optional_str(v):
    if v is None:
        return None
    if not isinstance(v, str) or not v:
        raise _Bad(f"expected a file name or null, got {_show(v)}")
    return v


def _settings_spec():
    from ..geometry.projection import NOISE_CLASSES, OUTLIERS, SIDES, VISIBILITY
    from ..geometry.visibility import ZBUFFER_RADIUS
    from ..io.images import MAX_PIXELS
    from ..matching import pipeline
    from ..matching.pipeline import GUIDES, MatchParams
    from ..products.dsm import AGGREGATIONS
    from .tiles import match_tiled

    # tile and overlap defaults in step with match_tiled's
    tiled = {k: v.default for k, v in inspect.signature(match_tiled).parameters.items()}
    mp = MatchParams()
    return {
        # block-wide
        "resolution": (None, _resolution),
        "crs": (None, _crs),
        "agg": ("max", _choice(AGGREGATIONS)),
        # matching
        "guide": (mp.guide, _choice(GUIDES)),
        **({"matcher": (mp.matcher, _choice(pipeline.MATCHERS))} if hasattr(pipeline, "MATCHERS") else {}),
        "window": (mp.window, _window),
        "census": ("x".join(map(str, mp.census)), _census),
        "paths": (mp.paths, _choice((4, 8, 16))),
        "p1": (mp.p1, _int(0)),
        "p2": (mp.p2, _int(0)),
        "subpixel": (mp.subpixel, _bool),
        "median": (mp.median, _int(0, 15)),
        "lr_check": (mp.lr_check, _bool),
        "min_disp": (None, _int(-100_000, 100_000, none=True)),
        "max_disp": (None, _int(-100_000, 100_000, none=True)),
        "max_pixels": (MAX_PIXELS, _int(1)),
        # tiling
        "tile": (tiled["tile"], _tile),
        "overlap": (tiled["overlap"], _int(0)),
        "lidar_range": (tiled["lidar_range"], _bool),
        # projection
        "outliers": ("sor", _choice(OUTLIERS)),
        "visibility": ("zbuffer", _choice(VISIBILITY)),
        "side": ("both", _choice(SIDES)),
        "footprint": (ZBUFFER_RADIUS, _footprint),
        "classes": (None, _classes(none=True)),
        "drop_classes": (sorted(NOISE_CLASSES), _classes(none=False)),
        "registration": (None, _optional_str),
        "lidar_crs": (None, _crs),
    }


def default_settings():
    """The effective settings of a pair when the manifest gives none (a fresh dict)."""
    return {k: (list(d) if isinstance(d, list) else d) for k, (d, _) in _settings_spec().items()}


# -- manifest -------------------------------------------------------------------------------------------------------

@dataclass
class PairSpec:
    """One entry of ``pairs:`` after validation: absolute paths and the effective settings."""

    index: int
    name: str
    pair: Path  # for a raw entry: None until plan_block has rectified it
    clouds: list
    settings: dict
    raw: dict = None  # raw frames and orientations (absolute paths), rectified by plan_block


@dataclass
class Manifest:
    path: Path
    defaults: dict
    pairs: list


def _read_manifest(path):
    return parse_yaml(read_text(path, "block manifest", MANIFEST_MAX_BYTES), path)


def _settings(raw, where, spec, path, base, block_wide):
    out = {}
    for key, value in raw.items():
        if key in BLOCK_KEYS and not block_wide:
            raise RiverbedError(f"{where}.{key}: a block-wide setting; give it under defaults", path)
        try:
            out[key] = spec[key][1](value)
        except _Bad as e:
            raise RiverbedError(f"{where}.{key}: {e}", path) from None
        if key == "registration" and out[key] is not None:
            reg = Path(os.path.normpath(base / out[key]))
            if not reg.is_file():
                raise RiverbedError(f"{where}.registration: file not found: {value}", path)
            out[key] = str(reg)
    return out


def _clouds(value, where, path, base):
    items = value if isinstance(value, list) else [value]
    if not items or not all(isinstance(v, str) and v for v in items):
        raise RiverbedError(f"{where}.cloud: expected a file name, a glob or a list of them, got {_show(value)}",
                            path)
    found = []
    for item in items:
        full = base / item
        if _GLOB.search(item):
            hits = sorted(Path(p) for p in glob.glob(str(full), recursive=True) if Path(p).is_file())
            if not hits:
                raise RiverbedError(f"{where}.cloud: '{item}' matches no file", path)
            found += hits
        elif not full.is_file():
            raise RiverbedError(f"{where}.cloud: file not found: {item}", path)
        else:
            found.append(full)
    out = []
    for p in found:
        p = Path(os.path.normpath(p.absolute()))
        if p not in out:
            out.append(p)
    return out


def _raw_frames(value, where, path, base):
    """The ``raw:`` entry of a pair: two frame images and their orientation files (riverbed rectify's inputs)."""
    if not isinstance(value, dict):
        raise RiverbedError(f"{where}.raw: expected a mapping with {', '.join(RAW_KEYS)}, got {_show(value)}", path)
    unknown = [str(k) for k in value if k not in RAW_KEYS + RAW_OPTIONS]
    if unknown:
        raise RiverbedError(f"{where}.raw: unknown key '{unknown[0]}' (raw keys: {', '.join(RAW_KEYS + RAW_OPTIONS)})",
                            path)
    from ..geometry.rectify import check_alpha, parse_size

    out = {}
    try:
        out["alpha"] = check_alpha(value.get("alpha", 0.0))
    except ValueError as e:
        raise RiverbedError(f"{where}.raw.alpha: {e}", path) from None
    try:
        out["size"] = None if value.get("size") is None else parse_size(value["size"])
    except ValueError as e:
        raise RiverbedError(f"{where}.raw.size: {e}", path) from None
    for key in RAW_KEYS:
        v = value.get(key)
        if not isinstance(v, str) or not v:
            raise RiverbedError(f"{where}.raw.{key}: missing (a file name)", path)
        p = Path(os.path.normpath(base / v))
        if not p.is_file():
            raise RiverbedError(f"{where}.raw.{key}: file not found: {v}", path)
        out[key] = p
    return out


def rectify_raw(spec, outdir):
    """Rectify a raw entry into ``outdir/pairs/NAME/rectified/`` (unless done for the same inputs); its pair file."""
    from ..geometry.rectify import rectify_files

    folder = Path(outdir) / "pairs" / spec.name / "rectified"
    stamp = folder / "inputs.json"
    r = spec.raw
    # the stamp holds the inputs and the settings: changing alpha or size re-rectifies
    inputs = [_stat(r[k], r[k].parent) for k in RAW_KEYS] + [
        {"alpha": r["alpha"], "size": list(r["size"]) if r["size"] else None}]
    if (folder / "pair.yaml").is_file() and stamp.is_file() and json.loads(stamp.read_text()) == inputs:
        return folder / "pair.yaml"
    folder.parent.mkdir(parents=True, exist_ok=True)
    rectify_files(r["left"], r["left_orientation"], r["right"], r["right_orientation"], folder, overwrite=True,
                  alpha=r["alpha"], size=r["size"])
    _write_json(stamp, inputs)
    return folder / "pair.yaml"


def default_name(pair_path, base):
    """A pair's default name: its pair file's path relative to the manifest, without suffix, '/' -> '_'."""
    rel = Path(os.path.relpath(pair_path, base)).with_suffix("")
    parts = [re.sub(r"[^A-Za-z0-9._-]", "_", p) for p in rel.parts if p not in ("..", ".", "")]
    name = "_".join(parts).lstrip("._-") or "pair"
    return name[:100]


def load_manifest(path):
    """Read and validate a block manifest.

    Raises :class:`RiverbedError` with one line naming the manifest and the key (``MANIFEST: pairs[1].cloud:
    'lidar/*.laz' matches no file``; pairs are numbered from 0) for: unreadable YAML, unknown keys, a missing pair
    file, a cloud glob matching nothing, a bad value, duplicate names, a block-wide setting given per pair.
    """
    path = Path(path)
    data = _read_manifest(path)
    base = path.absolute().parent
    if not isinstance(data, dict):
        raise RiverbedError("not a block manifest (expected a mapping with 'pairs')", path)
    unknown = [str(k) for k in data if k not in TOP_KEYS]
    if unknown:
        raise RiverbedError(f"unknown key '{unknown[0]}' (manifest keys: {', '.join(TOP_KEYS)})", path)
    spec = _settings_spec()
    defaults = data.get("defaults") or {}
    if not isinstance(defaults, dict):
        raise RiverbedError(f"defaults: expected a mapping of settings, got {type(defaults).__name__}", path)
    unknown = [str(k) for k in defaults if k not in spec]
    if unknown:
        raise RiverbedError(f"defaults: unknown key '{unknown[0]}' (settings: {', '.join(spec)})", path)
    defaults = _settings(defaults, "defaults", spec, path, base, block_wide=True)
    pairs = data.get("pairs")
    if not isinstance(pairs, list) or not pairs:
        raise RiverbedError("pairs: expected a non-empty list of {pair: PAIR_FILE, cloud: CLOUDS}", path)
    specs, names = [], {}
    for i, entry in enumerate(pairs):
        where = f"pairs[{i}]"
        if not isinstance(entry, dict):
            raise RiverbedError(f"{where}: expected a mapping with pair and cloud, got {_show(entry)}", path)
        unknown = [str(k) for k in entry if k not in PAIR_KEYS and k not in spec]
        if unknown:
            raise RiverbedError(f"{where}: unknown key '{unknown[0]}' (pair keys: {', '.join(PAIR_KEYS)}, and "
                                "the settings of defaults)", path)
        if "cloud" not in entry:
            raise RiverbedError(f"{where}.cloud: missing", path)
        if ("pair" in entry) == ("raw" in entry):
            raise RiverbedError(f"{where}: give either pair (a rectified pair file) or raw (frames and orientations)",
                                path)
        raw = None
        if "raw" in entry:
            raw = _raw_frames(entry["raw"], where, path, base)
            pair_path = None
        else:
            value = entry["pair"]
            if not isinstance(value, str) or not value:
                raise RiverbedError(f"{where}.pair: expected a file name, got {_show(value)}", path)
            pair_path = Path(os.path.normpath(base / value))
            if not pair_path.is_file():
                raise RiverbedError(f"{where}.pair: file not found: {value}", path)
        clouds = _clouds(entry["cloud"], where, path, base)
        name = entry.get("name")
        if name is None:
            name = default_name(pair_path if raw is None else raw["left_orientation"], base)
        elif not isinstance(name, str) or not _NAME.fullmatch(name):
            raise RiverbedError(f"{where}.name: expected letters, digits, '.', '_' or '-' (at most 100, not "
                                f"starting with '.', '_' or '-'), got {_show(name)}", path)
        if name in names:
            raise RiverbedError(f"{where}.name: '{name}' is already the name of pairs[{names[name]}]; give each "
                                "pair a unique name", path)
        names[name] = i
        overrides = {k: v for k, v in entry.items() if k not in PAIR_KEYS}
        settings = {**default_settings(), **defaults,
                    **_settings(overrides, where, spec, path, base, block_wide=False)}
        lo, hi = settings["min_disp"], settings["max_disp"]
        if lo is not None and hi is not None and lo > hi:
            raise RiverbedError(f"{where}: min_disp {lo} > max_disp {hi}", path)
        specs.append(PairSpec(i, name, pair_path, clouds, settings, raw))
    return Manifest(path.absolute(), {**default_settings(), **defaults}, specs)


# -- planning -------------------------------------------------------------------------------------------------------

@dataclass
class PairJob:
    """Everything a worker needs to run one pair (picklable; absolute paths as strings)."""

    name: str
    index: int
    pair: str
    clouds: list
    settings: dict
    folder: str
    shape: tuple = None  # (H, W)
    settings_hash: str = ""
    inputs: list = field(default_factory=list)
    status: str = "run"  # run | skip | failed (at planning)
    error: str = None
    record: dict = None  # done.json of a skipped pair


@dataclass
class BlockPlan:
    manifest: Manifest
    outdir: Path
    jobs: list
    seconds: float = 0.0  # validating, stat-ing inputs, verifying finished pairs (sha256 of their outputs)

    @property
    def to_run(self):
        return [j for j in self.jobs if j.status == "run"]


def _version():
    try:
        from importlib.metadata import version

        return version("riverbed")
    except Exception:  # noqa: BLE001 - not installed (a source checkout): the hash just leaves it out
        return "unknown"


def _image_size(path):
    """``(H, W)`` from an image header (GDAL), without decoding the pixels when it can."""
    import warnings

    import rasterio

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            with rasterio.open(path) as ds:
                return ds.height, ds.width
    except Exception:  # noqa: BLE001 - GDAL cannot read it: decode it the usual way (one-line errors)
        from ..io.images import read_image

        return read_image(path).shape[:2]


def _stat(path, base):
    """Path (relative to the manifest's folder when inside it, so a block folder can move), size and mtime."""
    path = Path(os.path.normpath(Path(path).absolute()))
    st = path.stat()
    shown = path.relative_to(base) if path.is_relative_to(base) else path
    return {"path": shown.as_posix(), "size": st.st_size, "mtime_ns": st.st_mtime_ns}


def _hash_json(obj):
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()


def sha256_file(path, chunk=1 << 20):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(chunk), b""):
            h.update(block)
    return h.hexdigest()


def verify_done(folder, settings_hash):
    """The pair's ``done.json`` if it verifies (outputs present, sizes and sha256 as recorded, same settings hash),
    else None."""
    folder = Path(folder)
    try:
        record = json.loads((folder / DONE).read_text(encoding="utf-8"))
        if record.get("settings_hash") != settings_hash:
            return None
        outputs = record["outputs"]
        for name in OUTPUTS:
            p = folder / name
            if not p.is_file() or p.stat().st_size != outputs[name]["size"]:
                return None
        for name in OUTPUTS:
            if sha256_file(folder / name) != outputs[name]["sha256"]:
                return None
        return record
    except (OSError, ValueError, KeyError, TypeError):
        return None


def prepare_outdir(outdir, manifest_path, overwrite=False):
    """Check (and create) the output folder by the rule in the module notes; write its ``block.json`` marker."""
    out = Path(outdir)
    marker = out / MARKER
    record = {}
    if out.exists():
        if not out.is_dir():
            raise RiverbedError("output exists and is not a folder", out)
        if marker.is_file():
            try:
                record = json.loads(marker.read_text(encoding="utf-8"))
            except (OSError, ValueError):
                record = {}
            owner = record.get("manifest") if isinstance(record, dict) else None
            if owner != str(manifest_path) and not overwrite:
                raise RiverbedError(f"holds the block of another manifest ({owner}); pass --overwrite to reuse "
                                    "it", out)
        elif any(out.iterdir()) and not overwrite:
            raise RiverbedError("output folder is not empty and holds no block; pass --overwrite to write into "
                                "it", out)
    else:
        parent = out.parent if str(out.parent) else Path(".")
        if not parent.is_dir():
            raise RiverbedError(f"output folder {parent} does not exist", out)
        out.mkdir()
    if not isinstance(record, dict) or record.get("manifest") != str(manifest_path):
        record = {}
    record.update({"riverbed": "block", "manifest": str(manifest_path)})
    _write_json(marker, record)
    return record


def _write_json(path, obj):
    with atomic_output(path, overwrite=True) as tmp:
        tmp.write_text(json.dumps(obj, indent=2, default=_plain) + "\n", encoding="utf-8")


def _plain(o):
    if hasattr(o, "item") and getattr(o, "ndim", 1) == 0:
        return o.item()
    if hasattr(o, "tolist"):
        return o.tolist()
    return str(o)


def plan_block(manifest, outdir, overwrite=False):
    """Validate the manifest, prepare ``outdir`` and decide per pair: run, skip (verified ``done.json``) or failed
    (its pair file or images cannot be read)."""
    from ..io.pairfile import load_pairfile

    t0 = time.perf_counter()
    if not isinstance(manifest, Manifest):
        manifest = load_manifest(manifest)
    outdir = Path(outdir).absolute()
    prepare_outdir(outdir, manifest.path, overwrite)
    base = manifest.path.parent
    version = _version()
    jobs = []
    for spec in manifest.pairs:
        s = spec.settings
        job = PairJob(spec.name, spec.index, str(spec.pair), [str(c) for c in spec.clouds], s,
                      str(outdir / "pairs" / spec.name))
        jobs.append(job)
        try:
            if spec.raw is not None:
                # raw frames: rectify first (cheap, here in the planner), then the pair runs like any other
                spec.pair = rectify_raw(spec, outdir)
                job.pair = str(spec.pair)
            pair = load_pairfile(spec.pair)
            for side in ("left", "right"):
                if getattr(pair, side) is None:
                    raise RiverbedError(f"{side}: missing (a block needs the rectified images)", spec.pair)
            shape = pair.image_size or _image_size(pair.left)
            job.shape = tuple(int(v) for v in shape)
            raw_files = [spec.raw[k] for k in RAW_KEYS] if spec.raw else []
            files = [spec.pair, pair.left, pair.right, *spec.clouds, *raw_files]
            if s["registration"]:
                files.append(Path(s["registration"]))
            job.inputs = [_stat(p, base) for p in files]
        except RiverbedError as e:
            job.status, job.error = "failed", str(e)
            continue
        except OSError as e:
            job.status, job.error = "failed", f"{e.filename or ''}: {e.strerror or e}"
            continue
        job.settings_hash = _hash_json({"name": spec.name, "settings": s, "inputs": job.inputs,
                                        "riverbed": version})
        record = verify_done(job.folder, job.settings_hash)
        if record is not None:
            job.status, job.record = "skip", record
    return BlockPlan(manifest, outdir, jobs, time.perf_counter() - t0)


# -- the per-pair stages (plain functions; tasks on dask) -----------------------------------------------------------

class PairFailure:
    """Bad input found by a stage: returned (not raised) so dask does not retry it; later stages pass it on."""

    def __init__(self, stage, message):
        self.stage, self.message = stage, message

    def __repr__(self):
        return f"PairFailure({self.stage!r}, {self.message!r})"


def _match_params(s):
    from ..matching.pipeline import MatchParams

    keys = ("guide", "matcher", "window", "census", "paths", "p1", "p2", "subpixel", "median", "lr_check")
    return MatchParams(**{k: s[k] for k in keys if k in s})


def _cloud_may_land(path, pair, reg, shape):
    """False when the cloud's header box cannot project into the left image (all corners in front of the camera
    and their image hull outside it): such a cloud is not read at all."""
    from ..io.lidar import lidar_info

    info = lidar_info(path)  # validates the header: a corrupt file fails here
    if info.point_count == 0:
        return False
    corners = np.array(np.meshgrid(*zip(info.mins, info.maxs))).T.reshape(-1, 3)
    local = pair.lidar_to_local(corners, reg)
    x, y, _, depth = pair.project(local)
    if not (depth > 0).all():
        return True
    H, W = shape
    return not (x.max() < -0.5 or x.min() >= W - 0.5 or y.max() < -0.5 or y.min() >= H - 0.5)


_EMPTY_CLOUD = ("no point lands in both images", "no point is left after")


def _clean_temps(folder, names):
    """Remove temporary files a killed task left behind (``.STEM.XXXXXXXX.tmp.SUFFIX``, see io.atomic)."""
    for name in names:
        p = Path(name)
        for tmp in Path(folder).glob(f".{glob.escape(p.stem)}.*.tmp{p.suffix}"):
            with contextlib.suppress(OSError):
                tmp.unlink()


def _image_source(path, shape, max_pixels):
    """The image as a windowed TIFF or an in-memory array, checked against the pair's size and the pixel limit."""
    from ..io.images import _check_pixels
    from .tiles import open_windowed

    H, W = shape
    _check_pixels(path, H, W, max_pixels)
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


def project_stage(job):
    """Project the pair's clouds into sparse disparities (``sparse.tif``) and plan the matching.

    Several clouds: each is projected alone and, per pixel, the larger disparity (the nearer point) is kept;
    clouds whose box misses the left image are not read, and a cloud with no point in the pair is ignored as
    long as another one has points. A pair larger than the tile is planned as :func:`match_tiled` plans it (tile
    size, LiDAR tile ranges, one riverbed window and one 16-bit scale for all tiles) and its images are copied
    to ``.work/*.npy`` for the tile tasks to read crops from. Returns a small dict: ``tiles`` (``[y0, y1, x0, x1,
    d_min, d_max, source]``, empty when not tiled), ``window``, ``bits``, ``d_min``, ``d_max``, ``stats``.
    """
    from ..geometry.projection import project_cloud
    from ..io.disparity import write_disparity
    from ..io.pairfile import load_pairfile, load_registration
    from ..matching.guidance import auto_window, lidar_share_of_points
    from ..matching.pipeline import resolve_disparity_range
    from .tiles import image_bits, plan_tiles, sparse_points_any

    t0 = time.perf_counter()
    s = job.settings
    folder = Path(job.folder)
    folder.mkdir(parents=True, exist_ok=True)
    with contextlib.suppress(FileNotFoundError):
        (folder / DONE).unlink()  # from now on the folder is not a finished pair
    _clean_temps(folder, ("sparse.tif",))
    _clean_temps(folder / WORK, ("left.npy", "right.npy"))
    pair = load_pairfile(job.pair)
    reg = load_registration(s["registration"]) if s["registration"] else None
    H, W = job.shape
    sparse, counts, used, empty = None, {}, [], []
    for cloud in job.clouds:
        if not _cloud_may_land(cloud, pair, pair.registration if reg is None else reg, (H, W)):
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
            counts[k] = counts.get(k, 0) + st[k]
        counts.setdefault("crs", st.get("crs"))
        sparse = sp if sparse is None else np.fmax(sparse, sp)  # the nearer point has the larger disparity
    if sparse is None:
        raise RiverbedError(f"no cloud has points in the pair's images ({len(job.clouds)} checked)", job.pair)
    tags = {"riverbed_pair": job.pair, "riverbed_clouds": json.dumps(used), "riverbed_block_pair": job.name}
    write_disparity(folder / "sparse.tif", sparse, overwrite=True, tags=tags)

    # The matching plan, as match_tiled makes it.
    p = _match_params(s)
    tile, overlap = s["tile"], s["overlap"]
    pr, pc, pv = sparse_points_any(sparse)
    share = lidar_share_of_points(pr, pc, (H, W))
    d_min, d_max = resolve_disparity_range(s["min_disp"], s["max_disp"], pv)

    planned, tile = plan_tiles(H, W, sparse, d_min, d_max, tile, overlap, s["lidar_range"])
    tiles, window, bits = [], p.window, None
    if max(H, W) > tile:
        srcs = [_image_source(getattr(pair, side), (H, W), s["max_pixels"]) for side in ("left", "right")]
        bits = image_bits(*srcs)
        if p.guide != "none" and p.window == "auto":
            window = auto_window(share, p.window_target)  # one window for every tile
        tiles = [[t.y0, t.y1, t.x0, t.x1, t.d_min, t.d_max, t.source] for t in planned]
        work = folder / WORK
        work.mkdir(exist_ok=True)
        for side, src in zip(("left", "right"), srcs):
            _save_npy(src, work / f"{side}.npy")
    stats = {"clouds": len(used), "clouds_without_points": len(empty), "lidar_points_read": counts["points_read"],
             "lidar_points_kept": counts["kept"], "lidar_share": share, "lidar_crs": counts["crs"],
             "tile": int(tile) if tiles else None}
    return {"tiles": tiles, "window": window, "bits": bits, "d_min": d_min, "d_max": d_max, "stats": stats,
            "seconds": round(time.perf_counter() - t0, 4)}


def tile_stage(job, proj, index):
    """Match tile ``index`` of a tiled pair (crops read from disk), or the whole pair when it is not tiled.

    Tiled: :func:`~riverbed_cli.scale.tiles.match_tile`, the body of ``match_tiled``'s loop
    (``test_tile_tasks_are_match_tiled`` pins the two together). Not tiled: :func:`match_pair` on the whole
    images. Returns ``{"index", "disparity" (the tile's own pixels), "evaluations", "stages", "seconds"}``.
    """
    from ..io.disparity import read_disparity
    from ..io.images import check_pair, read_image
    from ..io.pairfile import load_pairfile
    from ..matching.pipeline import MatchParams, match_pair

    t0 = time.perf_counter()
    s = job.settings
    p = _match_params(s)
    folder = Path(job.folder)
    H, W = job.shape
    if not proj["tiles"]:
        pair = load_pairfile(job.pair)
        left = read_image(pair.left, s["max_pixels"])
        right = read_image(pair.right, s["max_pixels"])
        check_pair(left, right, pair.left, pair.right)
        if left.shape[:2] != (H, W):
            raise RiverbedError(f"image is {left.shape[1]}x{left.shape[0]} but the pair file says {W}x{H} (WxH)",
                                pair.left)
        sparse = read_disparity(folder / "sparse.tif")
        res = match_pair(left, right, sparse, s["min_disp"], s["max_disp"], p)
        n_d = res.info["d_max"] - res.info["d_min"] + 1
        return {"index": 0, "disparity": res.disparity, "evaluations": H * W * n_d, "stages": res.info["stages"],
                "seconds": round(time.perf_counter() - t0, 4)}
    from .tiles import Tile, WindowedRaster, match_tile

    p = MatchParams(**{**p.__dict__, "window": proj["window"]})
    tile = Tile(*proj["tiles"][index])
    left = np.load(folder / WORK / "left.npy", mmap_mode="r")
    right = np.load(folder / WORK / "right.npy", mmap_mode="r")
    sparse = WindowedRaster(folder / "sparse.tif", "disparity")
    disp, n, stages = match_tile(left, right, sparse, tile, s["overlap"], p, proj["bits"])
    return {"index": index, "disparity": disp, "evaluations": n, "stages": stages,
            "seconds": round(time.perf_counter() - t0, 4)}


def n_tasks(proj):
    """Number of matching tasks a projected pair needs (its tiles, or one)."""
    return len(proj["tiles"]) or 1


def finish_stage(job, proj, tiles):
    """Stitch the tiles, triangulate, write ``disparity.tif``, ``points.laz``, ``dsm.tif`` and, last, ``done.json``.

    Returns the pair's summary (``points``, ``resolution``, ``crs``, per-stage ``seconds``).
    """
    from ..io.disparity import write_disparity
    from ..io.images import read_image
    from ..io.pairfile import load_pairfile
    from ..io.pointcloud import write_points
    from ..io.raster import write_geotiff
    from ..products.dsm import build_dsm

    t0 = time.perf_counter()
    s = job.settings
    folder = Path(job.folder)
    _clean_temps(folder, (*OUTPUTS, DONE))
    H, W = job.shape
    tiled = bool(proj["tiles"])
    if tiled:
        disp = np.full((H, W), np.nan, np.float32)
        for t in tiles:
            y0, y1, x0, x1 = proj["tiles"][t["index"]][:4]
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
    pair = load_pairfile(job.pair)
    work = folder / WORK
    if tiled:
        image = np.load(work / "left.npy", mmap_mode="r")
    else:
        image = read_image(pair.left, s["max_pixels"])
    crs = s["crs"] or pair.crs or proj["stats"]["lidar_crs"]
    blocks = []
    res = build_dsm([(disp, pair, image)], (), s["resolution"], s["agg"],
                    point_sink=lambda xyz, rgb: blocks.append((xyz, rgb)))
    xyz = np.concatenate([b[0] for b in blocks]) if blocks else np.zeros((0, 3))
    rgb = np.concatenate([b[1] for b in blocks]) if blocks and all(b[1] is not None for b in blocks) else None
    blocks.clear()
    del image
    write_points(folder / "points.laz", xyz, rgb, crs, overwrite=True)
    write_geotiff(folder / "dsm.tif", res.dsm, res.grid.transform, crs, float("nan"), None, overwrite=True,
                  band_descriptions=["height"],
                  tags={"riverbed_aggregation": s["agg"], "riverbed_block_pair": job.name})
    t_match = sum(t["seconds"] for t in tiles)
    seconds = {"project": proj["seconds"], "match": round(t_match, 4), "dsm": round(time.perf_counter() - t0, 4)}
    summary = {"points": len(xyz), "resolution": res.grid.resolution, "crs": crs,
               "bounds": list(res.grid.bounds), **proj["stats"], **info, "d_min": proj["d_min"],
               "d_max": proj["d_max"], "seconds": seconds}
    outputs = {name: {"size": (folder / name).stat().st_size, "sha256": sha256_file(folder / name)}
               for name in OUTPUTS}
    record = {"name": job.name, "pair": job.pair, "clouds": job.clouds, "settings_hash": job.settings_hash,
              "settings": s, "inputs": job.inputs, "outputs": outputs, "stats": summary, "riverbed": _version(),
              "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
    _write_json(folder / DONE, record)
    shutil.rmtree(work, ignore_errors=True)
    return summary


def run_pair(job, progress=None):
    """The whole pair in this process, stage after stage (what the dask tasks do); returns the summary dict.

    Raises :class:`RiverbedError` on bad input.
    """
    proj = project_stage(job)
    tiles = []
    for i in range(n_tasks(proj)):
        tiles.append(tile_stage(job, proj, i))
        if progress:
            progress("tile", job.name)
    return finish_stage(job, proj, tiles)


# -- merging --------------------------------------------------------------------------------------------------------

def merge_dsm(laz_paths, output, resolution, agg="max", crs=None, chunk_size=1_000_000):
    """Rasterise the points of several LAS/LAZ files onto one grid (snapped to multiples of ``resolution``).

    Chunks stream into one :class:`~riverbed_cli.products.dsm.Accumulator`, so the result is the aggregation over
    the union of the points, exact for every aggregation. Writes a COG GeoTIFF (NaN nodata) and returns stats.
    """
    from ..io.lidar import iter_lidar, lidar_info
    from ..io.raster import write_geotiff
    from ..products.dsm import Accumulator, Grid

    t0 = time.perf_counter()
    infos = [lidar_info(p) for p in laz_paths]
    infos = [i for i in infos if i.point_count]
    if not infos:
        raise RiverbedError("no points to merge")
    lo = np.min([i.mins for i in infos], axis=0)
    hi = np.max([i.maxs for i in infos], axis=0)
    grid = Grid.from_bounds(lo[0], lo[1], hi[0], hi[1], resolution)
    acc = Accumulator(grid, agg)
    n = 0
    for info in infos:
        for ch in iter_lidar(info.path, chunk_size=chunk_size):
            xyz = ch["xyz"]
            acc.add(xyz[:, 0], xyz[:, 1], xyz[:, 2])
            n += len(xyz)
    dsm = acc.result()
    write_geotiff(output, dsm, grid.transform, crs, float("nan"), None, overwrite=True, band_descriptions=["height"],
                  tags={"riverbed_aggregation": agg, "riverbed_pairs": len(laz_paths)})
    return {"points": n, "resolution": grid.resolution, "width": grid.width, "height": grid.height,
            "bounds": list(grid.bounds), "cells_with_data": float(100.0 * np.isfinite(dsm).mean()),
            "seconds": round(time.perf_counter() - t0, 4)}


def _merge_settings(plan, records):
    """Resolution and CRS of the merged DSM from the block's defaults and the finished pairs' records."""
    d = plan.manifest.defaults
    resolution = d["resolution"]
    if resolution is None:
        resolution = float(f"{statistics.median(r['stats']['resolution'] for r in records.values()):.3g}")
    crs = d["crs"]
    if crs is None:
        found = {n: r["stats"].get("crs") for n, r in records.items() if r["stats"].get("crs")}
        if found:
            from pyproj import CRS

            first_name, first = next(iter(found.items()))
            ref = CRS.from_user_input(first)
            for n, c in found.items():
                if c != first and not CRS.from_user_input(c).equals(ref, ignore_axis_order=True):
                    raise RiverbedError(f"pairs '{first_name}' and '{n}' have different CRSs ({first} vs {c}); "
                                        "give crs under defaults")
            crs = first
    return resolution, crs


# -- orchestration --------------------------------------------------------------------------------------------------

def _numba_threads(n):
    """Inside a task: set this thread's Numba threads (``n``; None: the worker host's CPUs / the worker's threads)."""
    if n == 0:
        return
    import numba

    if n is None:
        try:
            from distributed import get_worker

            w = get_worker()
            n = max(1, (os.cpu_count() or 1) // max(1, getattr(w.state, "nthreads", None) or w.nthreads))
        except (ImportError, ValueError):
            return
    numba.set_num_threads(max(1, min(int(n), numba.config.NUMBA_NUM_THREADS)))


def _guard(stage, fn, *args):
    try:
        return fn(*args)
    except RiverbedError as e:
        return PairFailure(stage, str(e))


def task_project(job, threads):
    _numba_threads(threads)
    return _guard("project", project_stage, job)


def task_tile(job, proj, index, threads):
    if isinstance(proj, PairFailure):
        return proj
    _numba_threads(threads)
    return _guard("match", tile_stage, job, proj, index)


def task_finish(job, proj, tiles, threads):
    for r in (proj, *tiles):
        if isinstance(r, PairFailure):
            return r
    _numba_threads(threads)
    return _guard("dsm", finish_stage, job, proj, tiles)


def task_merge(laz_paths, output, resolution, agg, crs):
    return _guard("merge", merge_dsm, laz_paths, output, resolution, agg, crs)


def _describe(exc):
    text = str(exc).splitlines()[0] if str(exc) else ""
    return f"{type(exc).__name__}: {text}" if not isinstance(exc, RiverbedError) else text


@dataclass
class BlockResult:
    outdir: Path
    pairs: list  # one dict per pair, manifest order
    merged: dict
    mode: str
    seconds: float
    cluster_seconds: float = None  # starting (or connecting to) the cluster
    plan_seconds: float = 0.0


    @property
    def failed(self):
        return [p for p in self.pairs if p["status"] == "failed"] + (
            [self.merged] if self.merged.get("status") == "failed" else [])

    def summary(self):
        return {"outdir": str(self.outdir), "mode": self.mode, "seconds": round(self.seconds, 3),
                "plan_seconds": round(self.plan_seconds, 3),
                "cluster_seconds": None if self.cluster_seconds is None else round(self.cluster_seconds, 3),
                "pairs": self.pairs, "merged": self.merged}


def _pair_entry(job, status, seconds=None, summary=None, error=None, stage=None):
    """One pair's line of the summary: ``seconds`` is the wall time of the pair in this run (on dask from its first
    submission to its end, queueing included), ``stage_seconds`` the compute time of its stages (pairs run now)."""
    summary = summary or {}
    return {"name": job.name, "status": status, "seconds": None if seconds is None else round(seconds, 3),
            "points": summary.get("points"), "tiles": summary.get("tiles"), "error": error, "stage": stage,
            "stage_seconds": summary.get("seconds") if status == "done" else None}


def _default_workers(threads_per_worker):
    return max(1, (os.cpu_count() or 1) // max(1, threads_per_worker))


def run_block(plan, workers=None, threads_per_worker=1, scheduler=None, retries=2, progress=None, client=None):
    """Run the pairs of a plan (sequentially with ``workers=0``, else on dask.distributed), then merge the DSM.

    Parameters
    ----------
    plan : BlockPlan
    workers : int, optional
        Worker processes of the local cluster (default: CPUs / ``threads_per_worker``); 0 runs the same stage
        functions in this process, in manifest order, without dask.
    threads_per_worker : int
        Dask threads per worker process; inside each task Numba gets ``CPUs // (workers * threads)`` threads.
    scheduler : str, optional
        Address of a running dask scheduler (its workers must see the same paths and have riverbed installed).
    retries : int
        How often a task is redone after an unexpected exception, and (local cluster) how many worker deaths a task
        survives (``distributed.scheduler.allowed-failures``). Bad input is never retried.
    client : distributed.Client, optional
        Run on this client's cluster (left open); ``workers`` and ``scheduler`` are then ignored.
    progress : callable, optional
        ``progress(kind, name, n=1)``: ``"plan"`` (a pair's ``n`` matching tasks are known), ``"tile"`` (one matched),
        ``"pair"`` (a pair settled).

    Returns
    -------
    BlockResult
    """
    t0 = time.perf_counter()
    entries, startup = {}, None
    for job in plan.jobs:
        if job.status == "failed":
            entries[job.name] = _pair_entry(job, "failed", 0.0, error=job.error, stage="plan")
        elif job.status == "skip":
            entries[job.name] = _pair_entry(job, "skipped", 0.0, summary=job.record.get("stats"))
    to_run = plan.to_run
    if scheduler is not None and workers is not None:
        raise RiverbedError("give --workers (a local cluster) or --scheduler (a running one), not both")
    sequential = workers == 0 and client is None
    mode = "client" if client is not None else "sequential" if sequential else ("scheduler" if scheduler else "local")
    own = client is None
    cluster = None
    try:
        if to_run and sequential:
            entries.update(_run_sequential(to_run, progress))
        elif to_run:
            t1 = time.perf_counter()
            threads = None
            if own:
                client, cluster, threads = _connect(workers, threads_per_worker, scheduler, retries)
            startup = time.perf_counter() - t1
            entries.update(_run_dask(client, to_run, retries, threads, progress))
        for job in to_run:  # a failed pair's image copies are not kept
            if entries[job.name]["status"] == "failed":
                shutil.rmtree(Path(job.folder) / WORK, ignore_errors=True)
        merged = _merge(plan, entries, client, retries)
    finally:
        if own and client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    pairs = [entries[j.name] for j in plan.jobs]
    return BlockResult(plan.outdir, pairs, merged, mode, time.perf_counter() - t0, startup, plan.seconds)


def _quiet_dask_logs():
    """dask's own INFO chatter (scheduler start, workers joining) stays out of riverbed's log unless it is at DEBUG
    (``-vv``); its warnings (a worker lost, a task retried) and errors still show."""
    if logging.getLogger().getEffectiveLevel() <= logging.DEBUG:
        return
    for name in list(logging.root.manager.loggerDict):
        if name.split(".")[0] in ("distributed", "dask", "tornado", "bokeh"):
            logger = logging.getLogger(name)
            if logger.level < logging.WARNING:
                logger.setLevel(logging.WARNING)


def _connect(workers, threads_per_worker, scheduler, retries):
    try:
        import dask
        from distributed import Client, LocalCluster
    except ImportError:
        raise RiverbedError("dask.distributed is not installed: pip install 'riverbed[dask]', or run the block "
                            "with --workers 0 (sequential)") from None
    _quiet_dask_logs()
    if scheduler:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as e:
            raise RiverbedError(f"cannot reach the dask scheduler at {scheduler} ({e})") from None
        return client, None, None
    n = workers if workers is not None else _default_workers(threads_per_worker)
    threads = max(1, (os.cpu_count() or 1) // (n * threads_per_worker))
    with dask.config.set({"distributed.scheduler.allowed-failures": int(retries)}):
        cluster = LocalCluster(n_workers=n, threads_per_worker=threads_per_worker, processes=True,
                               dashboard_address=":0", silence_logs=logging.ERROR)
    try:
        client = Client(cluster)
    except BaseException:
        cluster.close()
        raise
    return client, cluster, threads


def _run_dask(client, jobs, retries, threads, progress):
    """Submit each pair's project task; when it is done, its tile tasks (they depend on the project future) and the
    finish task (depends on all of them). Returns the pairs' entries."""
    from distributed import as_completed

    run = uuid.uuid4().hex[:8]
    opts = {"retries": retries, "pure": False}
    kinds, started, entries = {}, {}, {}
    ac = as_completed()
    for job in jobs:
        fp = client.submit(task_project, job, threads, key=f"project-{job.name}-{run}", **opts)
        kinds[fp.key] = ("project", job)
        started[job.name] = time.perf_counter()
        ac.add(fp)
    for fut in ac:
        kind, job = kinds[fut.key]
        if kind == "tile":
            if progress:
                progress("tile", job.name)
            continue
        seconds = time.perf_counter() - started[job.name]
        if fut.status != "finished":
            exc = fut.exception() if fut.status == "error" else None
            entries[job.name] = _pair_entry(job, "failed", seconds, error=_describe(exc) if exc is not None
                                            else f"task {fut.status}", stage=kind if kind == "project" else None)
        elif kind == "project" and not isinstance(proj := fut.result(), PairFailure):
            n = n_tasks(proj)
            if progress:
                progress("plan", job.name, n)
            fts = [client.submit(task_tile, job, fut, i, threads, key=f"tile-{job.name}-{i}-{run}", **opts)
                   for i in range(n)]
            ff = client.submit(task_finish, job, fut, fts, threads, key=f"finish-{job.name}-{run}", **opts)
            kinds.update({f.key: ("tile", job) for f in fts})
            kinds[ff.key] = ("finish", job)
            ac.update([*fts, ff])
            continue
        else:
            entries[job.name] = _entry_from(job, fut.result(), seconds)
        if progress:
            progress("pair", job.name)
    return entries


def _entry_from(job, result, seconds):
    if isinstance(result, PairFailure):
        return _pair_entry(job, "failed", seconds, error=result.message, stage=result.stage)
    return _pair_entry(job, "done", seconds, result)


def _run_sequential(jobs, progress):
    """The same task functions as on dask, in this process, pair after pair (Numba threads left as they are)."""
    entries = {}
    for job in jobs:
        t1 = time.perf_counter()
        try:
            result = proj = task_project(job, 0)
            if not isinstance(proj, PairFailure):
                if progress:
                    progress("plan", job.name, n_tasks(proj))
                tiles = []
                for i in range(n_tasks(proj)):
                    tiles.append(task_tile(job, proj, i, 0))
                    if progress:
                        progress("tile", job.name)
                result = task_finish(job, proj, tiles, 0)
        except Exception as e:  # one pair's crash must not stop the block
            log.debug("pair %s failed", job.name, exc_info=True)
            result = PairFailure(None, _describe(e))
        entries[job.name] = _entry_from(job, result, time.perf_counter() - t1)
        if progress:
            progress("pair", job.name)
    return entries


def _merge(plan, entries, client, retries):
    """Merge the finished pairs' points into ``OUTDIR/dsm.tif`` unless the last merge used exactly these pairs."""
    t0 = time.perf_counter()
    good = [j for j in plan.jobs if entries[j.name]["status"] in ("done", "skipped")]
    output = plan.outdir / "dsm.tif"
    if not good:
        return {"status": "failed", "error": "no pair finished: no merged DSM", "output": None}
    records, hashes = {}, {}
    try:
        for j in good:
            path = Path(j.folder) / DONE
            records[j.name] = json.loads(path.read_text(encoding="utf-8"))
            hashes[j.name] = sha256_file(path)
        resolution, crs = _merge_settings(plan, records)
    except (OSError, ValueError, KeyError) as e:
        return {"status": "failed", "error": f"cannot read a finished pair's record ({e})", "output": None}
    except RiverbedError as e:
        return {"status": "failed", "error": str(e), "output": None}
    agg = plan.manifest.defaults["agg"]
    key = {"pairs": hashes, "resolution": resolution, "agg": agg, "crs": crs}
    marker = plan.outdir / MARKER
    try:
        record = json.loads(marker.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        record = {}
    last = record.get("merged") or {}
    if (last.get("key") == key and output.is_file() and output.stat().st_size == last.get("size")
            and sha256_file(output) == last.get("sha256")):
        return {"status": "skipped", "output": str(output), **last.get("stats", {}),
                "seconds": round(time.perf_counter() - t0, 3)}
    paths = [str(Path(j.folder) / "points.laz") for j in good]
    if client is not None:
        fut = client.submit(task_merge, paths, str(output), resolution, agg, crs, key=f"merge-{uuid.uuid4().hex[:8]}",
                            retries=retries, pure=False)
        try:
            stats = fut.result()
        except Exception as e:  # noqa: BLE001 - reported like a failed pair
            stats = PairFailure("merge", _describe(e))
    else:
        stats = _guard("merge", merge_dsm, paths, output, resolution, agg, crs)
    if isinstance(stats, PairFailure):
        return {"status": "failed", "error": stats.message, "output": None}
    record["merged"] = {"key": key, "size": output.stat().st_size, "sha256": sha256_file(output), "stats": stats}
    _write_json(marker, record)
    return {"status": "done", "output": str(output), "pairs": len(good), "crs": crs, **stats,
            "seconds": round(time.perf_counter() - t0, 3)}


def job_dict(job):
    """A plain dict of a job (for logs and debugging)."""
    return asdict(job)
