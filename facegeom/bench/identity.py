"""``facegeom bench identity``: what not knowing the person costs, and how much identity fitting gets back.

Truth: held-out random ICT identities (coefficients N(0, 1), seeded) with
random expressions of two kinds -- ``sparse`` (2-6 shapes at U(0.2, 1), the
``bench fit`` cases) and ``dense`` (frames sampled across the real ARKit takes,
mapped to the ICT shapes). Each target is fitted three ways with the same
solver (:class:`~facegeom.methods.identity.IdentityFitter`, the same priors
and bounds, so only the identity differs):

- ``generic``: the generic neutral (no identity modes), expression and pose fitted;
- ``identity``: identity, pose and expression fitted;
- ``oracle``: the true identity's neutral, expression and pose fitted;
- ``eos`` (landmarks, one image, when eos-py is installed): the peer
  ``eos.fitting.fit_shape_and_pose`` on the ICT arrays (entry point ``eos`` of
  the ``facegeom.identity`` group, ``baselines.eos_identity``), with eos's
  default regularisers and its affine camera (NE through that camera).

Protocols:

- ``landmarks``: one image, 640 x 480, focal 1000 px **known**, pose unknown
  (yaw U(-30, 30), pitch U(-10, 10) degrees), 1 px noise; fitted on the 23
  ``bench fit`` landmarks plus the 17 jaw-contour ones (40: with the 23 alone
  a frame has 46 numbers for 53 weights + 6 pose, and the expression can
  explain anything the identity could), NE on the 26 unused ones (against their clean
  projections, through each fit's camera, normalised by the true inner-eye
  distance);
- ``neutral``: the SEM paper's protocol (Sec. V-A; ``facegeom identity`` then
  ``facegeom fit --rig``): the identity from 5 *neutral* images of the person
  (``expressions=False``), then each of 5 expression images fitted
  separately on that user-specific rig (expression and pose; the identity
  held); generic / oracle fit the same expression images on the generic / true
  neutral; the identity condition's time includes its share of the identity fit;
- ``frames``: 5 expression images of one person (each its own expression, yaw
  and noise), one identity for all fitted jointly with the 5 expressions;
  errors per frame;
- ``mesh``: the face in correspondence with 0.5 mm Gaussian noise per coordinate,
  under a random rigid motion;
- ``cloud``: 30,000 points sampled by area on the face area, 0.5 mm noise;
- ``partial``: a scan as a scanner sees one side: 10,000 points on the face
  area minus a side strip (left or right) of U(0, 25) % of its width, 0.5 mm
  noise, in the model's frame and units;
- ``scan``: the same people and the same scans (the ``partial`` draws) as
  another tool exports them: in millimetres, turned by a uniformly random
  rotation and moved by N(0, 50 cm) per axis; read as ``facegeom fit`` /
  ``facegeom identity`` read a file (the units by
  :func:`~facegeom.registration.units_factor`), the pose found by the
  fitter's global search (:func:`~facegeom.registration.align_rigid`).
  ``scan`` against ``partial`` is what not knowing the frame and units costs;
- ``head``: a head scan as scanners deliver them: 30,000 points over the whole
  skin of the model's face geometry (face, ears, neck, the scalp it has; about
  half of the points are off the face area the fitter uses), 0.5 mm noise, in
  millimetres, in any orientation, moved.

Metrics: mean 3-D vertex error over the face area in mm, in the model frame
(``vertex mm``) and after the best rigid alignment of the fitted face to the
truth (``aligned mm``: a pose / gauge offset removed; the face's size stays);
expression coefficient MAE; identity coefficient RMS error (``identity`` only);
time per fit (ms, median).
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np
from scipy.spatial.transform import Rotation

from facegeom import metrics as fm
from facegeom.bench.common import (
    PhotoAnnotator,
    face_area_triangles,
    progress_bar,
    sample_surface,
    side_strip_seen,
)
from facegeom.bench.report import Report, format_table, machine_note
from facegeom.constants import CM_TO_MM, FACE_AREA
from facegeom.methods.identity import IdentityFit, IdentityFitter
from facegeom.model import (
    EVAL_LANDMARKS_26,
    FIT_LANDMARKS_23,
    INNER_EYE_CORNERS,
    LandmarkTarget,
    MeshTarget,
    PinholeCamera,
    PointCloudTarget,
    look_at_camera,
    random_sparse_expression,
)
from facegeom.registration import units_factor

PROTOCOLS = ("landmarks", "neutral", "frames", "mesh", "cloud", "partial", "scan", "head")
SCAN_POINTS = 10000  # partial / scan: points per scan
SCAN_HIDDEN = 0.25  # partial / scan: the hidden side strip's width is U(0, this) of the face area's
CONDITIONS = ("generic", "identity", "oracle", "eos")

__all__ = ["CONDITIONS", "PROTOCOLS", "identity_peer", "main", "make_people", "run", "summarize"]


@dataclasses.dataclass
class Person:
    """A held-out person: identity ``(I,)`` and expression weights per frame ``(F, B)`` (kind ``sparse``/``dense``)."""

    identity: np.ndarray
    weights: np.ndarray
    kind: str


def make_people(model, count, seed, dense_weights=None, frames=1):
    """``count`` people (half sparse, half dense when ``dense_weights (T, B)`` is given), ``frames`` expressions each."""
    rng = np.random.default_rng([int(seed), 1818])
    out = []
    for i in range(count):
        a = model.random_identity(rng)
        dense = dense_weights is not None and i % 2 == 1
        if dense:
            W = dense_weights[rng.integers(0, dense_weights.shape[0], frames)]
        else:
            W = np.stack([model.expression_vector(random_sparse_expression(model.expression_names, rng))
                          for _ in range(frames)])
        out.append(Person(a, np.asarray(W, dtype=np.float64), "dense" if dense else "sparse"))
    return out


def _aligned_mm(V, T):
    A, B = V[:FACE_AREA], T[:FACE_AREA]
    ca, cb = A.mean(0), B.mean(0)
    U, _, Vt = np.linalg.svd((A - ca).T @ (B - cb))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return float(np.linalg.norm((A - ca) @ R.T + cb - B, axis=1).mean() * CM_TO_MM)


def _models(model, identity):
    """The fitter's model per condition: generic and identity use ``model``; the oracle the true neutral."""
    oracle = dataclasses.replace(model, neutral=model.identity_neutral(identity).astype(np.float32))
    return {"generic": (model, 0), "identity": (model, None), "oracle": (oracle, 0)}


