"""A real peer for landmark blendshape fitting: eos (Patrik Huber's 3DMM fitting library).

:class:`EosFitter` fits *our* rig's delta-blendshapes to 2-D landmarks with the
functions of eos's Python bindings (PyPI ``eos-py``), following the pose /
expression alternation of eos's own ``fit_shape_and_pose`` (without the identity
PCA and contour steps: the rig's neutral is the identity here):

1. ``eos.fitting.estimate_orthographic_projection_linear`` estimates a scaled
   orthographic camera (rotation, scale, 2-D translation) from the landmarks
   and the neutral face's landmark vertices;
2. ``eos.fitting.RenderingParameters`` + ``eos.fitting.get_3x4_affine_camera_matrix``
   turn it into the 3x4 affine model -> pixel matrix;
3. ``eos.fitting.fit_expressions`` with a list of ``eos.morphablemodel.Blendshape``
   solves the expression coefficients (eos: non-negative least squares,
   ``fit_blendshapes_to_landmarks_nnls``, no regulariser and no upper bound);
4. steps 1-3 are repeated ``iterations`` times with the camera re-estimated on
   the current face (neutral + fitted expression), as ``fit_shape_and_pose``
   does (its default is 5 iterations).

Only the landmark vertices take part in eos's computations, so by default
(``compact=True``) the blendshapes handed to eos hold just those ``L``
vertices (and the vertex ids are ``0..L-1``): the same numbers, about 100x
faster than passing the full ``3n`` deformations, which eos copies on every
call.  ``compact=False`` passes the whole rig (for checking).

Differences from our own fitters (what a comparison must keep in mind):

- the camera is eos's **affine** (scaled orthographic) one, estimated from the
  landmarks; the target's :class:`~facegeom.model.camera.PinholeCamera` (pose and focal
  length) is ignored, and perspective effects of the synthetic targets are
  model error for eos;
- the weights are ``>= 0`` but **unbounded** above (eos's NNLS); nothing
  regularises them, so with fewer equations (``2L``) than shapes they can
  over-fit;
- everything in eos is single-precision (float32).
"""
from __future__ import annotations

import time

import numpy as np

from facegeom.errors import InputError, SolveError
from facegeom.interfaces import FitResult, Params, check_range
from facegeom.methods.fitting import check_fit_inputs, result
from facegeom.model import BlendshapeRig, LandmarkTarget

__all__ = ["EosFitter"]

_NOT_INSTALLED = "eos is not installed: pip install 'facegeom[eos]' (eos-py)"


def _import_eos():
    try:
        import eos  # noqa: F401
        import eos.fitting  # noqa: F401
        import eos.morphablemodel  # noqa: F401
    except ImportError:
        raise InputError(_NOT_INSTALLED) from None
    return eos


