"""The options every command with ``--rig`` shares: ``--neutral``, ``--names``, ``--units``, ``--up``.

:func:`rig_options` adds them to a command (its function receives ``neutral``,
``names_map``, ``units`` and ``up``); :func:`load_cli_rig` loads the rig with
them (:func:`facegeom.model.load_rig`) and prints the note line saying what
was found: shapes, neutral, units, up axis, naming convention and the shapes
that do not cross to ICT names, by name.
"""
from __future__ import annotations

import click

from facegeom.cli.flags import as_flags

__all__ = ["RIG_OPTION_NAMES", "load_cli_rig", "rig_options"]

#: The parameters :func:`rig_options` adds (as the command function receives them).
RIG_OPTION_NAMES = ("neutral", "names_map", "units", "up")

_OPTIONS = (
    click.option("--neutral", default=None, metavar="NAME",
                 help="With --rig FOLDER: the neutral OBJ (NAME or NAME.obj); default: the one OBJ called neutral, "
                      "base, neutral_mesh, default or basis, in any case."),
    click.option("--names", "names_map", type=click.Path(dir_okay=False), default=None, metavar="MAP.csv",
                 help="A shape mapping CSV rig_shape,source_shape,gain (gain default 1; rows of one rig shape add "
                      "up): how ICT / ARKit weights drive the rig's shapes. Default: matched by name (ICT "
                      "eyeBlink_L = ARKit eyeBlinkLeft / EyeBlinkLeft, any case, exporter prefixes and .001 "
                      "suffixes ignored; ARKit browInnerUp / cheekPuff = the mean of ICT's two sides)."),
    click.option("--units", type=click.Choice(["auto", "mm", "cm", "m"]), default="auto", show_default=True,
                 help="The rig's length unit; auto: what the file states (glTF: m), else found from the face's "
                      "size."),
    click.option("--up", type=click.Choice(["auto", "y", "z"]), default="auto", show_default=True,
                 help="The rig's up axis (Z-up: Blender / 3ds Max, face along -Y); auto: glTF's Y, else from where "
                      "its shapes move the face."),
)


def rig_options(func):
    """Add ``--neutral``, ``--names``, ``--units`` and ``--up`` to a click command (in that order)."""
    for option in reversed(_OPTIONS):
        func = option(func)
    return func


def rig_options_given(neutral, names_map, units, up) -> bool:
    """Any of the four options set (not at its default)."""
    return neutral is not None or names_map is not None or units != "auto" or up != "auto"


def load_cli_rig(rig_path, face_model, neutral=None, names_map=None, units="auto", up="auto", echo=click.echo):
    """The rig of a command (``rig_path`` None: the ICT face of ``face_model()``), its note line printed."""
    from facegeom.model import load_rig

    notes: list[str] = []
    rig = load_rig(rig_path, face_model, neutral=neutral, names=names_map, units=units, up=up, notes=notes)
    for line in notes:
        echo(as_flags(line))
    return rig
