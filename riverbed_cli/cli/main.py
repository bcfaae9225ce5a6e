"""The ``riverbed`` click group. Subcommands live in their own modules and are registered here."""

import click

from ..errors import RiverbedError
from .options import setup_logging


class UserError(click.ClickException):
    """A one-line error for the user: ``riverbed: error: <message>``, exit code 1."""

    def show(self, file=None):
        click.echo(f"riverbed: error: {self.format_message()}", err=True)


class RiverbedGroup(click.Group):
    """Turn library errors into one-line messages instead of tracebacks."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except RiverbedError as e:
            raise UserError(str(e)) from None
        except MemoryError:
            raise UserError("out of memory; match in tiles or reduce the disparity range") from None
        except OSError as e:
            where = f"{e.filename}: " if getattr(e, "filename", None) else ""
            raise UserError(f"{where}{e.strerror or e}") from None


@click.group(cls=RiverbedGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="riverbed")
@click.option("-v", "--verbose", count=True, help="More log output (repeatable).")
@click.option("-q", "--quiet", is_flag=True, help="Only errors.")
def cli(verbose, quiet):
    """riverbed: LiDAR-guided stereo matching, point clouds and DSMs.

    Reference image is the left one; disparity d = x_left - x_right >= 0.
    """
    setup_logging(-1 if quiet else verbose)


def _register():
    from . import dsm, evaluate, match, pair, project

    cli.add_command(pair.pair_cmd)
    cli.add_command(project.project_cmd)
    cli.add_command(match.match_cmd)
    cli.add_command(evaluate.evaluate_cmd)
    cli.add_command(dsm.dsm_cmd)

    from . import sample

    cli.add_command(sample.sample_cmd)

    from . import block

    cli.add_command(block.block_cmd)

    from . import rectify

    cli.add_command(rectify.rectify_cmd)

    from . import benchmark

    cli.add_command(benchmark.benchmark_cmd)


_register()
