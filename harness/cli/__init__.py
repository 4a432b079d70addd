"""Command line of the harness (``python -m harness COMMAND``): see
:mod:`harness.cli.commands`."""

from harness.cli.commands import main

__all__ = ["main"]