def identity_peer(name="eos"):
    """The identity fitter registered as ``name`` in the ``facegeom.identity`` entry points, or None.

    None when it is not registered or cannot be built (eos-py not installed).
    """
    from importlib.metadata import entry_points

    from facegeom.errors import FacegeomError

    eps = {ep.name: ep for ep in entry_points(group="facegeom.identity")}
    if name not in eps:
        return None
    try:
        return eps[name].load()()
    except (FacegeomError, ImportError):
        return None


def _fit(fitter_params, model, n_id, targets):
    f = IdentityFitter(**{**fitter_params, "n_identities": n_id})
    t = time.perf_counter()
    r = f.fit(model, targets)
    return r, time.perf_counter() - t


def _rows(protocol, pi, person, cond, r, dt, truths, model, extra=None):
    rows = []
    for k, T in enumerate(truths):
        V = r.vertices(k)
        row = {"protocol": protocol, "person": pi, "kind": person.kind, "frame": k, "condition": cond,
               "time_ms": dt * 1e3 / len(truths),
               "vertex_mm": fm.mean_vertex_error_mm(V, T, np.arange(FACE_AREA)),
               "aligned_mm": _aligned_mm(V, T),
               "coef_mae": float(np.abs(r.weights[k] - person.weights[k]).mean()),
               "identity_rms": (float(np.sqrt(np.mean((r.identity - person.identity) ** 2)))
                                if cond in ("identity", "eos") else float("nan"))}
        if extra is not None:
            row.update(extra(k, r))
        rows.append(row)
    return rows


