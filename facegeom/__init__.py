"""facegeom: geometry processing for facial animation, on libigl.

Face driving (deform a mesh from a few markers), expression retargeting
(carry a marker sequence onto another character) and blendshape fitting,
each a set of interchangeable methods behind one small interface
(:mod:`facegeom.interfaces`), discovered through entry points
(:mod:`facegeom.registry`).
"""
from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as _version

try:
    __version__ = _version("facegeom")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0+unknown"

from facegeom.errors import DataNotFoundError, FacegeomError, InputError  # noqa: E402

__all__ = ["__version__", "FacegeomError", "InputError", "DataNotFoundError"]
