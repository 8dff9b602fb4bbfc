"""A real peer for identity fitting: eos's ``fit_shape_and_pose`` on a morphable model built from the ICT arrays.

:class:`EosIdentityFitter` fits identity, camera and expression to the 2-D
landmarks of one image with eos (PyPI ``eos-py``), the same job as
:class:`facegeom.methods.identity.IdentityFitter` on a landmark target:

1. the ICT identity modes at the landmark vertices, ``M (3L, I)``, become an
   eos :class:`PcaModel`: ``M = U S V'`` (thin SVD, the non-zero part), the
   orthonormal basis ``U`` with eigenvalues ``S^2`` -- the covariance
   ``M M'`` of the face when ``a ~ N(0, I)`` (the ICT prior); eos's shape
   coefficients ``alpha`` (in standard deviations) map back to ``a = V alpha``
   (the minimum-norm identity, which is the posterior mean of the modes the
   landmarks cannot see);
2. the expression deltas at those vertices become eos ``Blendshape`` s; the
   model holds only the ``L`` landmark vertices (eos only uses those), and an
   identity :class:`LandmarkMapper` names each landmark by its index there;
3. ``eos.fitting.fit_shape_and_pose`` (the overload without contour fitting)
   alternates eos's affine camera, the shape (``lambda_identity``) and the
   blendshapes (``lambda_expressions``) for ``iterations`` rounds.

Differences from our fitter: the camera is eos's **scaled orthographic**
one (the target's focal length and perspective are ignored), the weights come
from eos's own regularised solve (not bounded to ``[0, 1]``: a weight may be
negative or above 1), everything is float32, and the regularisation strengths
are eos's (``lambda``\\ s), not a noise level.

The result is eos's as eos returns it: the weights are passed on unchanged
(not clipped to ``[0, 1]``), so the fitted face (:meth:`IdentityFit.vertices`)
is eos's face and a comparison scores eos's fit, not a changed one (clipping
had raised eos's landmark error, e.g. from 2.1 to 4.5 px on a synthetic image).
"""
from __future__ import annotations

import time

import numpy as np
from threadpoolctl import threadpool_limits

from facegeom.baselines.eos_peer import _import_eos
from facegeom.errors import InputError, SolveError
from facegeom.interfaces import Params, check_range
from facegeom.methods.identity import IdentityFit
from facegeom.model import LandmarkTarget

__all__ = ["EosIdentityFitter"]

