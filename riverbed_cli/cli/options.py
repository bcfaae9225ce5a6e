"""Options shared by several subcommands, defined once (in the manner of rasterio's ``rio``)."""

import json
import logging
import sys

import click

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


def setup_logging(verbosity):
    level = {-1: logging.ERROR, 0: logging.WARNING, 1: logging.INFO}.get(verbosity, logging.DEBUG)
    logging.basicConfig(level=level, format="riverbed: %(levelname)s: %(message)s", stream=sys.stderr, force=True)
