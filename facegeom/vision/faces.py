"""Every face of a photo: its box, its 468 points and irises, and the 68 landmarks of the iBUG convention.

:class:`FaceFinder` runs the detector (:mod:`facegeom.vision.detector`), then
the face-mesh model on each face's region, twice: the second pass reads the
region the first pass's points give (upright on the eye line, tight on the
face), which is steadier than the detector's box. The 68 landmarks come from
the 468 points through the map between the face-mesh model and the face model
(:mod:`facegeom.vision.correspondence`), with the jaw contour placed on the
face's outline in the image, as annotators and other landmark detectors
place it (:func:`outline_jaw`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facegeom.errors import InputError
from facegeom.vision.detector import FaceDetection, FaceDetector
from facegeom.vision.mesh import MIN_PRESENCE, FaceMesh, FacePoints, region_from_points

__all__ = ["Face", "FaceFinder", "landmarks68"]


@dataclass
class Face:
    """One face of an image.

    Attributes
    ----------
    detection : FaceDetection
        The detector's box, keypoints and score.
    mesh : FacePoints
        The 468 points (image pixels, relative depth), irises and the presence score.
    landmarks : (68, 2) float64
        The 68 landmarks of the iBUG / Multi-PIE convention in 0-based image pixels (a ``.pts`` file adds 1).
    """

    detection: FaceDetection
    mesh: FacePoints
    landmarks: np.ndarray

    @property
    def size(self) -> float:
        """The distance between the outer eye corners, in pixels (the NME normaliser)."""
        return float(np.linalg.norm(self.landmarks[36] - self.landmarks[45]))


def landmarks68(points: np.ndarray) -> np.ndarray:
    """The 68 iBUG landmarks ``(68, 2)`` from the 468 face-mesh points ``(468, 2+)`` of one face (image pixels).

    The inner 51 come through the map onto the face model; the jaw contour is put on the face's outline in the
    image and in the annotators' convention (:func:`facegeom.vision.outline.outline_jaw`).
    """
    from facegeom.vision.correspondence import landmarks68_from_mesh_points
    from facegeom.vision.outline import outline_jaw

    P = np.asarray(points, dtype=np.float64)
    return outline_jaw(P, landmarks68_from_mesh_points(P[:, :2]))


class FaceFinder:
    """Find faces in photos: boxes, 468 points, irises and 68 landmarks.

    Parameters
    ----------
    detector : {"auto", "short", "full"}
        Which face detector (:class:`FaceDetector`).
    iris : bool
        Also find the irises.
    min_presence : float
        A face whose mesh presence score is below this is dropped (a detection that is not a face).
    """

    def __init__(self, detector: str = "auto", iris: bool = True, min_presence: float = MIN_PRESENCE):
        self.detector = FaceDetector(detector)
        self.mesh = FaceMesh(iris=iris)
        self.min_presence = float(min_presence)

    def face(self, image: np.ndarray, detection: FaceDetection) -> Face | None:
        """The face in one detection's region, or None when the mesh model sees no face there."""
        first = self.mesh.run(image, detection.region())
        if first.presence < self.min_presence:
            return None
        second = self.mesh.run(image, region_from_points(first.points))
        best = second if second.presence >= self.min_presence else first
        return Face(detection, best, landmarks68(best.points))

    def find(self, image: np.ndarray, all_faces: bool = False) -> list[Face]:
        """The faces of ``image`` ((H, W, 3) uint8 RGB), largest first; only the largest unless ``all_faces``."""
        a = np.asarray(image)
        if a.ndim != 3 or a.shape[2] != 3 or a.dtype != np.uint8:
            raise InputError(f"an image must be (H, W, 3) uint8 RGB, not {a.shape} {a.dtype}")
        dets = sorted(self.detector.detect(a), key=lambda d: -d.area)
        faces = []
        for d in dets:
            f = self.face(a, d)
            if f is not None:
                faces.append(f)
                if not all_faces:
                    break
        return faces
