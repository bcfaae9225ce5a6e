"""The ``riverbed`` command line: one thin click module per subcommand over a library function.

Importing it changes nothing in the process; the program (:func:`.main.main`) runs its commands inside
:class:`riverbed_cli.runtime.Env`.
"""
