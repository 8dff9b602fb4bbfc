"""Constants of the face data shared by every layer (units and the face area).

The ICT face is in centimetres; errors are reported in millimetres. Its first
``FACE_AREA`` vertices are the narrow face (no neck, ears, eyeballs or mouth
interior), where markers and landmarks sit and where face errors are measured.
"""
from __future__ import annotations

__all__ = ["CM_TO_MM", "FACE_AREA", "ICT_VERTICES", "EXPRESSION_WEIGHT_SD"]

CM_TO_MM = 10.0
"""Millimetres per centimetre (the ICT data's unit)."""

FACE_AREA = 6706
"""Vertices ``[0, FACE_AREA)`` of the ICT mesh are the narrow face area."""

ICT_VERTICES = 9409
"""Vertex count of the ICT mesh (the generic face and every rig made from it): rigs with it have the face area."""

EXPRESSION_WEIGHT_SD = 0.2
"""Spread of an expression weight in real performances: the RMS of the 52 ARKit weights of real Live Link Face
takes (four takes: 0.15, 0.16, 0.17 and 0.22; all frames together 0.18). The standard deviation of the Gaussian prior
on each weight where the data leave most of the expression to the prior (landmarks); the marginal likelihood of
real annotated photos agrees (maximised per photo with the weights' bounds respected: about 0.2 on average)."""
