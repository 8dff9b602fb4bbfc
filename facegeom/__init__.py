"""facegeom: geometry processing for facial animation, on libigl.

Face driving (deform a mesh from a few markers), expression retargeting
(carry a marker sequence onto another character) and blendshape fitting,
each a set of interchangeable methods behind one small interface
(:mod:`facegeom.interfaces`), discovered through entry points
(:mod:`facegeom.registry`).
"""
from facegeom.errors import DataNotFoundError, FacegeomError, InputError
from facegeom.version import __version__

__all__ = ["__version__", "FacegeomError", "InputError", "DataNotFoundError"]