def run(model, protocol, people, params=None, noise_px=1.0, noise_mm=0.5, points=30000, seed=0, progress=True,
        jaw=True, contour="outline"):
    """Fit every person of ``people`` under ``protocol`` in the three conditions -> list of row dicts.

    ``jaw``: landmark protocols fit the 17 jaw-contour landmarks too (40 in all), else the 23 of ``bench fit``.
    ``contour``: ``"outline"``: the side contour is marked on the face's outline in each view, as annotators do
    (:class:`~facegeom.bench.common.PhotoAnnotator`); ``"fixed"``: on its vertices.
    """
    params = dict(params or {})
    same = "partial" if protocol == "scan" else protocol  # scan: the partial protocol's scans, then moved
    rng = np.random.default_rng([int(seed), 77, PROTOCOLS.index(same)])
    rng_frame = np.random.default_rng([int(seed), 78])
    lm = model.landmarks
    fit_lm = (tuple(range(17)) if jaw else ()) + FIT_LANDMARKS_23
    fit_ids, eval_ids, eye_ids = lm[list(fit_lm)], lm[list(EVAL_LANDMARKS_26)], lm[list(INNER_EYE_CORNERS)]
    annotate = PhotoAnnotator(model, fit_lm, contour == "outline")
    tris = model.triangles[(model.triangles < FACE_AREA).all(axis=1)]
    peer = identity_peer("eos") if protocol == "landmarks" else None
    rows = []
    items = progress_bar(people, f"identity {protocol}", progress, unit="person")
    for pi, p in enumerate(items):
        truths = [model.face(p.identity, w) for w in p.weights]
        extra = None
        if protocol in ("landmarks", "frames", "neutral"):
            targets, evals = [], []
            neutrals = []
            if protocol == "neutral":
                N = model.face(p.identity)
                for _ in range(len(truths)):
                    cam = look_at_camera(N, yaw=rng.uniform(-30, 30), pitch=rng.uniform(-10, 10))
                    uv = annotate(N, cam) + rng.normal(size=(fit_ids.size, 2)) * noise_px
                    neutrals.append(LandmarkTarget(uv, fit_ids, PinholeCamera(cam.focal, cam.cx, cam.cy),
                                                   annotate.mask))
            for T in truths:
                cam = look_at_camera(T, yaw=rng.uniform(-30, 30), pitch=rng.uniform(-10, 10))
                uv = annotate(T, cam) + rng.normal(size=(fit_ids.size, 2)) * noise_px
                targets.append(LandmarkTarget(uv, fit_ids, PinholeCamera(cam.focal, cam.cx, cam.cy), annotate.mask))
                evals.append((cam.project(T[eval_ids]), fm.interocular_distance(*cam.project(T[eye_ids]))))

            def extra(k, r, evals=evals):
                uv_eval, io = evals[k]
                X = r.vertices(k)[eval_ids]
                if r.cameras[k] is not None:
                    uv = r.cameras[k].project(X)
                else:  # an affine camera (eos)
                    A = r.info["affine_camera"]
                    uv = np.c_[X, np.ones(len(X))] @ A[:2].T
                return {"ne_eval": fm.normalized_error(uv, uv_eval, io)}
        elif protocol == "mesh":
            targets = []
            for T in truths:
                R = Rotation.from_rotvec(rng.normal(size=3) * 0.3).as_matrix()
                targets.append(MeshTarget((T + rng.normal(size=T.shape) * noise_mm / CM_TO_MM) @ R.T
                                          + rng.normal(size=3) * 5))
        elif protocol in ("partial", "scan", "head"):
            targets = []
            for T in truths:
                if protocol == "head":
                    P = sample_surface(T, model.triangles, points, rng)
                    P = P + rng.normal(size=P.shape) * noise_mm / CM_TO_MM
                else:
                    P = partial_scan(model, T, rng, SCAN_POINTS, rng.uniform(0.0, SCAN_HIDDEN), rng.choice([-1, 1]),
                                     noise_mm / CM_TO_MM)
                if protocol in ("scan", "head"):
                    R = Rotation.random(random_state=rng_frame.integers(1 << 31)).as_matrix()
                    P = (P @ R.T + rng_frame.normal(size=3) * 50.0) * CM_TO_MM  # mm, turned, moved
                    P = P * units_factor(P, model.face()[:FACE_AREA])  # as the file readers do
                targets.append(PointCloudTarget(P))
        else:
            targets = []
            for T in truths:
                P = sample_surface(T, tris, points, rng)
                targets.append(PointCloudTarget(P + rng.normal(size=P.shape) * noise_mm / CM_TO_MM))
        if protocol == "landmarks":
            targets, truths_l = targets[:1], truths[:1]
        else:
            truths_l = truths
        kw = {"noise_px": noise_px, "noise_mm": noise_mm, **params}
        for cond, (mdl, n_id) in _models(model, p.identity).items():
            if protocol == "neutral":
                r, dt = _two_step(model, cond, p.identity, neutrals, targets, kw)
            else:
                r, dt = _fit(kw, mdl, n_id, targets)
            rows += _rows(protocol, pi, p, cond, r, dt, truths_l, model, extra)
        if protocol == "landmarks" and peer is not None:
            t = time.perf_counter()
            r = peer.fit(model, targets)
            rows += _rows(protocol, pi, p, "eos", r, time.perf_counter() - t, truths_l, model, extra)
    return rows


def partial_scan(model, V, rng, points, hidden, side, noise):
    """Points sampled by area on the face area of ``V (n, 3)`` minus a side strip, plus noise -> ``(points, 3)``.

    The strip is ``hidden`` of the face area's width (of the generic face),
    on the right (``side`` 1) or the left (-1); ``noise`` in model units.
    """
    tris = face_area_triangles(model)
    P = sample_surface(V, tris[side_strip_seen(model, hidden, side)[tris].all(axis=1)], points, rng)
    return P + rng.normal(size=P.shape) * noise


