"""The pinhole camera of landmark fitting (intrinsics and an optional rigid pose).

A :class:`~facegeom.model.targets.LandmarkTarget` holds one; :func:`look_at_camera`
frames a face from the front; :mod:`facegeom.model.pose` estimates the pose
when it is unknown.

Convention
----------
World -> camera is ``x_cam = R @ x + t``.  Camera space is OpenGL-like: x to
the right, y up, the camera at the origin looking down **-z** (the ICT face
has +z towards the viewer, so the identity rotation sees it from the front).
Pixels: ``u = cx + f * x / (-z)`` (to the right), ``v = cy - f * y / (-z)``
(downwards, image rows).  A point with ``-z <= 0`` is behind the camera and
cannot be projected (:class:`~facegeom.errors.InputError`).  With this
convention the subject's right eye (landmark 36, world -x) appears on the
image's left, as in a photograph.
"""
from __future__ import annotations

import numpy as np

from facegeom.errors import InputError
from facegeom.interfaces import as_vertices
from facegeom.model._checks import _as_scalar, _first_nonfinite, _readonly

__all__ = ['PinholeCamera', 'look_at_camera']


class PinholeCamera:
    """A pinhole camera; see the module docstring for the convention.

    ``x_cam = R @ x + t``; camera looks down -z, x right, y up;
    ``u = cx + focal * x_cam / (-z_cam)``, ``v = cy - focal * y_cam / (-z_cam)``.

    Parameters
    ----------
    focal : float
        Focal length in pixels (> 0).
    cx, cy : float
        Principal point in pixels.
    R : (3, 3) rotation (world -> camera), default identity.
    t : (3,) translation, default zero.

    Attributes
    ----------
    R : (3, 3) float64, t : (3,) float64
        Read-only copies of the pose.
    posed : bool
        Whether ``R`` or ``t`` was given; ``False`` means the pose is unknown
        (the fitters estimate it).

    Raises
    ------
    InputError
        ``focal`` not a positive finite number, ``cx`` / ``cy`` not finite,
        ``R`` not a ``(3, 3)`` rotation (orthonormal, det +1), ``t`` not a
        finite ``(3,)`` vector.
    """

    __slots__ = ("focal", "cx", "cy", "R", "t", "posed")

    def __init__(self, focal: float, cx: float, cy: float, R=None, t=None):
        self.posed = R is not None or t is not None  # False: the pose is unknown (fitters estimate it)
        self.focal = _as_scalar(focal, "focal", positive=True)
        self.cx = _as_scalar(cx, "cx")
        self.cy = _as_scalar(cy, "cy")
        if R is None:
            R = np.eye(3)
        R = np.asarray(R, dtype=np.float64)
        if R.shape != (3, 3):
            raise InputError(f"camera rotation R must have shape (3, 3), got {R.shape}")
        if not np.all(np.isfinite(R)):
            raise InputError("camera rotation R contains NaN or inf")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise InputError("camera rotation R must be a rotation matrix (orthonormal, det +1)")
        if t is None:
            t = np.zeros(3)
        t = np.asarray(t, dtype=np.float64)
        if t.shape != (3,):
            raise InputError(f"camera translation t must have shape (3,), got {t.shape}")
        if not np.all(np.isfinite(t)):
            raise InputError("camera translation t contains NaN or inf")
        self.R = _readonly(R.copy())
        self.t = _readonly(t.copy())

    def __repr__(self) -> str:
        return f"PinholeCamera(focal={self.focal:g}, cx={self.cx:g}, cy={self.cy:g}, t={self.t.tolist()})"

    def with_pose(self, R, t) -> "PinholeCamera":
        """The same intrinsics with the pose ``(R, t)`` (world -> camera)."""
        return PinholeCamera(self.focal, self.cx, self.cy, R, t)

    @property
    def center(self) -> np.ndarray:
        """The camera position in world coordinates, ``-R.T @ t``."""
        return -self.R.T @ self.t

    def to_camera(self, points) -> np.ndarray:
        """World ``(N, 3)`` -> camera coordinates ``(N, 3)``."""
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise InputError(f"points must have shape (N, 3), got {p.shape}")
        bad = _first_nonfinite(p)
        if bad is not None:
            raise InputError(f"point {bad[0]} is NaN or inf")
        return p @ self.R.T + self.t

    def _depth(self, pc: np.ndarray, what: str) -> np.ndarray:
        depth = -pc[:, 2]
        bad = ~(depth > 0)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise InputError(
                f"{what} {i} is behind the camera (depth {depth[i]:.6g}; the camera looks down -z)")
        return depth

    def project(self, points, what: str = "point") -> np.ndarray:
        """World points ``(N, 3)`` -> pixels ``(N, 2)`` (``Pi`` of eq. 4).

        ``what`` names the points in the error message ("landmark 3 is behind the camera").
        """
        pc = self.to_camera(points)
        depth = self._depth(pc, what)
        return np.c_[self.cx + self.focal * pc[:, 0] / depth, self.cy - self.focal * pc[:, 1] / depth]

    def jacobian(self, points, what: str = "point") -> np.ndarray:
        """d(u, v) / d(world x, y, z) at each point -> ``(N, 2, 3)``."""
        pc = self.to_camera(points)
        depth = self._depth(pc, what)
        f = self.focal
        J = np.zeros((pc.shape[0], 2, 3))
        # u = cx - f X / Z, v = cy + f Y / Z with Z = -depth
        J[:, 0, 0] = f / depth
        J[:, 0, 2] = f * pc[:, 0] / depth**2
        J[:, 1, 1] = -f / depth
        J[:, 1, 2] = -f * pc[:, 1] / depth**2
        return J @ self.R


