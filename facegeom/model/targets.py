"""What a blendshape rig is fitted to: a mesh, 2-D landmarks under a camera, or a point cloud.

All three are validated when built (:class:`~facegeom.errors.InputError`) and
hold read-only arrays; the section numbers are those of the SEM paper (Kang et
al., IEEE Access):

- :class:`MeshTarget`: a mesh in vertex correspondence with the rig (Sec. IV-B),
- :class:`LandmarkTarget`: 2-D image landmarks of known rig vertices seen by a
  :class:`~facegeom.model.camera.PinholeCamera` (Sec. IV-C, the projection
  ``Pi`` of eq. 4),
- :class:`PointCloudTarget`: unordered 3-D points, no correspondence (Sec. IV-D),
- :class:`MarkerTarget`: 3-D positions of known rig vertices (motion-capture
  markers) in any rigid frame, with optional confidences and lost markers
  (solved by :mod:`facegeom.methods.marker_solve`).
"""
from __future__ import annotations

import numpy as np

from facegeom.errors import InputError
from facegeom.interfaces import MAX_COORDINATE, as_handles, as_vertices
from facegeom.model._checks import _as_ids, _first_nonfinite, _readonly
from facegeom.model.camera import PinholeCamera
from facegeom.model.rig import BlendshapeRig

__all__ = ['MeshTarget', 'LandmarkTarget', 'PointCloudTarget', 'MarkerTarget', 'MIN_FACE_PX']

#: Landmarks spanning less than this (pixels, the larger side of their bounding box) hold no face to fit: no
#: annotation or detector places a face's landmarks within one pixel, and the pose's depth follows the face's size
#: in the photo (0.0005 px put the head 2,500 km from the camera). Checked from 4 landmarks (fewer: the fitters'
#: own minimum refuses them).
MIN_FACE_PX = 1.0
#: Landmarks whose second principal spread is below this fraction of the first lie on one line: no pose to estimate.
MIN_LANDMARK_FLATNESS = 1e-3


def _refuse_far(p: np.ndarray, what: str) -> None:
    """Refuse a coordinate beyond :data:`~facegeom.interfaces.MAX_COORDINATE` (NaN, a lost marker, is let by)."""
    with np.errstate(invalid="ignore"):
        far = np.abs(p) > MAX_COORDINATE
    if far.any():
        i = int(np.argwhere(far)[0, 0])
        raise InputError(f"{what} {i} has a coordinate of {float(p[far][0]):.3g}: beyond {MAX_COORDINATE:g}, which no "
                         f"real geometry reaches in any unit")


class MeshTarget:
    """A target mesh in vertex correspondence with the rig (SEM on meshes, Sec. IV-B).

    Parameters
    ----------
    vertices : (n, 3)
        Target positions ``T``.
    weights : (n,) or None
        Optional non-negative per-vertex weights (not all zero).
    """

    __slots__ = ("vertices", "weights")

    def __init__(self, vertices, weights=None):
        self.vertices = _readonly(as_vertices(vertices, "target vertices").copy())
        if weights is not None:
            w = np.asarray(weights, dtype=np.float64)
            n = self.vertices.shape[0]
            if w.shape != (n,):
                raise InputError(f"target weights must have shape ({n},), got {w.shape}")
            if not np.all(np.isfinite(w)):
                raise InputError("target weights contain NaN or inf")
            if (w < 0).any():
                raise InputError(f"target weights must be >= 0 (vertex {int(np.flatnonzero(w < 0)[0])} is negative)")
            if not (w > 0).any():
                raise InputError("target weights are all zero")
            weights = _readonly(w.copy())
        self.weights = weights

    @property
    def n_vertices(self) -> int:
        """Number of target vertices ``n``."""
        return int(self.vertices.shape[0])

    def check(self, rig: BlendshapeRig) -> "MeshTarget":
        """Raise :class:`InputError` unless this target matches ``rig``'s vertex count."""
        if self.n_vertices != rig.n_vertices:
            raise InputError(f"target mesh has {self.n_vertices} vertices, the rig {rig.n_vertices}")
        return self


