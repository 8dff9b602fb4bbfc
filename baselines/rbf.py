"""RBF interpolation of marker displacements (scipy's RBFInterpolator)."""
from __future__ import annotations

import numpy as np
from scipy.interpolate import RBFInterpolator

from facegeom.baselines._common import apply_displacement_map, fit_inputs
from facegeom.errors import InputError
from facegeom.interfaces import Params, as_positions, check_fitted, check_range

KERNELS = ("thin_plate_spline", "cubic", "quintic", "linear", "multiquadric", "inverse_multiquadric",
           "inverse_quadratic", "gaussian")


class RBFDeformer(Params):
    """Scattered-data interpolation of the marker displacements over Euclidean distance.

    ``d(x) = sum_j c_j phi(|x - m_j|) + p(x)``, fitted so that ``d(m_j)`` is
    marker ``j``'s displacement; every vertex moves by ``d``. The interpolant is
    linear in the displacements, so ``fit`` evaluates it once for unit data and
    stores the ``(n, k)`` map; ``deform`` is one matrix product.

    Parameters
    ----------
    kernel : str
        One of scipy's kernels (``thin_plate_spline``, ``cubic``, ``quintic``,
        ``linear``, ``multiquadric``, ``inverse_multiquadric``,
        ``inverse_quadratic``, ``gaussian``).
    smoothing : float
        0 interpolates the markers exactly.
    epsilon : float, optional
        Shape parameter, required by the scale-dependent kernels
        (``gaussian``, ``*multiquadric``, ``inverse_quadratic``); default 1 /
        the mean marker spacing for those.
    degree : int
        Degree of the added polynomial; 1 (affine) reproduces any affine, hence
        any rigid, motion of all markers exactly.
    """

    def __init__(self, kernel: str = "thin_plate_spline", smoothing: float = 0.0, epsilon: float | None = None,
                 degree: int = 1):
        if kernel not in KERNELS:
            raise InputError(f"kernel must be one of {', '.join(KERNELS)}, got {kernel!r}")
        smoothing = check_range("smoothing", smoothing, 0, 1e6, "beyond it only the polynomial part is left")
        if epsilon is not None:
            epsilon = check_range("epsilon", epsilon, 0, 1e6, "the kernel's shape factor; beyond it the kernel "
                                  "overflows", above=True)
        degree = check_range("degree", degree, -1, 3, "a degree-d polynomial in 3-D has (d+1)(d+2)(d+3)/6 terms: "
                             "3 needs 20 markers already", integer=True)
        self.kernel, self.smoothing, self.epsilon, self.degree = kernel, smoothing, epsilon, degree
        self.map_ = None

    def fit(self, vertices, faces, handles) -> "RBFDeformer":
        """Fit scipy's ``RBFInterpolator`` on the markers' rest positions for unit data and evaluate it at every vertex.

        The interpolant is linear in the data, so its values at the vertices, stored
        as the ``(k, n)`` map ``map_``, give any displacement with one product. For
        a scale-dependent kernel without ``epsilon``, ``epsilon`` is 1 / the mean
        distance from a marker to its nearest marker. ``faces`` are only validated.

        Parameters
        ----------
        vertices : (n, 3) float64
            The rest shape.
        faces : (m, 3) int64
            Triangles indexing ``vertices``.
        handles : (k,) int64
            Distinct marker vertex ids (``k >= 4`` with ``degree >= 1``).

        Returns
        -------
        self

        Raises
        ------
        InputError
            Bad arrays, too few markers, or markers scipy cannot interpolate from
            (e.g. a singular system).
        """
        V, _, H = fit_inputs(vertices, faces, handles, min_handles=4 if self.degree >= 1 else 1)
        M = V[H]
        eps = self.epsilon
        if eps is None and self.kernel in ("gaussian", "multiquadric", "inverse_multiquadric",
                                           "inverse_quadratic"):
            from scipy.spatial import cKDTree

            dist, _ = cKDTree(M).query(M, k=2)
            eps = 1.0 / max(float(dist[:, 1].mean()), 1e-12)
        kw = {} if eps is None else {"epsilon": eps}
        try:
            rbf = RBFInterpolator(M, np.eye(H.size), kernel=self.kernel, smoothing=self.smoothing,
                                  degree=self.degree, **kw)
        except (ValueError, np.linalg.LinAlgError) as exc:
            raise InputError(f"rbf: cannot interpolate from these markers ({exc})") from None
        self.map_ = np.ascontiguousarray(rbf(V).T)  # (k, n), transposed for a fast product
        self.vertices_, self.handles_ = V, H
        return self

    def deform(self, handle_positions) -> np.ndarray:
        """Move every vertex by the interpolated marker displacement: ``V + map_^T (handle_positions - V[handles])``.

        Parameters
        ----------
        handle_positions : (k, 3) float64
            One position per marker, in the order of ``handles``.

        Returns
        -------
        (n, 3) float64
            The deformed vertices (markers exact when ``smoothing`` is 0).

        Raises
        ------
        InputError
            A wrong shape, NaN or inf; :class:`~facegeom.interfaces.NotFittedError`
            before :meth:`fit`.
        """
        check_fitted(self, "map_")
        P = as_positions(handle_positions, self.handles_.size)
        Y = apply_displacement_map(self.vertices_, self.handles_, self.map_, P)
        if self.smoothing == 0:
            Y[self.handles_] = P  # exact at the markers (removes round-off)
        return Y