class EosFitter(Params):
    """Landmark blendshape fitting with eos (``eos.fitting.fit_expressions`` + eos's affine camera).

    Parameters
    ----------
    iterations : int, >= 0
        Camera / expression rounds after the first fit (eos's ``num_iterations``, default 5).
    compact : bool
        Hand eos only the landmark vertices of the blendshapes (same result, faster).

    Raises
    ------
    InputError
        eos is not importable, or a bad parameter.
    """

    def __init__(self, iterations: int = 5, compact: bool = True):
        self._eos = _import_eos()
        iterations = check_range("iterations", iterations, 0, 1000, "eos alternates pose and shape a few times",
                                 integer=True)
        if not isinstance(compact, (bool, np.bool_)):
            raise InputError(f"compact must be true or false, got {compact!r}")
        self.iterations = int(iterations)
        self.compact = bool(compact)
        self._cache_key = None
        self._cache = None

    def __repr__(self) -> str:
        return f"EosFitter(iterations={self.iterations}, compact={self.compact})"

    # ------------------------------------------------------------------ eos model
    def _model(self, rig: BlendshapeRig, ids: np.ndarray):
        """``(blendshapes, face_instance (float32), eos vertex ids, landmark deltas (B, L, 3))`` for
        ``rig`` and landmark vertices ``ids`` (cached for the last rig / ids)."""
        key = (id(rig), self.compact, ids.tobytes())
        if self._cache_key == key and self._cache is not None and self._cache[0] is rig:
            return self._cache[1]
        Blendshape = self._eos.morphablemodel.Blendshape
        if self.compact:
            deltas, face, vids = rig.deltas[:, ids], rig.neutral[ids], list(range(len(ids)))
        else:
            deltas, face, vids = rig.deltas, rig.neutral, [int(i) for i in ids]
        shapes = [Blendshape(name, np.ascontiguousarray(d.reshape(-1), dtype=np.float32))
                  for name, d in zip(rig.names, deltas)]
        model = (shapes, np.ascontiguousarray(face.reshape(-1), dtype=np.float32), vids,
                 np.ascontiguousarray(rig.deltas[:, ids]))
        self._cache_key, self._cache = key, (rig, model)
        return model

    def _camera(self, image_points, model_points: np.ndarray, width: int, height: int):
        """eos's scaled-orthographic estimate -> ``(pose, rendering parameters, 3x4 affine matrix)``."""
        fitting = self._eos.fitting
        homog = [np.array([x, y, z, 1.0], dtype=np.float32) for x, y, z in model_points]
        # our pixels have v downwards (OpenCV-like): eos flips them with the viewport height
        pose = fitting.estimate_orthographic_projection_linear(image_points, homog, True, height)
        params = fitting.RenderingParameters(pose, width, height)
        return pose, params, np.asarray(fitting.get_3x4_affine_camera_matrix(params, width, height))

    # ------------------------------------------------------------------ fit
    def fit(self, rig: BlendshapeRig, target) -> FitResult:
        """Fit ``rig``'s expression to a :class:`~facegeom.model.targets.LandmarkTarget` -> :class:`FitResult`.

        ``info``: ``iterations`` (camera / expression rounds run after the first),
        ``time_s``, ``affine_camera`` (the final 3x4 model -> pixel matrix of eos),
        ``scale``, ``rotation`` (3x3), ``yaw_pitch_roll`` (degrees, eos's),
        ``rms_px_affine`` (landmark RMS error of the fit under eos's camera),
        ``selected`` (names of the shapes with a non-zero weight).
        """
        rig, target = check_fit_inputs(rig, target)
        if not isinstance(target, LandmarkTarget):
            raise InputError("eos fits 2-D landmarks only")
        if target.n_landmarks < 4:
            raise InputError(f"eos needs at least 4 landmarks for its camera, got {target.n_landmarks}")
        t0 = time.perf_counter()
        ids = np.asarray(target.vertex_ids, dtype=np.int64)
        shapes, face, vids, sub_deltas = self._model(rig, ids)
        cam = target.camera
        # eos's camera needs an image size; it only enters through the v flip and cancels (any
        # positive width / height gives the same affine matrix): take the image the principal point centres.
        width = max(1, int(np.ceil(2.0 * abs(cam.cx))))
        height = max(1, int(np.ceil(2.0 * abs(cam.cy))))
        image_points = [np.asarray(p, dtype=np.float32) for p in target.points2d]

        base = rig.neutral[ids]
        current = base
        w = np.zeros(rig.n_shapes)
        for _ in range(self.iterations + 1):
            pose, params, A = self._camera(image_points, current, width, height)
            coeffs = self._eos.fitting.fit_expressions(shapes, face, A.astype(np.float32), image_points, vids)
            w = np.asarray(coeffs, dtype=np.float64)
            if w.shape != (rig.n_shapes,) or not np.all(np.isfinite(w)):
                raise SolveError(f"eos returned {w.size} coefficient(s) for {rig.n_shapes} shapes or a NaN")
            current = base + np.tensordot(w, sub_deltas, axes=1)
        # the camera that goes with the final expression (as eos's loop ends on a pose)
        pose, params, A = self._camera(image_points, current, width, height)
        proj = np.c_[current, np.ones(len(ids))] @ A[:2].T.astype(np.float64)
        rms = float(np.sqrt(((proj - target.points2d) ** 2).sum(axis=1).mean()))
        info = {
            "iterations": self.iterations,
            "time_s": time.perf_counter() - t0,
            "affine_camera": A.astype(np.float64),
            "scale": float(pose.s),
            "rotation": np.asarray(pose.R, dtype=np.float64),
            "yaw_pitch_roll": np.asarray(params.get_yaw_pitch_roll(), dtype=np.float64).ravel(),
            "rms_px_affine": rms,
            "selected": [rig.names[i] for i in np.flatnonzero(w > 0)],
        }
        return result(rig, w, **info)
