"""``python -m riverbed_cli.sample OUTDIR [options]``: the same as ``riverbed sample OUTDIR [options]``.

The only module of the package that imports the command line (it is the top of the stack, never imported)."""

import sys

from riverbed_cli.cli.main import cli

cli.main(args=["sample", *sys.argv[1:]], prog_name="riverbed")
