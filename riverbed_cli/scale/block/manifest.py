"""A block manifest: reading and validating it into :class:`Manifest` (see the package notes for its format)."""

import glob
import os
import re
from dataclasses import dataclass
from pathlib import Path


from ...errors import RiverbedError
from ...geometry.rectify import check_alpha, parse_size
from ...geometry.rpc_dem import dem_vertical
from ...geometry.rpc_pair import MIN_ROI_PX, check_roi, parse_heights, parse_roi
from ...io.images import header_size
from ...io.textfiles import load_text_data
from ...settings import SettingError, show
from .settings import default_settings, settings_spec

#: Manifests larger than this are refused before parsing.
MANIFEST_MAX_BYTES = 10_000_000
TOP_KEYS = ("defaults", "pairs")
PAIR_KEYS = ("pair", "raw", "rpc", "cloud", "name", "range_map")
RAW_KEYS = ("left", "left_orientation", "right", "right_orientation")
#: Optional rectification settings of a ``raw:`` entry (as ``riverbed rectify --alpha / --size``).
RAW_OPTIONS = ("alpha", "size")
#: An ``rpc:`` entry: two satellite images and their RPC models (``riverbed rectify --rpc``'s inputs) ...
RPC_KEYS = ("left", "left_rpc", "right", "right_rpc")
#: ... and its optional settings (as ``--roi``, ``--dem``, ``--heights``, ``--vertical``,
#: ``--no-pointing-correction``); without ``dem`` and ``heights`` the height range comes from the pair's clouds
#: (without clouds: the images' tie points).
RPC_OPTIONS = ("roi", "dem", "heights", "vertical", "pointing")
#: Settings that shape the merged DSM: one value for the whole block, given under ``defaults`` only.
BLOCK_KEYS = ("resolution", "crs", "agg")
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}")
_GLOB = re.compile(r"[*?\[]")
#: most files a cloud glob may match
MAX_GLOB_FILES = 10_000


@dataclass
class PairSpec:
    """One entry of ``pairs:`` after validation: absolute paths and the effective settings."""

    index: int
    name: str
    pair: Path  # for a raw entry: None until plan_block has rectified it
    clouds: list
    settings: dict
    raw: dict = None  # raw frames and orientations (absolute paths), rectified by plan_block
    rpc: dict = None  # satellite images, RPCs and ROI (absolute paths), rectified by the pair's project stage
    range_map: Path = None  # per-pixel disparity ranges of the rectified pair (``riverbed match --range-map``)


@dataclass
class Manifest:
    path: Path
    defaults: dict
    pairs: list


def _read_manifest(path):
    return load_text_data(path, "block manifest", MANIFEST_MAX_BYTES, fmt="yaml")[0]


def _settings(raw, where, spec, path, base, block_wide):
    out = {}
    for key, value in raw.items():
        if key in BLOCK_KEYS and not block_wide:
            raise RiverbedError(f"{where}.{key}: a block-wide setting; give it under defaults", path)
        try:
            out[key] = spec[key][1](value)
        except SettingError as e:
            raise RiverbedError(f"{where}.{key}: {e}", path) from None
        if key in ("registration", "range_dsm") and out[key] is not None:
            file = Path(os.path.normpath(base / out[key]))
            if not file.is_file():
                raise RiverbedError(f"{where}.{key}: file not found: {value}", path)
            out[key] = str(file)
    return out


def _clouds(value, where, path, base):
    items = value if isinstance(value, list) else [value]
    if not items or not all(isinstance(v, str) and v for v in items):
        raise RiverbedError(f"{where}.cloud: expected a file name, a glob or a list of them, got {show(value)}",
                            path)
    found = []
    for item in items:
        full = base / item
        if _GLOB.search(item):
            # a glob walks folders: it stays inside the manifest's folder, and its matches are bounded
            if Path(item).is_absolute() or ".." in Path(item).parts:
                raise RiverbedError(f"{where}.cloud: the glob '{item}' must stay inside the manifest's folder (no "
                                    "absolute path, no '..'); name files outside it one by one", path)
            hits = []
            for p in glob.iglob(str(full), recursive=True):
                if Path(p).is_file():
                    hits.append(Path(p))
                    if len(hits) > MAX_GLOB_FILES:
                        raise RiverbedError(f"{where}.cloud: '{item}' matches more than {MAX_GLOB_FILES} files",
                                            path)
            hits.sort()
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
        raise RiverbedError(f"{where}.raw: expected a mapping with {', '.join(RAW_KEYS)}, got {show(value)}", path)
    unknown = [str(k) for k in value if k not in RAW_KEYS + RAW_OPTIONS]
    if unknown:
        raise RiverbedError(f"{where}.raw: unknown key '{unknown[0]}' (raw keys: {', '.join(RAW_KEYS + RAW_OPTIONS)})",
                            path)
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


