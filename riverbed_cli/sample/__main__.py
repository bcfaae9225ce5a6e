"""``python -m riverbed_cli.sample OUTDIR [options]``: the same as ``riverbed sample OUTDIR [options]`` (the program,
:mod:`riverbed_cli.__main__`)."""

import sys

from riverbed_cli.__main__ import main

if __name__ == "__main__":
    main(["sample", *sys.argv[1:]])
