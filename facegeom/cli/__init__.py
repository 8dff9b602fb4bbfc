"""The ``facegeom`` command line (also ``python -m facegeom``): one module per command group.

- ``main``: the ``facegeom`` group, ``info``, ``methods`` and the entry point ``main`` (errors as one line);
  the table of the other commands, each imported only when it is used.
- ``lazy``: the group class that lists commands from that table and imports a command on first use.
- ``context``: the group's context object (``--data``, the face model) and shared option parsing.
- ``single``: ``drive``, ``retarget``, ``fit`` and ``animate``, one method run on one input.
- ``bench``: the ``bench`` group, the benchmarks that reproduce the papers' experiments.
- ``demo``: ``demo``, the main job in one command.
- ``cleanup``: ``clean``, ``decimate`` and ``crop``, mesh clean-up with index maps.
- ``view``: the ``view`` group, the interactive polyscope viewer.
- ``batch``: ``batch``, one operation over many inputs on Dask.
- ``data``: the ``data`` group: fetch the face model (verified), build the bundle from a local copy, ``info``.
- ``flags``: library messages rewritten with command-line flag names.

Only this layer speaks of command-line flags.
"""
from facegeom.cli.main import cli, main

__all__ = ["cli", "main"]
