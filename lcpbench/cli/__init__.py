"""The ``lcpbench`` command line."""

from lcpbench.cli.app import main

__all__ = ["main"]
