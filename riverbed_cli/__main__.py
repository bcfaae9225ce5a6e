"""The ``riverbed`` program: the console script and ``python -m riverbed_cli``.

It enters the runtime's ``Env(program=True)`` (:mod:`riverbed_cli.runtime`) before anything else is imported, since
NumPy reads ``NUMPY_MADVISE_HUGEPAGE`` when it is imported, then runs the command line inside it.
"""

import sys

from .runtime import Env


def main(args=None):
    """Run ``riverbed`` with ``args`` (default: the process's arguments) and exit."""
    with Env(program=True):
        try:
            from .cli.main import main as command_line  # inside the Env: NumPy reads its settings at import
        except KeyboardInterrupt:  # Ctrl-C while the command line loads
            print("riverbed: interrupted", file=sys.stderr)
            sys.exit(130)
        command_line(args)


if __name__ == "__main__":
    main()
