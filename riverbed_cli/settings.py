"""Settings and their validators, shared by the command line, the block manifest and the library.

A :class:`Setting` is one row of a settings table: a flat name (``--name-with-dashes`` on the command line, ``name``
in a manifest), a default, a validator, one line of help, and where it lands in a configuration object. A validator
takes a value as YAML gives it (``int``, ``float``, ``bool``, ``str``, ``list``, ``None``) and returns it
normalised, or raises :class:`SettingError` whose message says what was expected ("expected an integer >= 0, got
-1"). :func:`parse_text` turns command-line text into such a value first, so a bad value gets the same message from
``riverbed match`` and from a manifest.

This module depends on nothing but :mod:`riverbed_cli.errors`: every layer may use it.
"""

import math
from dataclasses import dataclass

from .errors import RiverbedError


#: Images larger than this (width x height) are refused unless ``--max-pixels`` says otherwise.
MAX_PIXELS = 400_000_000


class SettingError(ValueError):
    """A setting's value is wrong; the message says what was expected and what was given."""


def show(v):
    """A value as error messages quote it: strings in single quotes, the rest as ``repr``."""
    return repr(v) if not isinstance(v, str) else f"'{v}'"


def _is_int(v):
    return isinstance(v, int) and not isinstance(v, bool)


def integer(lo=None, hi=None, none=False, unit=""):
    """An integer, optionally within ``[lo, hi]`` or null."""
    desc = "an integer" + (f" >= {lo}" if lo is not None and hi is None else "")
    if lo is not None and hi is not None:
        desc = f"an integer from {lo} to {hi}"
    if unit:
        desc += f" ({unit})"
    if none:
        desc += " or null"

    def check(v):
        if v is None and none:
            return None
        if not _is_int(v) or (lo is not None and v < lo) or (hi is not None and v > hi):
            raise SettingError(f"expected {desc}, got {show(v)}")
        return int(v)
    return check


def number(lo=None, positive=False, unit=""):
    """A finite number (int or float, returned as float), ``> 0`` with ``positive`` or ``>= lo``."""
    desc = "a positive number" if positive else "a number" + (f" >= {lo}" if lo is not None else "")
    if unit:
        desc += f" ({unit})"

    def check(v):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                or (positive and v <= 0) or (lo is not None and v < lo):
            raise SettingError(f"expected {desc}, got {show(v)}")
        return float(v)
    return check


def choice(options):
    """One of ``options`` (compared as given: ``8`` is not ``'8'``; :func:`parse_text` converts command-line text)."""
    def check(v):
        if v not in options:
            raise SettingError(f"expected one of {', '.join(map(str, options))}, got {show(v)}")
        return v
    check.options = tuple(options)
    return check


def boolean(v):
    """``true`` or ``false``."""
    if not isinstance(v, bool):
        raise SettingError(f"expected true or false, got {show(v)}")
    return v


def auto_or(check_value, desc):
    """``'auto'`` or a value ``check_value`` accepts; ``desc`` names that value in the message."""
    def check(v):
        if v == "auto":
            return v
        try:
            return check_value(v)
        except SettingError:
            raise SettingError(f"expected 'auto' or {desc}, got {show(v)}") from None
    return check


def odd_window(v):
    """A positive odd integer (a window side in px)."""
    if not _is_int(v) or v < 1 or v % 2 == 0:
        raise SettingError(f"expected an odd positive integer, got {show(v)}")
    return int(v)


def odd_window_upto(hi):
    """A positive odd integer up to ``hi`` (a window side in px)."""
    def check(v):
        if not _is_int(v) or v < 1 or v % 2 == 0 or v > hi:
            raise SettingError(f"expected an odd integer from 1 to {hi}, got {show(v)}")
        return int(v)
    return check


def parse_census_window(spec):
    """Parse ``"9x7"`` (width x height, both odd, at most 65 cells) or ``(9, 7)`` into ``(width, height)``.

    Raises :class:`RiverbedError` naming the problem.
    """
    if isinstance(spec, str):
        try:
            w, h = (int(v) for v in spec.lower().split("x"))
        except ValueError:
            raise RiverbedError(f"census window '{spec}' is not WIDTHxHEIGHT, e.g. 9x7") from None
    else:
        w, h = (int(v) for v in spec)
    if w < 1 or h < 1 or w % 2 == 0 or h % 2 == 0:
        raise RiverbedError(f"census window {w}x{h}: width and height must be odd and positive")
    if w * h - 1 > 64:
        raise RiverbedError(f"census window {w}x{h} has {w * h - 1} bits; at most 64 fit (e.g. 9x7)")
    if w * h < 9:
        raise RiverbedError(f"census window {w}x{h} is too small; use at least 3x3")
    return w, h


def census_window(v):
    """A census window ``WIDTHxHEIGHT`` (or ``[W, H]``), normalised to the string ``'WxH'``."""
    if not isinstance(v, str) and not (isinstance(v, (list, tuple)) and len(v) == 2 and all(_is_int(x) for x in v)):
        raise SettingError(f"expected WIDTHxHEIGHT such as 9x7, got {show(v)}")
    try:
        w, h = parse_census_window(v)
    except RiverbedError as e:
        raise SettingError(str(e)) from None
    return f"{w}x{h}"


@dataclass(frozen=True)
class Setting:
    """One row of a settings table.

    ``name`` is the flat name (manifest key; ``--name`` with ``_`` as ``-`` on the command line); ``group`` and
    ``field`` say where the value lands in a configuration object (``group=None``: a setting of the run, not of
    the matcher, such as the tile size); ``applies`` names the matchers or guides it belongs to (``"all"`` for
    every one), for the help text; ``kind`` (``int``, ``float``, ``bool``, ``str``, ``auto-int``) tells
    :func:`parse_text` how to read command-line text.
    """

    name: str
    default: object
    check: object
    help: str
    group: str = None
    field: str = None
    applies: str = "all"
    kind: str = "str"
    metavar: str = None

    @property
    def option(self):
        """The command-line option, ``--name-with-dashes``."""
        return "--" + self.name.replace("_", "-")

    def validate(self, value):
        """The value normalised; :class:`SettingError` if it is wrong."""
        return self.check(value)


def parse_text(setting, text):
    """A command-line string as the value a manifest would give: ``'7'`` -> 7, ``'0.5'`` -> 0.5, ``'auto'`` stays.

    Text that does not read as the setting's kind is passed on unchanged, so the validator reports it.
    """
    if not isinstance(text, str):
        return text
    t = text.strip()
    if setting.kind in ("int", "auto-int", "float", "auto-float", "choice-int"):
        if t == "auto" and setting.kind.startswith("auto"):
            return t
        for conv in ((int,) if "int" in setting.kind else (int, float)):
            try:
                return conv(t)
            except ValueError:
                pass
        return text
    if setting.kind == "bool":
        low = t.lower()
        if low in ("true", "yes", "1", "on"):
            return True
        if low in ("false", "no", "0", "off"):
            return False
        return text
    return text
