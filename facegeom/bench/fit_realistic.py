"""Realistic blendshape-fitting protocols, reported before the paper's idealised ones.

The paper's experiments (:mod:`facegeom.bench.fit`) fit sparse expressions (2 to
6 shapes) with the true identity's rig and exact intrinsics. Real inputs differ
in four ways, and each is part of every case here:

- **dense expressions**: the weights of a frame of a real ARKit take (frames
  drawn across the four shared takes; a frame has ~40 of 53 weights above
  0.001), on a random identity (coefficients N(0, 1)) that no rig here was built
  from;
- **identity unknown**: every target is fitted with the rig of the *generic*
  neutral (what a user without an identity fit has), with the rig of a fitted
  identity when an identity fitter is given, and with the true identity's rig
  (the oracle), so the tables show what identity costs;
- **landmarks**: 40 landmarks (the paper's 23 fit landmarks and the 17 of the jaw contour, which
  every 68-point detector gives and which carry the face's outline) seen by a pinhole camera turned by yaw
  U(-30, 30) and pitch U(-15, 15) degrees, Gaussian noise of U(0.5, 2) px per
  case, and a focal length given to the fitter off by a factor U(0.7, 1.3)
  (a photo without calibration: the fitters keep the wrong focal, and the pose
  estimate absorbs most of it in the distance, since a face is shallow
  compared with its distance to the camera; the table shows what remains);
- **meshes and point clouds**: 0.5 mm Gaussian noise and partial coverage:
  only the face area (the scan is cropped) minus a random side strip of up to a
  quarter of the face's width (one side occluded) is observed; errors are
  measured over the whole face area, seen or not.

Metrics: the mean 3-D vertex error over the face area against the true face
(mm), the mean absolute coefficient error against the true weights, the active
shapes (weights above 1e-3) and Corr (eq. 33); landmarks also NE on the 26
unused landmarks through each fit's own camera.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
from scipy.spatial.transform import Rotation

from facegeom import metrics as fm
from facegeom.bench.common import (
    PhotoAnnotator,
    available_specs,
    face_area_triangles,
    progress_bar,
    projector,
    sample_surface,
    side_strip_seen,
)
from facegeom.bench.report import format_table
from facegeom.constants import CM_TO_MM, FACE_AREA
from facegeom.errors import FacegeomError, InputError
from facegeom.methods.fitting import fit_aligned, to_rig_frame
from facegeom.methods.identity import IdentityFitter
from facegeom.model import (
    EVAL_LANDMARKS_26,
    FIT_LANDMARKS_23,
    INNER_EYE_CORNERS,
    BlendshapeRig,
    LandmarkTarget,
    MeshTarget,
    PinholeCamera,
    PointCloudTarget,
    look_at_camera,
)
from facegeom.registration import RigidAlignment, units_factor

__all__ = ["RealisticCase", "realistic_cases", "identity_fitters", "FIT_LANDMARKS_40", "run_landmarks", "run_meshes",
           "run_clouds", "summarize", "IDENTITY_MODES", "pooled_reduction", "JOINT", "JOINT_GENERIC"]

IDENTITY_MODES = ("generic", "fitted", "oracle")
MESH_NOISE_CM = 0.05  # 0.5 mm


@dataclass(frozen=True)
class RealisticCase:
    """One realistic target: a real-take frame on a random identity, with its viewing and scanning conditions."""

    identity: np.ndarray  # (I,) identity coefficients
    weights: np.ndarray  # (B,) expression weights of a real take's frame
    take: str
    frame: int
    yaw: float
    pitch: float
    noise_px: float
    focal_factor: float  # the focal length given to the fitters, over the true one
    strip: float  # fraction of the face width hidden on one side (meshes, clouds)
    side: int  # +1: the strip is on +x, -1: on -x


def realistic_cases(model, takes, count: int, seed: int = 0) -> list[RealisticCase]:
    """``count`` cases, frames drawn in turn from each take of ``takes`` (``[(name, W (T, B)), ...]``).

    The random stream is separate from the paper protocol's
    (:func:`~facegeom.model.scenarios.fitting_cases`), so identities differ.
    """
    if not takes:
        raise FacegeomError("the realistic protocol needs at least one take of expression weights")
    rng = np.random.default_rng([int(seed), 1818])
    out = []
    for k in range(int(count)):
        name, W = takes[k % len(takes)]
        f = int(rng.integers(W.shape[0]))
        out.append(RealisticCase(model.random_identity(rng), np.asarray(W[f], dtype=np.float64), name, f,
                                 float(rng.uniform(-30, 30)), float(rng.uniform(-15, 15)),
                                 float(rng.uniform(0.5, 2.0)), float(rng.uniform(0.7, 1.3)),
                                 float(rng.uniform(0.0, 0.25)), int(rng.choice([-1, 1]))))
    return out


def _rigs(model, case, modes, identity_fit):
    """The rig each identity mode fits with: generic neutral, fitted identity (``identity_fit(case)``), truth."""
    out = {}
    for mode in modes:
        if mode == "generic":
            out[mode] = BlendshapeRig.from_face_model(model)
        elif mode == "oracle":
            out[mode] = BlendshapeRig.from_face_model(model, case.identity)
        elif mode == "fitted" and identity_fit is not None:
            out[mode] = identity_fit
    return out


def _row(rig, r, case, index, V_true, method, mode, dt, **extra):
    corr = fm.correlation_metrics(rig, r.weights)
    return {"case": index, "take": case.take, "frame": case.frame, "identity": mode, "method": method,
            "time_ms": dt * 1e3, "vertex_mm": fm.mean_vertex_error_mm(r.vertices, V_true, np.arange(FACE_AREA)),
            "coef_mae": float(np.abs(np.asarray(r.weights) - case.weights).mean()),
            "n_active": int((np.abs(r.weights) > 1e-3).sum()), "corr": corr.corr, **extra}


def _fit(spec, rig, target, region=None, aligned=False):
    m = spec.build("fitters")
    if region is not None and "region" in m.param_names():
        m.set_params(region=region)
    t = time.perf_counter()
    r = fit_aligned(rig, target, m)[0] if aligned else m.fit(rig, target)
    return r, time.perf_counter() - t


JOINT = "identity (joint)"
"""Method name of the ``fitted`` mode's extra row: the identity fitter's own expression, fitted jointly with the
identity and the pose (what ``facegeom fit --identity`` returns without ``--method``)."""

_JOINT_SPEC = SimpleNamespace(label=JOINT)

JOINT_GENERIC = "joint, no identity"
"""Method name of the ``generic`` mode's extra landmark row: the identity fitter's joint fit (pose, expression,
jaw contour) with the identity held at the generic neutral -- the reference that differs from :data:`JOINT` only by
the identity."""

_JOINT_GENERIC_SPEC = SimpleNamespace(label=JOINT_GENERIC)


def _fits(model, case, target, specs, modes, identity_fitter, region=None, off_frame=False):
    """Yield ``(mode, rig, spec, result, seconds)`` for every identity mode and method that fits ``target``.

    ``identity_fitter`` returns the user's rig, or an
    :class:`~facegeom.methods.identity.IdentityFit`: then its own joint
    expression is one more row of the ``fitted`` mode (method :data:`JOINT`,
    timed as the identity fit). ``off_frame``: the target is in another frame
    (see :func:`run_clouds`).
    """
    fitted, spent = None, float("nan")
    if identity_fitter is not None and "fitted" in modes:
        t = time.perf_counter()
        fitted = identity_fitter(target)
        spent = time.perf_counter() - t
    rig_fitted = getattr(fitted, "rig", fitted)
    for mode, rig in _rigs(model, case, modes, rig_fitted).items():
        for spec in specs:
            try:
                if not off_frame:
                    r, dt = _fit(spec, rig, target, region)
                elif mode == "fitted" and hasattr(fitted, "rotations"):
                    pose = RigidAlignment(fitted.rotations[0], fitted.translations[0])
                    r, dt = _fit(spec, rig, to_rig_frame(target, pose), region)
                else:
                    r, dt = _fit(spec, rig, target, region, aligned=True)
            except FacegeomError:  # a method that does not fit this kind of target (eos: landmarks only)
                continue
            yield mode, rig, spec, r, dt
    if hasattr(fitted, "fit_result"):
        yield "fitted", rig_fitted, _JOINT_SPEC, fitted.fit_result(0), spent


FIT_LANDMARKS_40 = tuple(range(17)) + tuple(FIT_LANDMARKS_23)
"""The realistic protocol's fit landmarks: the jaw contour (0-16) and the paper's 23."""


def run_landmarks(model, cases, specs, modes=("generic", "oracle"), identity_fitter=None, progress=True,
                  contour="outline"):
    """Fit the 40 noisy landmarks of every case (pose unknown, focal off) with every method and identity mode.

    ``contour="outline"`` (realistic): the jaw-contour landmarks of
    :data:`~facegeom.model.landmarks.SIDE_CONTOUR` are drawn where an annotator
    or a detector puts them, on the true face's outline in the view
    (:func:`~facegeom.model.landmarks.silhouette_vertices`), while the fitters
    are told the landmarks' usual vertices; ``"fixed"``: on those vertices.
    With an identity fitter, the ``generic`` mode also gets the joint fit with
    the identity held at the generic neutral (:data:`JOINT_GENERIC`, an
    :class:`~facegeom.methods.identity.IdentityFitter` with no identity modes):
    what fitting the identity adds, everything else equal.

    Parameters
    ----------
    model : FaceModel
    cases : list of RealisticCase
    specs : list of MethodSpec
    modes : sequence of str
        Identity modes (:data:`IDENTITY_MODES`); ``fitted`` needs ``identity_fitter``.
    identity_fitter : callable(LandmarkTarget) -> BlendshapeRig or IdentityFit, optional
        Fits the person's identity from the target itself.
    progress : bool

    Returns
    -------
    list of dict
        Per case, identity mode and method: ``vertex_mm``, ``coef_mae``,
        ``n_active``, ``corr``, ``ne_eval`` (NE on the 26 unused landmarks
        against their clean projections, a fraction of the true inner-eye
        distance), ``time_ms``, plus the case's ``noise_px`` and ``yaw``.
    """
    if contour not in ("outline", "fixed"):
        raise InputError(f"contour must be 'outline' or 'fixed', got {contour!r}")
    rng = np.random.default_rng(7319)
    lm = np.asarray(model.landmarks)
    fit_ids, eval_ids = lm[list(FIT_LANDMARKS_40)], lm[list(EVAL_LANDMARKS_26)]
    annotate = PhotoAnnotator(model, FIT_LANDMARKS_40, contour == "outline")
    eye_ids = lm[list(INNER_EYE_CORNERS)]
    rows = []
    for ci, c in enumerate(progress_bar(cases, "realistic landmarks", progress)):
        truth = BlendshapeRig.from_face_model(model, c.identity)
        V = truth.evaluate(c.weights)
        cam = look_at_camera(V, yaw=c.yaw, pitch=c.pitch)
        uv = annotate(V, cam) + rng.normal(size=(fit_ids.size, 2)) * c.noise_px  # the jaw contour on the outline
        uv_eval = cam.project(V[eval_ids])
        io = fm.interocular_distance(*cam.project(V[eye_ids]))
        target = LandmarkTarget(uv, fit_ids, PinholeCamera(cam.focal * c.focal_factor, cam.cx, cam.cy), annotate.mask)
        fits = list(_fits(model, c, target, specs, modes, identity_fitter))
        if identity_fitter is not None and "fitted" in modes:
            t = time.perf_counter()
            generic = IdentityFitter(n_identities=0).fit(model, [target])
            fits.append(("generic", generic.rig, _JOINT_GENERIC_SPEC, generic.fit_result(0), time.perf_counter() - t))
        for mode, rig, spec, r, dt in fits:
            proj = projector(r, cam)
            rows.append(_row(rig, r, c, ci, V, spec.label, mode, dt, noise_px=c.noise_px, yaw=c.yaw,
                             ne_eval=fm.normalized_error(proj(r.vertices[eval_ids]), uv_eval, io)))
    return rows


def coverage(model, case) -> np.ndarray:
    """``(n,)`` bool: the vertices a partial scan of ``case`` observes (face area minus a side strip)."""
    return side_strip_seen(model, case.strip, case.side)


def run_meshes(model, cases, specs, modes=("generic", "oracle"), identity_fitter=None, progress=True):
    """Fit every case's true face plus 0.5 mm noise, observed on a partial region (weights 0 elsewhere).

    ``identity_fitter``: callable(MeshTarget) -> BlendshapeRig or IdentityFit for the ``fitted`` mode.
    Returns rows as :func:`run_landmarks` (without ``ne_eval``), plus ``seen`` (observed fraction of the face area).
    """
    rng = np.random.default_rng(7320)
    rows = []
    for ci, c in enumerate(progress_bar(cases, "realistic meshes", progress)):
        truth = BlendshapeRig.from_face_model(model, c.identity)
        V = truth.evaluate(c.weights)
        seen = coverage(model, c)
        target = MeshTarget(V + rng.normal(size=V.shape) * MESH_NOISE_CM, weights=seen.astype(np.float64))
        for mode, rig, spec, r, dt in _fits(model, c, target, specs, modes, identity_fitter):
            rows.append(_row(rig, r, c, ci, V, spec.label, mode, dt, seen=float(seen[:FACE_AREA].mean())))
    return rows


def run_clouds(model, cases, specs, modes=("generic", "oracle"), identity_fitter=None, points=10000,
               progress=True, frame="model"):
    """Fit ``points`` noisy surface samples (0.5 mm) of the observed part of every case's face.

    ``identity_fitter``: callable(PointCloudTarget) -> BlendshapeRig or IdentityFit for the ``fitted`` mode.
    Fitters with a ``region`` parameter match the face area. Rows as :func:`run_meshes`,
    plus ``identity_ms`` (the identity fit's time, ``fitted`` rows; else NaN).

    ``frame``: ``model`` -- the scan in the model's frame and units; ``any`` --
    as another tool exports it: in mm, turned by a uniformly random rotation,
    moved by N(0, 50 cm) per axis, then read as ``facegeom fit`` reads a file
    (units by :func:`~facegeom.registration.units_factor`); the generic and
    true rigs are fitted by :func:`~facegeom.methods.fitting.fit_aligned` (global
    search, pose and expression alternately, as ``facegeom fit``), the fitted
    rig on the scan brought into the model's frame by the identity fit's pose
    (as ``facegeom fit --identity -m METHOD``). Errors in the model's frame.
    """
    if frame not in ("model", "any"):
        raise InputError(f"frame must be 'model' or 'any', got {frame!r}")
    rng_frame = np.random.default_rng(7322)
    rng = np.random.default_rng(7321)
    tris = face_area_triangles(model)
    region = np.arange(FACE_AREA)
    rows = []
    spent = {}

    def timed(target):
        t = time.perf_counter()
        fitted = identity_fitter(target)
        spent["s"] = time.perf_counter() - t
        return fitted

    for ci, c in enumerate(progress_bar(cases, "realistic clouds", progress)):
        truth = BlendshapeRig.from_face_model(model, c.identity)
        V = truth.evaluate(c.weights)
        seen = coverage(model, c)
        vis = tris[seen[tris].all(axis=1)]
        P = sample_surface(V, vis, points, rng) + rng.normal(size=(points, 3)) * MESH_NOISE_CM
        if frame == "any":
            R = Rotation.random(random_state=rng_frame.integers(1 << 31)).as_matrix()
            P = (P @ R.T + rng_frame.normal(size=3) * 50.0) * CM_TO_MM
            P = P * units_factor(P, model.face()[:FACE_AREA])
        target = PointCloudTarget(P)
        spent.clear()
        for mode, rig, spec, r, dt in _fits(model, c, target, specs, modes,
                                            None if identity_fitter is None else timed, region, frame == "any"):
            rows.append(_row(rig, r, c, ci, V, spec.label, mode, dt, seen=float(seen[:FACE_AREA].mean()),
                             identity_ms=spent.get("s", np.nan) * 1e3 if mode == "fitted" else np.nan,
                             cloud_frame=frame))
    return rows


def identity_fitters(model) -> dict:
    """The ``fitted`` identity mode: :class:`~facegeom.methods.identity.IdentityFitter` (defaults) per target kind.

    Each returns the :class:`~facegeom.methods.identity.IdentityFit` of the
    target itself (identity, expression and pose jointly): the expression
    methods then fit its user-specific rig, and its own expression is the
    :data:`JOINT` row.
    """
    from facegeom.methods.identity import IdentityFitter

    def fit(target):
        return IdentityFitter().fit(model, [target])

    return {"landmarks": fit, "meshes": fit, "clouds": fit}


def _stat(rows, mode, method, key, how=np.mean):
    v = np.array([r[key] for r in rows if r["identity"] == mode and r["method"] == method], dtype=float)
    v = v[np.isfinite(v)]
    return float(how(v)) if v.size else float("nan")


TITLES = {
    "landmarks": "Realistic: landmarks (real-take expressions on random identities; 40 landmarks, yaw ±30°, "
                 "noise 0.5-2 px, focal off by up to ±30 %; pose estimated)",
    "meshes": "Realistic: corresponding meshes (real-take expressions on random identities; 0.5 mm noise; "
              "face area minus a side strip observed)",
    "clouds": "Realistic: point clouds (real-take expressions on random identities; 0.5 mm noise; partial)",
}


def summarize(results: dict, specs) -> str:
    """One table per realistic experiment: rows per identity mode and method; means (median time).

    The first column of each block is the identity the rig was built with; within a
    mode the best vertex error is the one to beat.
    """
    labels = [s.label for s in specs] + [JOINT, JOINT_GENERIC]  # the joint rows show only where they were fitted
    parts = []
    for ex in ("landmarks", "meshes", "clouds"):
        rows = results.get(ex)
        if not rows:
            continue
        header = ["identity", "method", "vertex (mm)", "vertex median (mm)"]
        header += ["NE unused 26 (%)"] if ex == "landmarks" else []
        header += ["coef MAE", "active", "Corr", "time (ms)"]
        table = []
        for mode in IDENTITY_MODES:
            for m in labels:
                if not any(r["identity"] == mode and r["method"] == m for r in rows):
                    continue
                line = [mode, m, _stat(rows, mode, m, "vertex_mm"), _stat(rows, mode, m, "vertex_mm", np.median)]
                line += [100 * _stat(rows, mode, m, "ne_eval")] if ex == "landmarks" else []
                line += [_stat(rows, mode, m, "coef_mae"), _stat(rows, mode, m, "n_active"),
                         _stat(rows, mode, m, "corr"), _stat(rows, mode, m, "time_ms", np.median)]
                table.append(line)
        n = len({r["case"] for r in rows})
        where = ("; in mm, any orientation, moved: fitted as `facegeom fit` fits a file"
                 if any(r.get("cloud_frame") == "any" for r in rows) else "")
        parts.append(f"{TITLES[ex]}{where}, {n} cases\n\n" + format_table(header, table))
    return "\n\n".join(parts)


def main(model, specs, experiments, takes, count, seed, report, identity_fitters=None, cloud_cases=3,
         points=10000, echo=print, progress=True, cloud_frame="model", contour="outline"):
    """Run the realistic experiments among ``experiments`` and write their CSVs into ``report``.

    Parameters
    ----------
    model : FaceModel
    specs : list of MethodSpec
    experiments : collection of str
        Any of ``landmarks``, ``meshes``, ``clouds``.
    takes : list of (str, (T, B) array)
        Real takes' ICT weights; frames are drawn across them.
    count : int
        Cases (the clouds use the first ``cloud_cases``).
    seed : int
    report : facegeom.bench.report.Report
    identity_fitters : dict kind -> callable(target) -> BlendshapeRig or IdentityFit, optional
        Identity fitters per experiment (``landmarks``, ``meshes``, ``clouds``)
        for the ``fitted`` identity mode.
    echo, progress
        Messages and progress bars.
    cloud_frame : "model" or "any"
        See :func:`run_clouds`.
    contour : "outline" or "fixed"
        See :func:`run_landmarks`.

    Returns
    -------
    results : dict of rows per experiment
    table : str (:func:`summarize`)
    """
    specs = available_specs(specs, echo)
    cases = realistic_cases(model, takes, count, seed)
    fitters = identity_fitters or {}
    results = {}

    def modes(kind):
        return ("generic", "fitted", "oracle") if kind in fitters else ("generic", "oracle")

    if "landmarks" in experiments:
        results["landmarks"] = run_landmarks(model, cases, specs, modes("landmarks"), fitters.get("landmarks"),
                                             progress, contour)
        report.csv(results["landmarks"], "realistic-landmarks")
    if "meshes" in experiments:
        results["meshes"] = run_meshes(model, cases, specs, modes("meshes"), fitters.get("meshes"), progress)
        report.csv(results["meshes"], "realistic-meshes")
    if "clouds" in experiments:
        results["clouds"] = run_clouds(model, cases[:cloud_cases], specs, modes("clouds"), fitters.get("clouds"),
                                       points, progress, cloud_frame)
        report.csv(results["clouds"], "realistic-clouds")
    return results, summarize(results, specs)


def pooled_reduction(row_sets, method: str = JOINT, resamples: int = 4000, seed: int = 0,
                     reference: str | None = None) -> dict:
    """How far below the generic neutral a method's 3-D error is, per run and pooled over runs (the one-photo target).

    Each run (one ``bench fit`` seed) gives the per-case ``vertex_mm`` of the
    ``generic`` mode's ``reference`` method (default: its first, the first
    expression fitter of the lineup) and of ``method`` in the ``fitted`` mode
    (the rows of ``fit-realistic-landmarks.csv``). Per run and pooled: the
    ratio of the mean errors minus 1 (the table's "joint vs generic"), and for
    the pool a percentile bootstrap over the cases (95 %), since 40 images per
    seed spread the ratio by a few percent.

    Parameters
    ----------
    row_sets : sequence of list of dict
        One list of rows per run (``case``, ``identity``, ``method``, ``vertex_mm``).
    method : str
        The ``fitted`` mode's method to score (default: the joint fit).
    resamples, seed : int
        Bootstrap resamples and their seed.

    Returns
    -------
    dict
        ``runs``: ``[(cases, generic mean, method mean, change)]``; ``pooled``:
        ``(cases, change, low, high)``, changes as fractions (-0.3 = 30 % below).
    """
    gens, fits, runs = [], [], []
    for rows in row_sets:
        generic = [r for r in rows if r["identity"] == "generic"]
        if not generic:
            raise FacegeomError("a run has no generic-neutral rows")
        first = generic[0]["method"] if reference is None else reference
        g = {int(r["case"]): float(r["vertex_mm"]) for r in generic if r["method"] == first}
        f = {int(r["case"]): float(r["vertex_mm"]) for r in rows if r["identity"] == "fitted" and r["method"] == method}
        cases = sorted(set(g) & set(f))
        if not cases:
            raise FacegeomError(f"a run has no cases with both generic {first!r} and {method!r} rows")
        gv, fv = np.array([g[c] for c in cases]), np.array([f[c] for c in cases])
        runs.append((len(cases), float(gv.mean()), float(fv.mean()), float(fv.mean() / gv.mean() - 1.0)))
        gens.append(gv)
        fits.append(fv)
    gv, fv = np.concatenate(gens), np.concatenate(fits)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, gv.size, (int(resamples), gv.size))
    boot = fv[idx].mean(axis=1) / gv[idx].mean(axis=1) - 1.0
    low, high = np.percentile(boot, [2.5, 97.5])
    return {"runs": runs, "pooled": (int(gv.size), float(fv.mean() / gv.mean() - 1.0), float(low), float(high))}


if __name__ == "__main__":  # python -m facegeom.bench.fit_realistic pool OUT_DIR...: the one-photo identity target
    import csv
    import sys
    from pathlib import Path

    _dirs = [Path(a) for a in sys.argv[2:]] if sys.argv[1:2] == ["pool"] else []
    if not _dirs:
        sys.exit("usage: python -m facegeom.bench.fit_realistic pool BENCH_FIT_OUT_DIR [...]")
    _sets = []
    for _d in _dirs:
        with open(_d / "fit-realistic-landmarks.csv", newline="", encoding="utf-8") as _fh:
            _sets.append(list(csv.DictReader(_fh)))
    _refs = [None] + ([JOINT_GENERIC] if any(r["method"] == JOINT_GENERIC for r in _sets[0]) else [])
    for _ref in _refs:
        _res = pooled_reduction(_sets, reference=_ref)
        _name = _ref or next(r["method"] for r in _sets[0] if r["identity"] == "generic")
        print(f"\n{JOINT} against the generic neutral's {_name}:")
        print(format_table(["run", "cases", "generic (mm)", JOINT + " (mm)", "change"],
                           [[str(d), n, g, f, f"{100 * c:+.1f} %"] for d, (n, g, f, c) in zip(_dirs, _res["runs"])]))
        _n, _c, _lo, _hi = _res["pooled"]
        print(f"pooled over {_n} cases: {100 * _c:+.1f} % (95 % bootstrap interval {100 * _lo:+.1f} to "
              f"{100 * _hi:+.1f} %)")
