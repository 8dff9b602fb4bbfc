"""Library messages in command-line words: one table from Python arguments to flags.

Code below the front ends raises errors that name the Python argument a caller
can change (``pass fill=True ...``, ``Pass path=PATH or set FACEGEOM_DATA``).
The command line prints every :class:`~facegeom.errors.FacegeomError` through
:func:`as_flags`, which rewrites those phrases into the flags that set the
same arguments, so a CLI user reads ``pass --fill-gaps ...``.

A library message that should show a flag on the command line uses one of the
phrases below verbatim (or adds its own entry here); the phrases are specific
enough not to occur in other text.
"""
from __future__ import annotations

__all__ = ["ARGUMENT_FLAGS", "as_flags"]

#: phrase of a library message -> the same phrase on the command line
ARGUMENT_FLAGS: dict[str, str] = {
    "pass fill=True": "pass --fill-gaps",  # io.read_retarget_inputs(fill=) / retarget --fill-gaps
    "use kind='points'": "use --kind points",  # model.read_fit_target(kind=) / fit --kind
    "the camera: focal, cx and cy": "the camera: --focal, --cx and --cy",  # read_fit_target / fit
    "or the photo they were marked on to take them from": "or --image PHOTO (the photo they were marked on)",
    "clean the mesh with largest_component=True": "facegeom clean --largest",  # pipelines.cleanup.clean
    "the path argument (not given), $FACEGEOM_DATA": "the --data option (not given), $FACEGEOM_DATA",
    "Pass path=PATH or set FACEGEOM_DATA": "Pass --data PATH or set FACEGEOM_DATA",  # model.locate_data(path)
    "the path argument (not given), $FACEGEOM_TAKES": "the --takes option (not given), $FACEGEOM_TAKES",
    "Pass path=PATH or set FACEGEOM_TAKES": "pass --takes FOLDER or set FACEGEOM_TAKES",  # model.locate_takes
    "pass drop_lost=True": "pass --drop-lost-markers",  # pipelines.cleanup.carry_vertex_csv(drop_lost=)
    "pass markers=MAP.csv": "pass --markers MAP.csv",  # pipelines.solve.marker_vertices(markers=) / solve --markers
    "a layout, markers=ict80": "a layout, --markers ict80",  # the same
    "the vertex target must be": "--vertices must be",  # pipelines.cleanup.decimate(vertices=)
    "pass verify=False": "pass --no-verify",
    "pass partial=True": "pass --partial",
    "pass force=True": "use --force",  # pipelines.examples.write_examples(force=) / data examples --force  # model.download.build_bundle(partial=) / data build --partial  # model.download.build_bundle(verify=) / data build --no-verify
    "neutral=NAME": "--neutral NAME",  # model.rig.find_neutral / model.load_rig(neutral=) / --neutral
    "names=MAP.csv": "--names MAP.csv",  # model.load_rig(names=) / --names
    "units=mm|cm|m": "--units mm|cm|m",  # model.units.rig_frame(units=) / --units
    "up=y|z": "--up y|z",  # model.units.rig_frame(up=) / --up
    "(rig_path=)": "(--rig)",  # model.load_rig(rig_path=) / --rig
    "pass identity='off'": "pass --identity off",  # pipelines.solve.solve_file(identity=) / solve --identity
    "solve with identity='auto'": "solve without --identity off",  # the same
    "give it a role with roles= (": "give it a role with --piece NAME=ROLE (",  # methods.transfer(roles=) / --piece
}


def as_flags(message: str) -> str:
    """Return ``message`` with every argument phrase of :data:`ARGUMENT_FLAGS` replaced by its flags.

    Parameters
    ----------
    message : str
        An error message of the library.

    Returns
    -------
    str
        The message as the command line prints it.
    """
    for phrase, flags in ARGUMENT_FLAGS.items():
        message = message.replace(phrase, flags)
    return message
