"""Constants of the face data shared by every layer (units and the face area).

The ICT face is in centimetres; errors are reported in millimetres. Its first
``FACE_AREA`` vertices are the narrow face (no neck, ears, eyeballs or mouth
interior), where markers and landmarks sit and where face errors are measured.
"""
from __future__ import annotations

__all__ = ["CM_TO_MM", "FACE_AREA", "ICT_VERTICES"]

CM_TO_MM = 10.0
"""Millimetres per centimetre (the ICT data's unit)."""

FACE_AREA = 6706
"""Vertices ``[0, FACE_AREA)`` of the ICT mesh are the narrow face area."""

ICT_VERTICES = 9409
"""Vertex count of the ICT mesh (the generic face and every rig made from it): rigs with it have the face area."""
