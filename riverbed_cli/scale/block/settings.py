"""A block's settings: the validators of the manifest's values, the table of settings with their defaults, and the
matcher's parameters of a pair's settings.

The matching settings (their entries of the table and :func:`match_params`) are kept together in the section
marked *matching settings* below.
"""

import inspect
import math

from pyproj import CRS
from pyproj.exceptions import CRSError

from ...errors import RiverbedError
from ...geometry.projection import NOISE_CLASSES, OUTLIERS, SIDES, VISIBILITY
from ...geometry.visibility import ZBUFFER_RADIUS
from ...io.images import MAX_PIXELS
from ...matching import pipeline
from ...matching.census import parse_census_window
from ...matching.pipeline import GUIDES, MatchParams
from ...products.dsm import AGGREGATIONS
from ..tiles import match_tiled


class SettingError(Exception):
    """A setting's value is wrong; the message says what was expected."""


def show_value(v):
    """A value as a manifest error message shows it (strings quoted)."""
    return repr(v) if not isinstance(v, str) else f"'{v}'"


# -- validators -----------------------------------------------------------------------------------------------------

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
            raise SettingError(f"expected {desc}, got {show_value(v)}")
        return int(v)
    return check


def _choice(options):
    def check(v):
        if v not in options:
            raise SettingError(f"expected one of {', '.join(map(str, options))}, got {show_value(v)}")
        return v
    return check


def _bool(v):
    if not isinstance(v, bool):
        raise SettingError(f"expected true or false, got {show_value(v)}")
    return v


def _resolution(v):
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0):
        raise SettingError(f"expected a positive number (CRS units) or null, got {show_value(v)}")
    return float(v)


def _crs(v):
    if v is None:
        return None
    if isinstance(v, int) and not isinstance(v, bool):
        v = f"EPSG:{v}"
    if not isinstance(v, str) or not v.strip():
        raise SettingError(f"expected a CRS such as EPSG:32632, got {show_value(v)}")
    try:
        CRS.from_user_input(v)
    except CRSError:
        raise SettingError(f"unknown CRS '{v}'") from None
    return v


def _tile(v):
    if v == "auto":
        return v
    if isinstance(v, bool) or not isinstance(v, int) or v < 16:
        raise SettingError(f"expected 'auto' or an integer >= 16 (px), got {show_value(v)}")
    return v


def _footprint(v):
    if v == "auto":
        return v
    if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 50:
        raise SettingError(f"expected 'auto' or an integer from 0 to 50 (px), got {show_value(v)}")
    return v


def _classes(none):
    def check(v):
        if v is None and none:
            return None
        if v is None:
            return []
        if not isinstance(v, list) or not all(isinstance(c, int) and not isinstance(c, bool) and 0 <= c <= 255
                                              for c in v):
            raise SettingError(f"expected a list of class numbers 0..255{' or null' if none else ''}, "
                               f"got {show_value(v)}")
        return sorted(set(v))
    return check


def _optional_str(v):
    if v is None:
        return None
    if not isinstance(v, str) or not v:
        raise SettingError(f"expected a file name or null, got {show_value(v)}")
    return v


# -- matching settings ----------------------------------------------------------------------------------------------
# Everything about the matcher's settings is in this section: their validators, their entries of the settings
# table (match_settings_spec) and the matcher's parameters of a pair's settings (match_params).

#: The settings that are fields of :class:`~riverbed_cli.matching.pipeline.MatchParams` (those the pipeline has).
MATCH_PARAM_KEYS = ("guide", "matcher", "window", "census", "paths", "p1", "p2", "subpixel", "median", "lr_check")


def _window(v):
    if v == "auto":
        return v
    if isinstance(v, bool) or not isinstance(v, int) or v < 1 or v % 2 == 0:
        raise SettingError(f"expected 'auto' or an odd positive integer, got {show_value(v)}")
    return v


def _census(v):
    if not isinstance(v, str) and not (isinstance(v, list) and len(v) == 2
                                       and all(isinstance(x, int) and not isinstance(x, bool) for x in v)):
        raise SettingError(f"expected WIDTHxHEIGHT such as 9x7, got {show_value(v)}")
    try:
        w, h = parse_census_window(v)
    except RiverbedError as e:
        raise SettingError(str(e)) from None
    return f"{w}x{h}"


def match_settings_spec():
    """The matching entries of the settings table (``{key: (default, validator)}``, in the manifest's order)."""
    mp = MatchParams()
    return {
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
    }


def match_params(s):
    """The matcher's parameters of a pair's effective settings."""
    return MatchParams(**{k: s[k] for k in MATCH_PARAM_KEYS if k in s})


# -- the settings table ---------------------------------------------------------------------------------------------

def settings_spec():
    """Every setting of a block: ``{key: (default, validator)}``; a validator returns the value to use or raises
    :class:`SettingError`."""
    # tile and overlap defaults in step with match_tiled's
    tiled = {k: v.default for k, v in inspect.signature(match_tiled).parameters.items()}
    return {
        # block-wide
        "resolution": (None, _resolution),
        "crs": (None, _crs),
        "agg": ("max", _choice(AGGREGATIONS)),
        # matching
        **match_settings_spec(),
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
    return {k: (list(d) if isinstance(d, list) else d) for k, (d, _) in settings_spec().items()}
