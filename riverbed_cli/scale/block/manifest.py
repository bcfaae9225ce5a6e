"""A block manifest: reading and validating it into :class:`Manifest` (see the package notes for its format)."""

import glob
import os
import re
from dataclasses import dataclass
from pathlib import Path

from ...errors import RiverbedError
from ...geometry.rectify import check_alpha, parse_size
from ...io.textfiles import parse_yaml, read_text
from ...settings import SettingError, show
from .settings import default_settings, settings_spec

#: Manifests larger than this are refused before parsing.
MANIFEST_MAX_BYTES = 10_000_000
TOP_KEYS = ("defaults", "pairs")
PAIR_KEYS = ("pair", "raw", "cloud", "name")
RAW_KEYS = ("left", "left_orientation", "right", "right_orientation")
#: Optional rectification settings of a ``raw:`` entry (as ``riverbed rectify --alpha / --size``).
RAW_OPTIONS = ("alpha", "size")
#: Settings that shape the merged DSM: one value for the whole block, given under ``defaults`` only.
BLOCK_KEYS = ("resolution", "crs", "agg")
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}")
_GLOB = re.compile(r"[*?\[]")


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
        except SettingError as e:
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
        raise RiverbedError(f"{where}.cloud: expected a file name, a glob or a list of them, got {show(value)}",
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
                raise RiverbedError(f"{where}.pair: expected a file name, got {show(value)}", path)
            pair_path = Path(os.path.normpath(base / value))
            if not pair_path.is_file():
                raise RiverbedError(f"{where}.pair: file not found: {value}", path)
        clouds = _clouds(entry["cloud"], where, path, base)
        name = entry.get("name")
        if name is None:
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
        specs.append(PairSpec(i, name, pair_path, clouds, settings, raw))
    return Manifest(path.absolute(), {**default_settings(), **defaults}, specs)
