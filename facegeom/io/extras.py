"""The optional packages of facegeom's pixel inputs, asked for by name when they are missing.

Reading and writing video needs PyAV (``av``), the face detector needs LiteRT
(``ai-edge-litert``); both come with the ``video`` extra::

    pip install 'facegeom[video]'

The functions here import them on demand, so facegeom itself imports without
them, and a command that needs one ends in one line saying how to get it
instead of a traceback.
"""
from __future__ import annotations

import os

from facegeom.errors import InputError

__all__ = ["VIDEO_EXTRA", "require_video_extra", "require_detector_runtime"]

#: How to install what video input and the face detector need.
VIDEO_EXTRA = "pip install 'facegeom[video]'"


def require_video_extra(path: str | os.PathLike | None = None, what: str = "reading video"):
    """PyAV's ``av`` module, or a one-line error saying how to install it.

    Parameters
    ----------
    path : str or os.PathLike, optional
        The file that was to be read or written; the error names it.
    what : str, optional
        What needs PyAV, the start of the message (``"reading video"``,
        ``"writing video"``).

    Returns
    -------
    module
        ``av``.

    Raises
    ------
    InputError
        ``"reading video needs PyAV: pip install 'facegeom[video]'"`` when
        ``av`` cannot be imported.
    """
    try:
        import av
    except ImportError:
        raise InputError(f"{what} needs PyAV: {VIDEO_EXTRA}", path) from None
    return av


def require_detector_runtime(path: str | os.PathLike | None = None):
    """LiteRT's interpreter module (``ai_edge_litert.interpreter``), or a one-line error saying how to install it.

    Parameters
    ----------
    path : str or os.PathLike, optional
        The input the detector was to run on; the error names it.

    Returns
    -------
    module
        ``ai_edge_litert.interpreter`` (its ``Interpreter`` runs a ``.tflite`` model).

    Raises
    ------
    InputError
        ``"the face detector needs LiteRT: pip install 'facegeom[video]'"``
        when ``ai_edge_litert`` cannot be imported.
    """
    try:
        from ai_edge_litert import interpreter
    except ImportError:
        raise InputError(f"the face detector needs LiteRT (ai-edge-litert): {VIDEO_EXTRA}", path) from None
    return interpreter
