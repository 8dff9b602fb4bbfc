"""Faces from pixels: MediaPipe's face detector, 468-point face mesh and iris models, run offline on the CPU.

- :mod:`facegeom.vision.models` -- the model files (Apache-2.0), fetched through the package registry and checked;
- :mod:`facegeom.vision.runtime` -- the TFLite interpreter (LiteRT) and rotated crops;
- :mod:`facegeom.vision.detector` -- face boxes and six keypoints (BlazeFace, short and full range);
- :mod:`facegeom.vision.mesh` -- the 468 points and the irises of a face region;
- :mod:`facegeom.vision.correspondence` -- the 468 points on the face model, and the 68 landmarks from them;
- :mod:`facegeom.vision.faces` -- all of it for a photo: every face's points and 68 landmarks.

Nothing here is imported by ``import facegeom``; LiteRT is needed only when a model runs
(``pip install 'facegeom[video]'``).
"""