def look_at_camera(vertices, focal: float = 1000.0, image_size: tuple[int, int] = (640, 480),
                   distance: float | None = None, yaw: float = 0.0, pitch: float = 0.0,
                   fill: float = 0.8) -> PinholeCamera:
    """A camera that frames ``vertices`` (a face, +z towards the viewer) from the front.

    The camera sits on the +z side of the bounding-box centre at ``distance``
    and looks at it (``R = I`` when ``yaw = pitch = 0``); ``yaw`` (about +y) and
    ``pitch`` (about +x), in degrees, orbit it around the centre.  The
    principal point is the image centre.  With ``distance=None`` the distance is
    chosen so that the face's bounding box fills ``fill`` of the image.

    Parameters
    ----------
    vertices : (n, 3) float array
        The points to frame (cm for the ICT face).
    focal : float
        Focal length in pixels.
    image_size : (width, height)
        In pixels; the principal point is its centre.
    distance : float, optional
        From the camera to the bounding-box centre, in the units of ``vertices``.
    yaw, pitch : float
        Orbit angles in degrees.
    fill : float
        Fraction of the smaller image side the bounding sphere covers (when
        ``distance`` is None).

    Returns
    -------
    PinholeCamera
        Posed, with ``x_cam = R @ x + t``.

    Raises
    ------
    InputError
        Invalid vertices, a non-positive focal, size, fill or distance, or a
        non-finite angle.
    """
    V = as_vertices(vertices)
    f = _as_scalar(focal, "focal", positive=True)
    try:
        W, H = (float(s) for s in image_size)
    except (TypeError, ValueError):
        raise InputError(f"image_size must be (width, height), got {image_size!r}") from None
    if not (W > 0 and H > 0 and np.isfinite(W) and np.isfinite(H)):
        raise InputError(f"image_size must be positive, got {image_size!r}")
    fill = _as_scalar(fill, "fill", positive=True)
    lo, hi = V.min(axis=0), V.max(axis=0)
    center = 0.5 * (lo + hi)
    ext = hi - lo
    radius = 0.5 * float(np.linalg.norm(ext))
    if distance is None:
        # the whole bounding sphere fits in fill * the smaller image side
        distance = radius + f * 2 * radius / (fill * min(W, H))
    distance = _as_scalar(distance, "distance", positive=True)
    a, b = np.deg2rad(_as_scalar(yaw, "yaw")), np.deg2rad(_as_scalar(pitch, "pitch"))
    Ry = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    Rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    M = Ry @ Rx  # camera -> world rotation: columns are the camera axes in world space
    eye = center + M @ np.array([0.0, 0.0, distance])
    R = M.T
    return PinholeCamera(f, W / 2.0, H / 2.0, R, -R @ eye)
