"""The ``facegeom`` command line (also ``python -m facegeom``): one module per command group.

``main`` holds the group and the single-item commands (drive, retarget, fit,
animate, bench, demo); ``cleanup``, ``view`` and ``batch`` register their
commands on it. Only this layer speaks of command-line flags.
"""
from facegeom.cli.main import cli, main

__all__ = ["cli", "main"]