class EosIdentityFitter(Params):
    """Identity + camera + expression from one image's landmarks with ``eos.fitting.fit_shape_and_pose``.

    Parameters
    ----------
    iterations : int >= 1
        eos's ``num_iterations`` (camera / shape / expression rounds; eos's default 5).
    lambda_identity : float > 0
        eos's shape regulariser (default 30, eos's).
    lambda_expressions : float > 0
        eos's blendshape regulariser (default 30, eos's).

    Raises
    ------
    InputError
        eos is not importable, or a bad parameter.
    """

    def __init__(self, iterations: int = 5, lambda_identity: float = 30.0, lambda_expressions: float = 30.0):
        self._eos = _import_eos()
        iterations = check_range("iterations", iterations, 1, 1000, "eos alternates pose and shape a few times",
                                 integer=True)
        for name, v in (("lambda_identity", lambda_identity), ("lambda_expressions", lambda_expressions)):
            check_range(name, v, 0, 1e12, "a regularisation weight; beyond it the fit is the mean face", above=True)
        self.iterations = int(iterations)
        self.lambda_identity = float(lambda_identity)
        self.lambda_expressions = float(lambda_expressions)

    def __repr__(self) -> str:
        return f"EosIdentityFitter(iterations={self.iterations}, lambda_identity={self.lambda_identity:g})"

    def _model(self, model, ids):
        """``(eos MorphableModel, V (I, r), S (r,))`` for the landmark vertices ``ids``."""
        mm = self._eos.morphablemodel
        L = ids.size
        mean = np.asarray(model.neutral[ids], dtype=np.float64).reshape(-1)
        M = np.asarray(model.identity_modes[:, ids], dtype=np.float64).reshape(model.n_identities, -1).T  # (3L, I)
        U, S, Vt = np.linalg.svd(M, full_matrices=False)
        keep = S > S[0] * 1e-6
        U, S, Vt = U[:, keep], S[keep], Vt[keep]
        tris = [[0, min(1, L - 1), min(2, L - 1)]]  # eos needs a triangle list; no rendering happens here
        shape = mm.PcaModel(mean.astype(np.float32), np.ascontiguousarray(U, dtype=np.float32),
                            (S ** 2).astype(np.float32), tris)
        blend = [mm.Blendshape(name, np.ascontiguousarray(d.reshape(-1), dtype=np.float32))
                 for name, d in zip(model.expression_names, np.asarray(model.expression_deltas[:, ids]))]
        color = mm.PcaModel()
        return mm.MorphableModel(shape, blend, color), Vt.T, S

    def fit(self, model, targets) -> IdentityFit:
        """Fit identity, eos's affine camera and the expression to one landmark target -> :class:`IdentityFit`.

        ``info``: ``time_s``, ``affine_camera`` (3x4 model -> pixel matrix),
        ``shape_coefficients`` (eos's), ``rms`` (pixels, under eos's camera).
        ``cameras`` is ``[None]`` (eos's camera is affine). ``weights`` are eos's
        blendshape coefficients as returned (float64, not clipped: they may lie outside ``[0, 1]``).
        """
        if isinstance(targets, (list, tuple)):
            if len(targets) != 1:
                raise InputError(f"eos's identity fit takes one image, got {len(targets)} targets")
            targets = targets[0]
        if not isinstance(targets, LandmarkTarget):
            raise InputError("eos fits identity to 2-D landmarks only")
        tg = targets
        if tg.n_landmarks < 4:
            raise InputError(f"eos needs at least 4 landmarks for its camera, got {tg.n_landmarks}")
        t0 = time.perf_counter()
        ids = np.asarray(tg.vertex_ids, dtype=np.int64)
        mmodel, V, _ = self._model(model, ids)
        core, fitting = self._eos.core, self._eos.fitting
        lms = [core.Landmark(str(i), np.asarray(p, dtype=np.float32).reshape(2, 1)) for i, p in enumerate(tg.points2d)]
        width = max(1, int(np.ceil(2.0 * abs(tg.camera.cx))))
        height = max(1, int(np.ceil(2.0 * abs(tg.camera.cy))))
        with threadpool_limits(limits=1, user_api="blas"):  # small solves: threads only cost on a shared machine
            mesh, params, alpha, w = fitting.fit_shape_and_pose(
                mmodel, lms, core.LandmarkMapper(), width, height, self.iterations, None, self.lambda_identity, None,
                self.lambda_expressions)
        alpha = np.asarray(alpha, dtype=np.float64)
        w = np.asarray(w, dtype=np.float64)
        if w.shape != (model.n_expressions,) or not np.all(np.isfinite(w)) or not np.all(np.isfinite(alpha)):
            raise SolveError("eos returned coefficients of the wrong size or NaN")
        a = V[:, :alpha.size] @ alpha
        A = np.asarray(fitting.get_3x4_affine_camera_matrix(params, width, height), dtype=np.float64)
        X = np.asarray(mesh.vertices, dtype=np.float64)
        proj = np.c_[X, np.ones(len(X))] @ A[:2].T
        rms = float(np.sqrt(((proj - tg.points2d) ** 2).sum(axis=1).mean()))
        info = {"time_s": time.perf_counter() - t0, "affine_camera": A, "shape_coefficients": alpha,
                "rms": [rms], "rounds": self.iterations, "converged": True}
        R = np.asarray(params.get_rotation_matrix() if hasattr(params, "get_rotation_matrix") else np.eye(3),
                       dtype=np.float64)[:3, :3]
        return IdentityFit(a, w[None], ("landmarks",), [None], R[None], np.zeros((1, 3)), info, model)
