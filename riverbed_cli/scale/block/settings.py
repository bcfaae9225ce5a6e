"""A block's settings: the table of settings with their defaults and validators, and the matcher's configuration
of a pair's settings.

The matching settings (their entries of the table, from ``riverbed_cli.matching.config.MATCH_SETTINGS``, and
:func:`match_params`) are kept together in the section marked *matching settings* below; the block adds its
block-wide and projection settings.
"""

import math

from pyproj import CRS
from pyproj.exceptions import CRSError

from ...geometry.projection import NOISE_CLASSES, OUTLIERS, SIDES, VISIBILITY
from ...geometry.visibility import ZBUFFER_RADIUS
from ...matching.config import MATCH_SETTINGS, MatchConfig
from ...products.dsm import AGGREGATIONS
from ...settings import SettingError, choice, show


# -- validators -----------------------------------------------------------------------------------------------------

def _resolution(v):
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0):
        raise SettingError(f"expected a positive number (CRS units) or null, got {show(v)}")
    return float(v)


def _crs(v):
    if v is None:
        return None
    if isinstance(v, int) and not isinstance(v, bool):
        v = f"EPSG:{v}"
    if not isinstance(v, str) or not v.strip():
        raise SettingError(f"expected a CRS such as EPSG:32632, got {show(v)}")
    try:
        CRS.from_user_input(v)
    except CRSError:
        raise SettingError(f"unknown CRS '{v}'") from None
    return v


def _footprint(v):
    if v == "auto":
        return v
    if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 50:
        raise SettingError(f"expected 'auto' or an integer from 0 to 50 (px), got {show(v)}")
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
                               f"got {show(v)}")
        return sorted(set(v))
    return check


def _optional_str(v):
    if v is None:
        return None
    if not isinstance(v, str) or not v:
        raise SettingError(f"expected a file name or null, got {show(v)}")
    return v


def _margin(v):
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v >= 0):
        raise SettingError(f"expected a number of pixels >= 0, got {show(v)}")
    return float(v)


# -- matching settings ----------------------------------------------------------------------------------------------
# Everything about the matcher's settings is in this section: their rows come from the matching settings table
# (riverbed_cli.matching.config.MATCH_SETTINGS: matcher, guides, disparity range, input size, tiling), and
# match_params turns a pair's settings into the matcher's configuration.

def match_settings_spec():
    """The matching entries of the settings table (``{key: (default, validator)}``), from ``MATCH_SETTINGS``."""
    return {s.name: (s.default, s.validate) for s in MATCH_SETTINGS}


def match_params(s):
    """The matcher's configuration (:class:`~riverbed_cli.matching.config.MatchConfig`) of a pair's settings."""
    return MatchConfig.from_settings(s)


# -- the settings table ---------------------------------------------------------------------------------------------

def settings_spec():
    """Every setting of a block: ``{key: (default, validator)}``; a validator returns the value to use or raises
    :class:`SettingError`."""
    return {
        # block-wide
        "resolution": (None, _resolution),
        "crs": (None, _crs),
        "agg": ("max", choice(AGGREGATIONS)),
        # matching, disparity range, input size, tiling
        **match_settings_spec(),
        # projection
        "outliers": ("sor", choice(OUTLIERS)),
        "visibility": ("zbuffer", choice(VISIBILITY)),
        "side": ("both", choice(SIDES)),
        "footprint": (ZBUFFER_RADIUS, _footprint),
        "classes": (None, _classes(none=True)),
        "drop_classes": (sorted(NOISE_CLASSES), _classes(none=False)),
        "registration": (None, _optional_str),
        "lidar_crs": (None, _crs),
        # per-pixel search ranges from a DSM (projected as a cloud, riverbed range-map --window auto)
        "range_dsm": (None, _optional_str),
        "range_dsm_margin": (2.0, _margin),
        "range_dsm_crs": (None, _crs),
    }


def default_settings():
    """The effective settings of a pair when the manifest gives none (a fresh dict)."""
    return {k: (list(d) if isinstance(d, list) else d) for k, (d, _) in settings_spec().items()}
