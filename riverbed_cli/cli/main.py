"""The ``riverbed`` click group. Subcommands live in their own modules, listed in :data:`COMMANDS` and imported
only when they run (or their ``--help`` is asked for): ``riverbed --help`` loads no subcommand, as rasterio's
``rio`` loads its commands from entry points."""

import contextlib
import functools
import importlib
import sys

import click

from ..errors import RiverbedError, one_line
from ..io.atomic import release_claims
from .. import runtime
from ..runtime.threads import threads as kernel_threads
from .options import setup_logging


class UserError(click.ClickException):
    """A one-line error for the user: ``riverbed: error: <message>``, exit code 1."""

    def show(self, file=None):
        # one printable line whatever the message quotes (a file's text may hold escape codes or newlines)
        click.echo(f"riverbed: error: {one_line(self.format_message())}", err=True)


class Interrupted(click.ClickException):
    """Ctrl-C: ``riverbed: interrupted`` and exit code 130 (128 + SIGINT), as a shell reports it."""

    exit_code = 130

    def __init__(self):
        super().__init__("interrupted")

    def show(self, file=None):
        click.echo("riverbed: interrupted", err=True)


def usage_error(e):
    """A click usage error (unknown option, missing argument, bad choice) as a :class:`UserError`: one line naming
    the command's help, exit code 1 (click prints three lines and exits 2). A bare ``riverbed`` keeps its help."""
    if isinstance(e, getattr(click.exceptions, "NoArgsIsHelpError", ())):
        return e  # bare `riverbed`: its help, as click shows it
    path = e.ctx.command_path if e.ctx is not None else "riverbed"
    return UserError(f"{e.format_message()} (see {path} --help)")


def interrupted_by_user(e):
    """True for a KeyboardInterrupt, or an error raised because of one (a Numba kernel interrupted by Ctrl-C
    surfaces as a SystemError whose context is the KeyboardInterrupt)."""
    seen = set()
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False


#: name -> (module under riverbed_cli.cli, command object, one line for ``riverbed --help``)
COMMANDS = {
    "pair": ("pair", "pair_cmd", "Write a pair file (the geometry of a rectified pair) from a benchmark calibration."),
    "project": ("project", "project_cmd", "Project a LiDAR cloud through a pair file into sparse disparities."),
    "match": ("match", "match_cmd", "Match a rectified pair into a disparity map, optionally guided by LiDAR."),
    "densify": ("densify", "densify_cmd", "Interpolate sparse LiDAR into a dense disparity map (no matching)."),
    "range-map": ("range_map", "range_map_cmd", "Per-pixel disparity ranges for match --range-map from a previous "
                  "disparity map."),
    "evaluate": ("evaluate", "evaluate_cmd", "Compare a disparity map (or a DSM) with ground truth."),
    "dsm": ("dsm", "dsm_cmd", "Triangulate disparity maps of pairs into a point cloud and a DSM."),
    "sample": ("sample", "sample_cmd", "Generate the synthetic aerial block (pair, LiDAR, ground truth)."),
    "block": ("block", "block_cmd", "Run a block manifest on dask and merge its DSMs (or split-rpc a scene)."),
    "rectify": ("rectify", "rectify_cmd", "Rectify raw frames with their orientations into a pair."),
    "orient": ("orient", "orient_cmd", "Import orientations (Orthority, OpenSfM/ODM, COLMAP) as orientation files."),
    "benchmark": ("benchmark", "benchmark_cmd", "Run the paper's protocol (matchers x guides x LiDAR shares)."),
}


def _before_kernels(callback):
    """``callback`` (a command's) preceded by :func:`riverbed_cli.runtime.before_kernels`: when the command runs,
    not when its ``--help`` is asked for (which loads no Numba)."""

    @functools.wraps(callback)
    def run(*args, **kwargs):
        ctx = click.get_current_context(silent=True)
        threads = (ctx.find_root().obj or {}).get("threads") if ctx is not None else None
        with kernel_threads(threads) if threads is not None else contextlib.nullcontext():
            runtime.before_kernels()
            return callback(*args, **kwargs)

    run.riverbed_runtime = True
    return run


#: commands that import their library only when they run, and end the program's start-up themselves
#: (``riverbed match``: once its kernels are loaded, ``scale/match_files.py``); the others' start-up ends when their
#: module has been imported (:mod:`~riverbed_cli.scale.collector`)
LATE_START_UP = {"match"}


class RiverbedGroup(click.Group):
    """Subcommands loaded on demand; library errors turned into one-line messages instead of tracebacks."""

    def list_commands(self, ctx):
        return list(COMMANDS)

    def get_command(self, ctx, name):
        if name not in COMMANDS:
            return None
        module, attr, _ = COMMANDS[name]
        command = getattr(importlib.import_module(f"{__package__}.{module}"), attr)
        if name not in LATE_START_UP:
            runtime.start_up_done()  # its modules are loaded: the collector on again (in the program only)
        if not getattr(command.callback, "riverbed_runtime", False):
            command.callback = _before_kernels(command.callback)
        return command

    def format_commands(self, ctx, formatter):
        # the one-line help from the table: listing the commands imports none of them
        with formatter.section("Commands"):
            formatter.write_dl([(name, line) for name, (_, _, line) in COMMANDS.items()])

    def make_context(self, info_name, args, parent=None, **extra):
        try:  # the group's own options (riverbed --bogus)
            return super().make_context(info_name, args, parent=parent, **extra)
        except click.UsageError as e:
            raise usage_error(e) from None
        except KeyboardInterrupt:
            raise Interrupted() from None

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except click.UsageError as e:  # a subcommand's options and arguments
            raise usage_error(e) from None
        except KeyboardInterrupt:
            raise Interrupted() from None
        except SystemError as e:
            if interrupted_by_user(e):
                raise Interrupted() from None
            raise
        except RiverbedError as e:
            raise UserError(str(e)) from None
        except MemoryError:
            raise UserError("out of memory; match in tiles or reduce the disparity range") from None
        except OSError as e:
            where = f"{e.filename}: " if getattr(e, "filename", None) else ""
            raise UserError(f"{where}{e.strerror or e}") from None
        finally:
            release_claims()  # the outputs this command claimed and did not write: temporaries removed, unlocked


@click.group(cls=RiverbedGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="riverbed")
@click.option("-v", "--verbose", count=True, help="More log output (repeatable).")
@click.option("-q", "--quiet", is_flag=True, help="Only errors.")
@click.option("--threads", type=int, default=None, metavar="N",
              help="Threads of the kernels (Numba and OpenCV) [default: all, NUMBA_NUM_THREADS]. The outputs are the "
                   "same for any count.")
@click.pass_context
def cli(ctx, verbose, quiet, threads):
    """riverbed: LiDAR-guided stereo matching, point clouds and DSMs.

    Reference image is the left one; disparity d = x_left - x_right >= 0.
    """
    setup_logging(-1 if quiet else verbose)
    ctx.obj = {"threads": threads}


def main(args=None):
    """The ``riverbed`` program's command line (called by :func:`riverbed_cli.__main__.main`, inside the runtime's
    ``Env(program=True)``, which turns the garbage collector off until the command's modules are loaded). Exits."""
    try:
        cli.main(args=args, prog_name="riverbed")
    except KeyboardInterrupt:  # Ctrl-C outside a command's run (while its modules load)
        Interrupted().show()
        sys.exit(Interrupted.exit_code)
