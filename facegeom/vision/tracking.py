"""One face followed through a video: the 468 points and the irises frame by frame, the detector only when lost.

:class:`FaceTracker` keeps the previous frame's points: the next frame's
face-mesh region is where they were (:func:`facegeom.vision.mesh.region_from_points`),
so a frame costs the mesh model (about 5 ms) and the iris model (about 5 ms)
but not the detector. The detector runs on the first frame, after a frame
whose presence score fell below :data:`facegeom.vision.mesh.MIN_PRESENCE`
(the face left, was covered or moved too fast), and every
:data:`REDETECT_EVERY` frames while lost. When it finds several faces, the one
nearest the last known face is taken (the largest on the first frame), and
the count is reported: a second person walking through does not take over
the track.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facegeom.vision.detector import FaceDetector
from facegeom.vision.mesh import MIN_PRESENCE, FaceMesh, region_from_points

__all__ = ["FaceTracker", "TrackedFrame"]

REDETECT_EVERY = 1  # while lost, the detector runs on every frame (offline: a face must not be missed)


@dataclass
class TrackedFrame:
    """What the tracker found in one frame.

    Attributes
    ----------
    points : (468, 3) float64 or None
        The face-mesh points (image pixels, relative depth); None: no face.
    iris : (2, 5, 3) float64 or None
        The subject's right and left iris (centre first).
    presence : float
        The mesh model's face-presence score (0 when no face was found).
    detected : bool
        The detector ran on this frame.
    faces : int
        Faces the detector saw when it ran (0 otherwise).
    """

    points: np.ndarray | None
    iris: np.ndarray | None
    presence: float
    detected: bool
    faces: int


class FaceTracker:
    """Follow the face of a video frame by frame (see the module docstring).

    Parameters
    ----------
    detector : {"auto", "short", "full"}
        The face detector (:class:`~facegeom.vision.detector.FaceDetector`).
    iris : bool
        Also track the irises.
    min_presence : float
        Below this presence score a frame has no face.
    """

    def __init__(self, detector: str = "auto", iris: bool = True, min_presence: float = MIN_PRESENCE):
        self.detector = FaceDetector(detector)
        self.mesh = FaceMesh(iris=iris)
        self.min_presence = float(min_presence)
        self.previous: np.ndarray | None = None
        self.last_centre: np.ndarray | None = None
        self.detections = 0

    def reset(self) -> None:
        """Forget the face (the next frame runs the detector)."""
        self.previous = None

    def _detect(self, image: np.ndarray):
        dets = self.detector.detect(image)
        self.detections += 1
        if not dets:
            return None, 0
        if self.last_centre is None:
            best = max(dets, key=lambda d: d.area)
        else:
            centre = self.last_centre
            best = min(dets, key=lambda d: float(np.linalg.norm((d.box[:2] + d.box[2:]) / 2 - centre)))
        first = self.mesh.run(image, best.region())
        if first.presence < self.min_presence:
            return None, len(dets)
        return self.mesh.run(image, region_from_points(first.points)), len(dets)

    def step(self, image: np.ndarray) -> TrackedFrame:
        """Track one frame ((H, W, 3) uint8 RGB)."""
        found, detected, faces = None, False, 0
        if self.previous is not None:
            found = self.mesh.run(image, region_from_points(self.previous))
            if found.presence < self.min_presence:
                found = None
        if found is None:
            found, faces = self._detect(image)
            detected = True
        if found is None or found.presence < self.min_presence:
            self.previous = None
            return TrackedFrame(None, None, 0.0 if found is None else found.presence, detected, faces)
        self.previous = found.points
        self.last_centre = found.points[:, :2].mean(axis=0)
        return TrackedFrame(found.points, found.iris, found.presence, detected, faces)