def _rpc_images(value, where, path, base):
    """The ``rpc:`` entry of a pair: two satellite images, their RPC models, a ROI of the left image and the
    terrain's height range (``riverbed rectify --rpc``'s inputs; docs/rpc.md)."""
    keys = RPC_KEYS + RPC_OPTIONS
    if not isinstance(value, dict):
        raise RiverbedError(f"{where}.rpc: expected a mapping with {', '.join(RPC_KEYS)}, got {show(value)}", path)
    unknown = [str(k) for k in value if k not in keys]
    if unknown:
        raise RiverbedError(f"{where}.rpc: unknown key '{unknown[0]}' (rpc keys: {', '.join(keys)})", path)
    out = {}
    for key in RPC_KEYS:
        v = value.get(key)
        if not isinstance(v, str) or not v:
            what = "an RPC file, or the image itself for GeoTIFF RPC tags" if key.endswith("_rpc") else "a file name"
            raise RiverbedError(f"{where}.rpc.{key}: missing ({what})", path)
        p = Path(os.path.normpath(base / v))
        if not p.is_file():
            raise RiverbedError(f"{where}.rpc.{key}: file not found: {v}", path)
        out[key] = p
    roi = value.get("roi")
    if roi is not None:
        text = ",".join(str(v) for v in roi) if isinstance(roi, list) else roi
        if isinstance(roi, list) and (len(roi) != 4 or not all(isinstance(v, int) and not isinstance(v, bool)
                                                                for v in roi)):
            text = None
        try:
            if not isinstance(text, str):
                raise ValueError(f"expected [col, row, width, height] (four integers, px, width and height at least "
                                 f"{MIN_ROI_PX}), got {show(roi)}")
            roi = parse_roi(text)
        except ValueError as e:
            raise RiverbedError(f"{where}.rpc.roi: {e}", path) from None
        size = header_size(out["left"])  # None: the stage says why
        if size is not None:
            try:
                check_roi(roi, size, out["left"], option="ROI")
            except RiverbedError as e:
                raise RiverbedError(f"{where}.rpc.roi: {e}", path) from None
    out["roi"] = None if roi is None else list(roi)
    if value.get("dem") is not None and value.get("heights") is not None:
        raise RiverbedError(f"{where}.rpc: give dem or heights (or neither: the pair's clouds), not both", path)
    out["dem"] = None
    if value.get("dem") is not None:
        v = value["dem"]
        if not isinstance(v, str) or not v:
            raise RiverbedError(f"{where}.rpc.dem: expected a file name, got {show(v)}", path)
        out["dem"] = Path(os.path.normpath(base / v))
        if not out["dem"].is_file():
            raise RiverbedError(f"{where}.rpc.dem: file not found: {v}", path)
    heights = value.get("heights")
    if heights is not None:
        text = ",".join(str(v) for v in heights) if isinstance(heights, list) else str(heights)
        if isinstance(heights, list) and not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                 for v in heights):
            text = show(heights)
        try:
            heights = list(parse_heights(text))
        except ValueError as e:
            raise RiverbedError(f"{where}.rpc.heights: {e}", path) from None
    out["heights"] = heights
    vertical = value.get("vertical")
    if vertical is not None:
        if not isinstance(vertical, str) or (out["dem"] is None and heights is None):
            raise RiverbedError(f"{where}.rpc.vertical: expected the datum (ellipsoid or a vertical CRS such as "
                                f"EPSG:5773) of dem or heights, got {show(vertical)}", path)
        try:
            dem_vertical(None, None, vertical)
        except RiverbedError as e:
            raise RiverbedError(f"{where}.rpc.vertical: {e}", path) from None
    out["vertical"] = vertical
    pointing = value.get("pointing", True)
    if not isinstance(pointing, bool):
        raise RiverbedError(f"{where}.rpc.pointing: expected true or false, got {show(pointing)}", path)
    out["pointing"] = pointing
    return out


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
    file, a cloud glob matching nothing, a bad value, duplicate names, a block-wide setting given per pair; for an
    ``rpc:`` entry a missing image, RPC or DEM file, a malformed ROI or one outside the left image, bad heights; a
    ``range_map`` that is missing or not on a ``pair:`` entry; a missing ``range_dsm``, or one with a ``range_map``.
    """
    path = Path(path)
    data = _read_manifest(path)
    base = path.absolute().parent
    if not isinstance(data, dict):
        raise RiverbedError("not a block manifest (expected a mapping with 'pairs')", path)
    unknown = [str(k) for k in data if k not in TOP_KEYS]
    if unknown:
        raise RiverbedError(f"unknown key '{unknown[0]}' (manifest keys: {', '.join(TOP_KEYS)})", path)
    spec = settings_spec()
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
            raise RiverbedError(f"{where}: expected a mapping with pair and cloud, got {show(entry)}", path)
        unknown = [str(k) for k in entry if k not in PAIR_KEYS and k not in spec]
        if unknown:
            raise RiverbedError(f"{where}: unknown key '{unknown[0]}' (pair keys: {', '.join(PAIR_KEYS)}, and "
                                "the settings of defaults)", path)
        if sum(k in entry for k in ("pair", "raw", "rpc")) != 1:
            raise RiverbedError(f"{where}: give one of pair (a rectified pair file), raw (frames and orientations) "
                                "or rpc (satellite images and their RPCs)", path)
        raw = rpc = pair_path = None
        if "raw" in entry:
            raw = _raw_frames(entry["raw"], where, path, base)
        elif "rpc" in entry:
            rpc = _rpc_images(entry["rpc"], where, path, base)
        else:
            value = entry["pair"]
            if not isinstance(value, str) or not value:
                raise RiverbedError(f"{where}.pair: expected a file name, got {show(value)}", path)
            pair_path = Path(os.path.normpath(base / value))
            if not pair_path.is_file():
                raise RiverbedError(f"{where}.pair: file not found: {value}", path)
        clouds = _clouds(entry["cloud"], where, path, base) if "cloud" in entry else []  # none: the images alone
        range_map = None
        if "range_map" in entry:
            value = entry["range_map"]
            if pair_path is None:
                raise RiverbedError(f"{where}.range_map: only for a pair: entry (its ranges are of the rectified "
                                    "images, which raw and rpc entries make later)", path)
            if not isinstance(value, str) or not value:
                raise RiverbedError(f"{where}.range_map: expected a file name, got {show(value)}", path)
            range_map = Path(os.path.normpath(base / value))
            if not range_map.is_file():
                raise RiverbedError(f"{where}.range_map: file not found: {value}", path)
        name = entry.get("name")
        if name is None and rpc is not None:
            name = default_name(rpc["left"], base) + ("_roi_{}_{}".format(*rpc["roi"][:2]) if rpc["roi"] else "")
        elif name is None:
            name = default_name(pair_path if raw is None else raw["left_orientation"], base)
        elif not isinstance(name, str) or not _NAME.fullmatch(name):
            raise RiverbedError(f"{where}.name: expected letters, digits, '.', '_' or '-' (at most 100, not "
                                f"starting with '.', '_' or '-'), got {show(name)}", path)
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
        if range_map is not None and settings["range_dsm"] is not None:
            raise RiverbedError(f"{where}: give range_map or range_dsm (the ranges from a DSM), not both", path)
        specs.append(PairSpec(i, name, pair_path, clouds, settings, raw, rpc, range_map))
    return Manifest(path.absolute(), {**default_settings(), **defaults}, specs)