class LandmarkTarget:
    """2-D landmarks ``l_k`` of rig vertices ``v_k`` seen by ``camera`` (eq. 4, Sec. IV-C).

    Parameters
    ----------
    points2d : (L, 2)
        Pixel positions, finite.
    vertex_ids : (L,)
        Distinct rig vertex ids (checked against a rig by :meth:`check`).
    camera : PinholeCamera
    outline : (L,) bool, optional
        Rows that are marked on the face's *outline* in the photo, as the
        jaw contour of the 68-point convention is (annotations, detectors):
        their vertex id is where the landmark usually lies, but the point is
        wherever the outline is in this view. Default: none (every row is the
        projection of its vertex). Set by the ``.pts`` reader
        (:func:`facegeom.model.read_fit_target`); used by the identity fitter.
    """

    __slots__ = ("points2d", "vertex_ids", "camera", "outline")

    def __init__(self, points2d, vertex_ids, camera: PinholeCamera, outline=None):
        p = np.asarray(points2d, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 2:
            raise InputError(f"landmark points must have shape (L, 2), got {p.shape}")
        if p.shape[0] == 0:
            raise InputError("no landmark: points2d is empty")
        bad = _first_nonfinite(p)
        if bad is not None:
            raise InputError(f"landmark {bad[0]} is NaN or inf")
        _refuse_far(p, "landmark")
        ids = _as_ids(vertex_ids, "landmark vertex_ids")
        if ids.size != p.shape[0]:
            raise InputError(f"{p.shape[0]} landmark points for {ids.size} vertex ids")
        if not isinstance(camera, PinholeCamera):
            raise InputError(f"camera must be a PinholeCamera, got {type(camera).__name__}")
        if p.shape[0] >= 4:
            span = float(np.max(p.max(axis=0) - p.min(axis=0)))
            if not span >= MIN_FACE_PX:
                raise InputError(f"the landmarks span {span:.3g} px: no face to fit (at least {MIN_FACE_PX:g} px; "
                                 f"pixels, not another unit?)")
            sv = np.linalg.svd(p - p.mean(axis=0), compute_uv=False)
            if sv[1] <= MIN_LANDMARK_FLATNESS * sv[0]:
                raise InputError("the landmarks all lie on one line: no face to fit, no pose to estimate")
        self.points2d = _readonly(p.copy())
        self.vertex_ids = _readonly(ids)
        self.camera = camera
        if outline is None:
            o = np.zeros(ids.size, dtype=bool)
        else:
            o = np.asarray(outline)
            if o.dtype != bool or o.shape != (ids.size,):
                raise InputError(f"outline must be a boolean array of shape ({ids.size},), got {o.dtype} {o.shape}")
        self.outline = _readonly(o.copy())

    @property
    def n_landmarks(self) -> int:
        """Number of landmarks ``L``."""
        return int(self.points2d.shape[0])

    @classmethod
    def from_mesh(cls, vertices, vertex_ids, camera: PinholeCamera) -> "LandmarkTarget":
        """Synthetic landmarks: the projection of ``vertices[vertex_ids]``.

        Parameters
        ----------
        vertices : (n, 3) float array
            A face (e.g. a rig evaluation), in the rig's units.
        vertex_ids : (L,) int array
            Distinct vertex ids in ``[0, n)``.
        camera : PinholeCamera

        Raises
        ------
        InputError
            Invalid ids or vertices, or a landmark behind the camera.
        """
        V = as_vertices(vertices)
        ids = as_handles(vertex_ids, V.shape[0], "landmark vertex_ids")
        return cls(camera.project(V[ids], "landmark"), ids, camera)

    def check(self, rig: BlendshapeRig) -> "LandmarkTarget":
        """Raise :class:`InputError` unless every vertex id exists in ``rig``."""
        as_handles(self.vertex_ids, rig.n_vertices, "landmark vertex_ids")
        return self

    def project(self, vertices) -> np.ndarray:
        """``Pi(f_{v_k})`` for a face ``vertices (n, 3)`` -> ``(L, 2)``."""
        V = np.asarray(vertices, dtype=np.float64)
        if V.ndim != 2 or V.shape[1] != 3 or V.shape[0] <= int(self.vertex_ids.max()):
            raise InputError(f"vertices must have shape (n, 3) with n > {int(self.vertex_ids.max())}, got {V.shape}")
        return self.camera.project(V[self.vertex_ids], "landmark")

    def subset(self, rows) -> "LandmarkTarget":
        """The landmarks at ``rows`` ``(r,)`` int (indices into this target), same camera.

        Raises
        ------
        InputError
            ``rows`` empty, not 1-D integers, or out of range.
        """
        r = np.asarray(rows)
        if r.ndim != 1 or r.size == 0 or not np.issubdtype(r.dtype, np.integer):
            raise InputError("rows must be a non-empty 1-D array of integers")
        if r.min() < -self.n_landmarks or r.max() >= self.n_landmarks:
            raise InputError(f"row out of range [0, {self.n_landmarks})")
        return LandmarkTarget(self.points2d[r], self.vertex_ids[r], self.camera, self.outline[r])

    def rows_of(self, vertex_ids) -> np.ndarray:
        """Row of each of ``vertex_ids`` in this target -> ``(r,)`` int64; InputError for an absent id."""
        pos = {int(v): i for i, v in enumerate(self.vertex_ids)}
        out = []
        for v in np.atleast_1d(np.asarray(vertex_ids)).tolist():
            if int(v) not in pos:
                raise InputError(f"vertex {int(v)} is not among the target's landmarks")
            out.append(pos[int(v)])
        return np.asarray(out, dtype=np.int64)


class PointCloudTarget:
    """Unordered target points (a scan), optionally with normals (Sec. IV-D).

    Parameters
    ----------
    points : (N, 3), N >= 1, finite.
    normals : (N, 3) or None; non-zero, finite; stored normalised.
    """

    __slots__ = ("points", "normals")

    def __init__(self, points, normals=None):
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise InputError(f"point cloud must have shape (N, 3), got {p.shape}")
        if p.shape[0] == 0:
            raise InputError("point cloud is empty")
        bad = _first_nonfinite(p)
        if bad is not None:
            raise InputError(f"point cloud point {bad[0]} is NaN or inf")
        _refuse_far(p, "point cloud point")
        if normals is not None:
            nr = np.asarray(normals, dtype=np.float64)
            if nr.shape != p.shape:
                raise InputError(f"normals must have shape {p.shape}, got {nr.shape}")
            bad = _first_nonfinite(nr)
            if bad is not None:
                raise InputError(f"normal {bad[0]} is NaN or inf")
            length = np.linalg.norm(nr, axis=1)
            if (length <= 1e-12).any():
                raise InputError(f"normal {int(np.flatnonzero(length <= 1e-12)[0])} is zero")
            normals = _readonly(nr / length[:, None])
        self.points = _readonly(p.copy())
        self.normals = normals

    @property
    def n_points(self) -> int:
        """Number of points ``N``."""
        return int(self.points.shape[0])


class MarkerTarget:
    """3-D marker positions of known rig vertices, in any rigid frame (a capture).

    The capture's frame need not be the rig's: the solve estimates the rigid
    head pose with the expression (:mod:`facegeom.methods.marker_solve`).

    Parameters
    ----------
    positions : (p, 3)
        Marker positions; a row with a NaN is a lost marker (ignored). inf is an error.
    vertex_ids : (p,)
        Distinct rig vertex ids (checked against a rig by :meth:`check`).
    confidence : (p,) or None
        Optional per-marker weights ``>= 0`` (0 ignores the marker).

    Raises
    ------
    InputError
        Wrong shapes, inf, repeated ids, negative or non-finite confidences,
        or fewer than 3 usable markers (found and with a positive confidence).
    """

    __slots__ = ("positions", "vertex_ids", "confidence")

    def __init__(self, positions, vertex_ids, confidence=None):
        p = np.asarray(positions, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise InputError(f"marker positions must have shape (p, 3), got {p.shape}")
        if p.shape[0] == 0:
            raise InputError("no marker: positions is empty")
        if np.isinf(p).any():
            raise InputError(f"marker {int(np.argwhere(np.isinf(p))[0, 0])} has an infinite coordinate")
        _refuse_far(p, "marker")
        ids = _as_ids(vertex_ids, "marker vertex_ids")
        if ids.size != p.shape[0]:
            raise InputError(f"{p.shape[0]} marker positions for {ids.size} vertex ids")
        lost = np.isnan(p).any(axis=1)
        p[lost] = np.nan
        if confidence is not None:
            c = np.asarray(confidence, dtype=np.float64)
            if c.shape != (p.shape[0],):
                raise InputError(f"marker confidence must have shape ({p.shape[0]},), got {c.shape}")
            if not np.all(np.isfinite(c)):
                raise InputError("marker confidence contains NaN or inf")
            if (c < 0).any():
                raise InputError(f"marker confidence must be >= 0 (marker {int(np.flatnonzero(c < 0)[0])} is negative)")
            confidence = _readonly(c.copy())
        usable = ~lost if confidence is None else (~lost & (confidence > 0))
        if int(usable.sum()) < 3:
            raise InputError(f"only {int(usable.sum())} usable markers (found, confidence > 0): "
                             "at least 3 are needed for the head pose")
        self.positions = _readonly(p.copy())
        self.vertex_ids = _readonly(ids)
        self.confidence = confidence

    @property
    def n_markers(self) -> int:
        """Number of markers ``p`` (lost ones included)."""
        return int(self.positions.shape[0])

    @property
    def lost(self) -> np.ndarray:
        """``(p,)`` bool: the marker has no position (NaN)."""
        return np.isnan(self.positions).any(axis=1)

    def marker_weights(self) -> np.ndarray:
        """``(p,)`` float64 weight of each marker: its confidence (1 without), 0 when lost."""
        w = np.ones(self.n_markers) if self.confidence is None else np.array(self.confidence)
        w[self.lost] = 0.0
        return w

    def check(self, rig: BlendshapeRig) -> "MarkerTarget":
        """Raise :class:`InputError` unless every vertex id exists in ``rig``."""
        as_handles(self.vertex_ids, rig.n_vertices, "marker vertex_ids")
        return self
