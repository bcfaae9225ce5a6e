"""Options shared by several subcommands, defined once (in the manner of rasterio's ``rio``)."""

import json
import logging
import os
import sys

import click

from ..errors import RiverbedError
from ..settings import SettingError, parse_text

output_opt = click.option(
    "-o", "--output", "output", required=True, type=click.Path(dir_okay=False), help="Output file."
)
overwrite_opt = click.option(
    "--overwrite", is_flag=True, default=False, help="Replace an existing output file."
)
json_opt = click.option(
    "--json", "as_json", is_flag=True, default=False, help="Print a machine-readable JSON summary on stdout."
)


def input_path(**kwargs):
    """A click path argument for an input file; existence is checked by the readers (one-line errors)."""
    return click.Path(dir_okay=False, **kwargs)


def print_json(obj):
    click.echo(json.dumps(obj, indent=2, sort_keys=False, default=_json_default))


def _json_default(o):
    # numpy scalars and arrays appear in summaries; turn them into plain Python values.
    if hasattr(o, "item") and getattr(o, "ndim", 1) == 0:
        return o.item()
    if hasattr(o, "tolist"):
        return o.tolist()
    return str(o)


def progress_enabled():
    """Progress bars only on a terminal, never in pipes or under CI logs."""
    return sys.stderr.isatty()


class _NoBar:
    """What a command does with a tqdm bar, doing nothing (pipes, CI logs, nothing to count)."""

    def __init__(self, total=0):
        self.total = total

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def update(self, n=1):
        pass

    def refresh(self):
        pass

    def set_postfix_str(self, s=""):
        pass

    def close(self):
        pass


def progress_bar(total=0, enabled=True, **kwargs):
    """A tqdm progress bar on a terminal (:func:`progress_enabled`) when ``enabled``, else one that does nothing.

    tqdm is imported only for a bar that shows: its import took 22-34 ms of a fresh ``riverbed match`` in a pipe
    (after Numba's), where the bar was made disabled."""
    if not (enabled and progress_enabled()):
        return _NoBar(total)
    from tqdm import tqdm

    return tqdm(total=total, **kwargs)


def setup_logging(verbosity):
    level = {-1: logging.ERROR, 0: logging.WARNING, 1: logging.INFO}.get(verbosity, logging.DEBUG)
    logging.basicConfig(level=level, format="riverbed: %(levelname)s: %(message)s", stream=sys.stderr, force=True)


class SettingType(click.ParamType):
    """A command-line value of a :class:`~riverbed_cli.settings.Setting`: read as a manifest would give it
    (:func:`~riverbed_cli.settings.parse_text`) and checked by the same validator, so a bad value gets the same
    one-line message here and in a block manifest (``riverbed: error: --window: expected ...``)."""

    def __init__(self, setting):
        self.setting = setting
        self.name = setting.kind

    def convert(self, value, param, ctx):
        if value is None or (not isinstance(value, str) and value is self.setting.default):
            return value
        try:
            return self.setting.validate(parse_text(self.setting, value))
        except SettingError as e:
            raise RiverbedError(f"{self.setting.option}: {e}") from None

    def get_metavar(self, param, ctx=None):
        choices = getattr(self.setting.check, "options", None)
        if choices:
            return "[" + "|".join(map(str, choices)) + "]"
        return {"int": "INTEGER", "float": "NUMBER", "auto-int": "auto|INTEGER", "auto-float": "auto|NUMBER",
                "choice-int": "INTEGER"}.get(self.setting.kind, "TEXT")


def setting_options(settings, defaults=None):
    """Click options for ``settings`` (rows of a settings table), in table order: ``--name VALUE``, or
    ``--name/--no-name`` flags for booleans. ``defaults`` overrides a row's default on the command line (e.g. None
    for a default that depends on other options). The parameter of ``--plus-hops`` is ``plus_hops``."""
    defaults = defaults or {}

    def decorate(f):
        for s in reversed(settings):
            default = defaults.get(s.name, s.default)
            where = "" if s.applies == "all" else f" [{s.applies}]"
            if s.kind == "bool":
                flag = s.option[2:]
                opt = click.option(f"--{flag}/--no-{flag}", s.name, default=default, show_default=True,
                                   help=s.help + where)
            else:
                opt = click.option(s.option, s.name, type=SettingType(s), default=default,
                                   show_default=default is not None, help=s.help + where)
            f = opt(f)
        return f
    return decorate


def parsed_value(parser, option):
    """A click callback turning an option's text into a value with ``parser`` (None stays None); a ``ValueError``
    becomes the one-line ``riverbed: error: OPTION: message``."""
    def callback(ctx, param, value):
        if value is None:
            return None
        try:
            return parser(value)
        except ValueError as e:
            raise RiverbedError(f"{option}: {e}") from None
    return callback


def read_disparity_named(path, scale, option):
    """:func:`~riverbed_cli.io.disparity.read_disparity` for a command whose scale option is ``option``: the
    reader's messages name ``--gt-scale`` (evaluate's), which that command does not have."""
    from ..io.disparity import read_disparity

    try:
        return read_disparity(path, scale=scale)
    except RiverbedError as e:
        if "--gt-scale" not in str(e) or option == "--gt-scale":
            raise
        message = str(e)[len(f"{e.path}: "):] if e.path else str(e)
        raise RiverbedError(message.replace("--gt-scale", option), e.path) from None


def check_raster_pixels(path, what="raster", max_pixels=None):
    """:class:`RiverbedError` when the header of the raster ``path`` claims more than ``max_pixels`` pixels (a
    damaged or forged header would otherwise be read into an "out of memory"); rasters GDAL cannot open pass (their
    reader reports them)."""
    from ..io.images import header_size
    from ..settings import MAX_PIXELS

    limit = MAX_PIXELS if max_pixels is None else max_pixels
    size = header_size(path) if os.path.isfile(path) else None
    if size is not None and size[0] * size[1] > limit:
        raise RiverbedError(f"{what} is {size[0]}x{size[1]} px, more than {limit} pixels (a damaged header?)", path)
