"""The ``shellspline`` command line: argument parsing, subcommands, exit codes, progress.

The entry point is :func:`shellspline.cli.main.main`; every other subcommand lives in a module
of its own here and registers its parsers there.
"""
