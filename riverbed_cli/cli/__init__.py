"""The ``riverbed`` command line: one thin click module per subcommand over a library function."""