def _two_step(model, cond, true_identity, neutrals, targets, kw):
    """The ``neutral`` protocol: an identity (fitted to the neutral images, or none, or the truth), then each
    target's expression and pose on that identity's rig, one target at a time -> ``(IdentityFit, seconds)``."""
    t = time.perf_counter()
    if cond == "identity":
        a = IdentityFitter(**{**kw, "expressions": False}).fit(model, neutrals).identity
    elif cond == "oracle":
        a = np.asarray(true_identity, dtype=np.float64)
    else:
        a = np.zeros(model.n_identities)
    user = dataclasses.replace(model, neutral=model.identity_neutral(a).astype(np.float32))
    fits = [IdentityFitter(**{**kw, "n_identities": 0}).fit(user, tg) for tg in targets]
    dt = time.perf_counter() - t
    r = IdentityFit(a, np.concatenate([f.weights for f in fits]), tuple(f.kinds[0] for f in fits),
                    [f.cameras[0] for f in fits], np.concatenate([f.rotations for f in fits]),
                    np.concatenate([f.translations for f in fits]), {"time_s": dt}, model)
    return r, dt


def _median(rows, key, **where):
    v = np.array([r.get(key, np.nan) for r in rows if all(r[k] == x for k, x in where.items())], dtype=float)
    v = v[np.isfinite(v)]
    return float(np.median(v)) if v.size else float("nan")


def summarize(rows) -> str:
    """One Markdown table: per protocol, expression kind and condition, medians over the cases."""
    header = ["protocol", "expressions", "condition", "vertex (mm)", "aligned (mm)", "vs generic", "NE unused 26 (%)",
              "coef MAE", "identity RMS", "time (ms)"]
    table = []
    for proto in PROTOCOLS:
        for kind in ("sparse", "dense", "all"):
            sel = {"protocol": proto} if kind == "all" else {"protocol": proto, "kind": kind}
            if not any(all(r[k] == x for k, x in sel.items()) for r in rows):
                continue
            gen = _median(rows, "vertex_mm", condition="generic", **sel)
            for cond in CONDITIONS:
                if not any(r["condition"] == cond and all(r[k] == x for k, x in sel.items()) for r in rows):
                    continue
                v = _median(rows, "vertex_mm", condition=cond, **sel)
                table.append([proto, kind, cond, v, _median(rows, "aligned_mm", condition=cond, **sel),
                              f"{100 * (v / gen - 1):+.0f} %", 100 * _median(rows, "ne_eval", condition=cond, **sel),
                              _median(rows, "coef_mae", condition=cond, **sel),
                              _median(rows, "identity_rms", condition=cond, **sel),
                              _median(rows, "time_ms", condition=cond, **sel)])
    return "Identity fitting (medians over targets)\n\n" + format_table(header, table)


def main(model, protocols, count, seed, out, dense_weights=None, params=None, frames=5, cloud_count=4,
         echo=print, progress=True, contour="outline"):
    """Run the protocols, echo the table and write ``identity.csv`` + ``identity-summary.md`` into ``out``."""
    report = Report(out, "identity", echo)
    rows = []
    for proto in protocols:
        n = cloud_count if proto in ("cloud", "partial", "scan", "head") else count
        same = "partial" if proto == "scan" else proto  # the same people for partial and scan
        people = make_people(model, n, seed + PROTOCOLS.index(same), dense_weights,
                             frames if proto in ("frames", "neutral") else 1)
        rows += run(model, proto, people, params, seed=seed, progress=progress, contour=contour)
    report.csv(rows)
    table = summarize(rows)
    dense = "dense = frames of the real takes" if dense_weights is not None else "no takes: sparse only"
    note = (f"{count} people per protocol ({cloud_count} for clouds), seed {seed}, {dense}; landmarks: 23 + 17 jaw "
            f"used (the side contour {'on the outline' if contour == 'outline' else 'on fixed vertices'}), "
            f"focal known, pose unknown (yaw +-30 deg), 1 px; neutral / frames: {frames} images per person; mesh / cloud: "
            f"0.5 mm noise; partial / scan: {SCAN_POINTS} points, a side strip of U(0, {SCAN_HIDDEN:g}) hidden, "
            f"0.5 mm; scan: in mm, random rotation, moved; head: 30,000 points on the whole face geometry, in mm, random "
            f"rotation, moved; {machine_note()}")
    report.summary(table, note)
    report.done()
    return rows, table
