"""468 points of a face, and its irises: MediaPipe's face-mesh and iris models run on a region of the image.

The face-mesh model reads a 192 x 192 crop of the face, upright, and returns
468 points (x, y in crop pixels, z a relative depth in the same scale) and a
face-presence logit. The crop comes from a detection (:meth:`FaceDetection.region`)
on the first frame, then from the previous frame's points
(:func:`region_from_points`: their extent in the face's own frame, 1.5x,
turned to the eye line of points 33 and 263), which is how a video is tracked
without running the detector on every frame.

The iris model reads a 64 x 64 crop around one eye (2.3x the eye-corner
distance, turned to the corners' line) and returns 71 eye-contour points
and 5 iris points (centre first). It is trained on one eye; the subject's
left eye is mirrored into it and the points mirrored back.

Coordinates everywhere are image pixels, x right, y down; z is in pixels of
the crop's scale, smaller is nearer the camera, zero near the face's centre.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from facegeom.errors import InputError
from facegeom.vision.models import model_path
from facegeom.vision.runtime import Region, crop, load_interpreter

__all__ = ["FaceMesh", "FacePoints", "region_from_points", "RIGHT_EYE_CORNERS", "LEFT_EYE_CORNERS"]

MESH_SIDE = 192
IRIS_SIDE = 64
REGION_SCALE = 1.5  # the face region is 1.5x the extent of the face (MediaPipe's value)
IRIS_SCALE = 2.3  # the eye region is 2.3x the eye-corner distance (MediaPipe's value)
MIN_PRESENCE = 0.5  # below this the crop holds no face (the tracker falls back to the detector)
# the eye corners of the 468-point mesh (outer, inner), the subject's right eye and left eye
RIGHT_EYE_CORNERS = (33, 133)
LEFT_EYE_CORNERS = (263, 362)


@dataclass
class FacePoints:
    """What the face-mesh (and iris) models found in one region of one image.

    Attributes
    ----------
    points : (468, 3) float64
        x, y in image pixels; z relative depth (pixels, smaller is nearer).
    presence : float
        The model's confidence that the region holds a face, in [0, 1].
    region : Region
        The region the model read.
    iris : (2, 5, 3) float64 or None
        The subject's right and left iris: centre then four points on its rim (image pixels, z as above).
    eyes : (2, 71, 3) float64 or None
        The iris model's eye contours (eyelids and brows), right then left.
    """

    points: np.ndarray
    presence: float
    region: Region
    iris: np.ndarray | None = None
    eyes: np.ndarray | None = None


def region_from_points(points: np.ndarray, scale: float = REGION_SCALE) -> Region:
    """The region the next frame reads: the points' extent in the face's frame (x along the eye line), times
    ``scale``, square."""
    xy = np.asarray(points, dtype=np.float64)[:, :2]
    r, l = xy[RIGHT_EYE_CORNERS[0]], xy[LEFT_EYE_CORNERS[0]]
    angle = math.atan2(l[1] - r[1], l[0] - r[0])
    axes = Region(0, 0, 1, angle).axes()
    local = xy @ axes.T
    lo, hi = local.min(0), local.max(0)
    centre = ((lo + hi) / 2) @ axes
    side = float(max(hi - lo)) * scale
    return Region(float(centre[0]), float(centre[1]), side, angle)


class FaceMesh:
    """MediaPipe's face-mesh model (468 points) and, optionally, its iris model.

    Parameters
    ----------
    iris : bool
        Also run the iris model on both eyes (about 2 x 1.5 ms a frame).
    threads : int
        Interpreter threads per model.
    """

    def __init__(self, iris: bool = True, threads: int = 1):
        self.iris = bool(iris)
        self._mesh = load_interpreter(model_path("face_landmark.tflite"), threads)
        self._iris = load_interpreter(model_path("iris_landmark.tflite"), threads) if self.iris else None

    def run(self, image: np.ndarray, region: Region) -> FacePoints:
        """The 468 points (and irises) of the face in ``region`` of ``image`` ((H, W, 3) uint8 RGB)."""
        a = np.asarray(image)
        if a.ndim != 3 or a.shape[2] != 3 or a.dtype != np.uint8:
            raise InputError(f"an image must be (H, W, 3) uint8 RGB, not {a.shape} {a.dtype}")
        if not (region.size > 0 and math.isfinite(region.size)):
            raise InputError(f"the face region has no size ({region.size})")
        x = crop(a, region, MESH_SIDE)
        raw, logit = self._mesh(x[None])
        local = raw.reshape(468, 3).astype(np.float64)
        pts = np.empty_like(local)
        pts[:, :2] = region.to_image(local[:, :2], MESH_SIDE)
        pts[:, 2] = local[:, 2] * region.size / MESH_SIDE
        presence = float(1.0 / (1.0 + math.exp(-max(min(float(logit.reshape(-1)[0]), 60.0), -60.0))))
        out = FacePoints(points=pts, presence=presence, region=region)
        if self._iris is not None:
            out.iris, out.eyes = self._irises(a, pts)
        return out

    def _eye(self, image: np.ndarray, points: np.ndarray, corners, mirror: bool):
        outer, inner = points[corners[0], :2], points[corners[1], :2]
        # the region's x axis runs from the outer to the inner corner for the right eye; the left eye's region runs
        # from its inner to its outer corner and is mirrored, so both look like the model's own eye
        a, b = (inner, outer) if mirror else (outer, inner)
        angle = math.atan2(b[1] - a[1], b[0] - a[0])
        c = (a + b) / 2
        region = Region(float(c[0]), float(c[1]), float(np.linalg.norm(b - a)) * IRIS_SCALE, angle)
        x = crop(image, region, IRIS_SIDE)
        if mirror:
            x = x[:, ::-1]
        eye_raw, iris_raw = self._iris(x[None])
        res = []
        for raw in (iris_raw.reshape(-1, 3), eye_raw.reshape(-1, 3)):
            local = raw.astype(np.float64).copy()
            if mirror:
                local[:, 0] = IRIS_SIDE - local[:, 0]
            p = np.empty_like(local)
            p[:, :2] = region.to_image(local[:, :2], IRIS_SIDE)
            p[:, 2] = local[:, 2] * region.size / IRIS_SIDE
            res.append(p)
        return res

    def _irises(self, image: np.ndarray, points: np.ndarray):
        r_iris, r_eye = self._eye(image, points, RIGHT_EYE_CORNERS, mirror=False)
        l_iris, l_eye = self._eye(image, points, LEFT_EYE_CORNERS, mirror=True)
        return np.stack([r_iris, l_iris]), np.stack([r_eye, l_eye])
