"""The blendshape-fitting experiments of the SEM paper (Sec. V), on the real ICT rig.

Targets (seeded): a random ICT identity (coefficients N(0, 1)) with a sparse
random expression, 2 to 6 of the 53 shapes active with weights U(0.2, 1.0).
The rig used for fitting is that identity's (the identity is known; the
expression is fitted), as in the paper's expression-fitting experiments.

- ``landmarks`` (Tables 1-3): the 68 landmarks projected by a pinhole camera
  (focal 1000 px, 640 x 480, head turned by yaw U(-25, 25) and pitch
  U(-15, 15) degrees) plus Gaussian pixel noise; the 23 fit landmarks
  (:data:`facegeom.model.landmarks.FIT_LANDMARKS_23`) are given to the fitter **without the
  pose** (every method estimates it); NE (eq. 31) on the 26 unused landmarks
  against their clean projections, normalised by the true inner-eye-corner
  distance, and on the 23 used ones against the noisy input; ERSim (appendix),
  Corr / Corr(+) / Corr(-) (eq. 33, full-mesh inner products, cm^2); mean
  vertex error over the face area (mm) and coefficient recovery.
- ``clouds`` (Table 4): ~30,000 points sampled uniformly on the target's face
  area plus Gaussian noise, ``samplings`` samplings per target; NE (eq. 32),
  vertex error, Corr, recovery.
- ``meshes``: the target mesh in correspondence; vertex error, ERSim, Corr,
  recovery, and fits per second.
- ``temporal`` (Sec. V-C): every frame of a real take window applied to one
  identity, fitted independently from noisy landmarks; per key shape, how much
  the coefficient jitters (RMS of its second difference over time, against the
  truth's) and how well it follows the truth (Pearson correlation, mean
  absolute error).
"""
from __future__ import annotations

import time

import numpy as np

from facegeom import metrics as fm
from facegeom.bench.common import available_specs, face_area_triangles, progress_bar, projector, sample_surface
from facegeom.bench.report import Report, format_table, machine_note
from facegeom.constants import FACE_AREA
from facegeom.errors import FacegeomError
from facegeom.interfaces import batched_targets, fit_many
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
from facegeom.model.scenarios import fitting_cases

EXPERIMENTS = ("landmarks", "clouds", "meshes", "temporal", "speed")
KEY_SHAPES = ("jawOpen", "eyeBlink_L", "eyeBlink_R", "mouthSmile_L", "mouthSmile_R", "browInnerUp_L", "mouthFunnel")


def _common(rig, r, w_true, V_true):
    corr = fm.correlation_metrics(rig, r.weights)
    sup = fm.support_scores(r.weights, w_true, tol=1e-3)
    return {"corr": corr.corr, "corr_pos": corr.corr_pos, "corr_neg": corr.corr_neg,
            "vertex_mm": fm.mean_vertex_error_mm(r.vertices, V_true, np.arange(FACE_AREA)),
            "n_active": int((np.abs(r.weights) > 1e-3).sum()), "precision": sup.precision, "recall": sup.recall,
            "coef_mae": sup.mean_abs_error}


def _fit(spec, rig, target):
    m = spec.build("fitters")
    t = time.perf_counter()
    r = m.fit(rig, target)
    return r, time.perf_counter() - t


# --------------------------------------------------------------------------- landmarks
def run_landmarks(model, cases, specs, noise_px=1.0, seed=0, progress=True):
    """The landmark experiment: fit the 23 noisy landmarks of every case with every method, pose unknown.

    Each case's face (its identity's rig at its true weights) is seen by a
    pinhole camera turned by the case's yaw and pitch; the 23 fit landmarks get
    Gaussian pixel noise and are given with the intrinsics only (every method
    estimates the pose). Landmark errors are measured through each fit's own
    camera.

    Parameters
    ----------
    model : FaceModel
        The ICT face model (positions in cm).
    cases : list of SparseExpressionCase
        Identity, true weights ``(B,)``, yaw and pitch of every target
        (:func:`~facegeom.model.scenarios.fitting_cases`).
    specs : list of MethodSpec
        The fitters.
    noise_px : float
        Standard deviation of the landmark noise per coordinate, pixels.
    seed : int
        Seed of the noise.
    progress : bool
        Show a progress bar.

    Returns
    -------
    list of dict
        One row per case and method: ``case``, ``method``, ``time_ms``,
        ``ne_eval`` (NE of the 26 unused landmarks against their clean
        projections) and ``ne_fit`` (NE of the 23 used ones against the noisy
        input), both fractions of the true projected inner-eye-corner distance;
        ``ersim``; ``corr``, ``corr_pos``, ``corr_neg`` (cm^2); ``vertex_mm``
        (mean vertex error over the face area, mm); ``n_active``,
        ``precision``, ``recall`` (support of the weights above 1e-3) and
        ``coef_mae``.
    """
    rng = np.random.default_rng([int(seed), 99])
    lm = model.landmarks
    fit_ids, eval_ids = lm[list(FIT_LANDMARKS_23)], lm[list(EVAL_LANDMARKS_26)]
    eye_ids = lm[list(INNER_EYE_CORNERS)]
    rows = []
    for ci, c in enumerate(progress_bar(cases, "landmarks", progress)):
        rig = BlendshapeRig.from_face_model(model, c.identity)
        V = rig.evaluate(c.weights)
        cam = look_at_camera(V, yaw=c.yaw, pitch=c.pitch)
        uv_fit = cam.project(V[fit_ids]) + rng.normal(size=(fit_ids.size, 2)) * noise_px
        uv_eval = cam.project(V[eval_ids])
        io = fm.interocular_distance(*cam.project(V[eye_ids]))
        target = LandmarkTarget(uv_fit, fit_ids, PinholeCamera(cam.focal, cam.cx, cam.cy))
        for spec in specs:
            r, dt = _fit(spec, rig, target)
            proj = projector(r, cam)
            row = {"case": ci, "method": spec.label, "time_ms": dt * 1e3,
                   "ne_eval": fm.normalized_error(proj(r.vertices[eval_ids]), uv_eval, io),
                   "ne_fit": fm.normalized_error(proj(r.vertices[fit_ids]), uv_fit, io),
                   "ersim": fm.motion_ersim(uv_fit, proj(r.vertices[fit_ids]), proj(rig.neutral[fit_ids]))}
            row.update(_common(rig, r, c.weights, V))
            rows.append(row)
    return rows


def run_landmark_throughput(model, specs, seed=0, count=1000, noise_px=1.0, one_by_one=10, repeats=1,
                            progress=False):
    """Landmark fits per second on one rig: known pose and estimated pose.

    A method that solves landmark targets together (``"landmarks"`` in
    :func:`~facegeom.interfaces.batched_targets`) fits ``count`` targets in one
    :func:`~facegeom.interfaces.fit_many`; others are timed one by one on
    ``one_by_one`` targets. The rate is the median of ``repeats`` timed runs
    (on a shared machine single runs vary by 2x). ``progress`` shows two bars:
    the targets being made, then the timed runs (one step per method and pose).
    """
    rng = np.random.default_rng([int(seed), 57])
    cases = fitting_cases(model, count, int(seed) + 1000)
    rig = BlendshapeRig.from_face_model(model, cases[0].identity)
    ids = model.landmarks[list(FIT_LANDMARKS_23)]
    posed, unposed = [], []
    for c in progress_bar(cases, "landmark speed: targets", progress, unit="target"):
        V = rig.evaluate(c.weights)
        cam = look_at_camera(V, yaw=c.yaw, pitch=c.pitch)
        uv = cam.project(V[ids]) + rng.normal(size=(ids.size, 2)) * noise_px
        posed.append(LandmarkTarget(uv, ids, cam))
        unposed.append(LandmarkTarget(uv, ids, PinholeCamera(cam.focal, cam.cx, cam.cy)))
    work = [(i, key, targets) for i in range(len(specs))
            for key, targets in (("known_pose", posed), ("estimated_pose", unposed))]
    rows = [{"method": s.label, "targets": int(count)} for s in specs]
    built = {}
    for i, key, targets in progress_bar(work, "landmark speed", progress, unit="run"):
        if i not in built:  # one fitter per method, for both poses
            built[i] = specs[i].build("fitters")
        m = built[i]
        row = rows[i]
        try:
            m.fit(rig, targets[0])
        except FacegeomError:
            row[key] = float("nan")
            continue
        rates = []
        for _ in range(max(1, int(repeats))):
            if "landmarks" in batched_targets(m):
                t = time.perf_counter()
                fit_many(m, rig, targets)
                n, row["path"] = len(targets), "batched"
            else:
                n, row["path"] = min(one_by_one, len(targets)), "one by one"
                t = time.perf_counter()
                for tg in targets[:n]:
                    m.fit(rig, tg)
            rates.append(n / (time.perf_counter() - t))
        row[key] = float(np.median(rates))
    return rows


def throughput_heading(kind: str, n_methods: int, count: int, repeats: int = 1) -> str:
    """The line announcing a throughput measurement: what it times and roughly how long it takes.

    Parameters
    ----------
    kind : "landmark" or "mesh"
        Which throughput.
    n_methods : int
        Fitters timed.
    count : int
        Targets per timed run (a method without a batched path times only its first few).
    repeats : int
        Timed runs per method (the rate is their median).

    Returns
    -------
    str
        One line; the duration is a range, from a quiet machine to a busy one.
    """
    runs = max(1, n_methods) * max(1, int(repeats)) * max(count, 1) / THROUGHPUT_REFERENCE[kind]
    lo, hi = (s * runs for s in THROUGHPUT_SECONDS[kind])
    what = ("landmark fits per second on one rig, 23 landmarks per target, with the pose known and with it "
            "estimated" if kind == "landmark" else "mesh fits per second on one rig, targets in correspondence")
    median = f", median of {repeats} runs" if repeats > 1 else ""
    return (f"{kind} throughput: {what} ({n_methods} fitters, {count:,} targets{median}); "
            f"this takes roughly {_duration(lo)} to {_duration(hi)}")


def landmark_throughput_targets(cases: int) -> int:
    """Targets of the landmark throughput that the ``landmarks`` experiment times after ``cases`` fits: ten per case,
    100 to 1,000 (the default 100 cases: 1,000; a quick run of a few cases does not spend most of its time on the
    rate; the ``speed`` experiment always times 1,000)."""
    return int(min(1000, max(100, 10 * int(cases))))


THROUGHPUT_SECONDS = {"landmark": (5.0, 30.0), "mesh": (0.5, 3.0)}
"""Seconds per fitter and timed run of the throughputs (targets included): an idle 2-core machine, a busy one;
at :data:`THROUGHPUT_REFERENCE` targets (in proportion for others)."""

THROUGHPUT_REFERENCE = {"landmark": 1000, "mesh": 2000}


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.0f} minutes"


# --------------------------------------------------------------------------- point clouds
def run_clouds(model, cases, specs, samplings=10, points=30000, noise_cm=0.02, seed=0, progress=True):
    """The point-cloud experiment: fit noisy surface samples of every case's face with every method.

    For each case and sampling, ``points`` points are drawn uniformly by area on
    the face-area triangles of the true face, plus Gaussian noise. A fitter with
    a ``region`` parameter is restricted to the face area; a fitter that refuses
    point clouds (a :class:`~facegeom.errors.FacegeomError`, e.g. eos) gets no
    row.

    Parameters
    ----------
    model : FaceModel
        The ICT face model (positions in cm).
    cases : list of SparseExpressionCase
        The targets.
    specs : list of MethodSpec
        The fitters.
    samplings : int
        Point clouds per case.
    points : int
        Points per cloud.
    noise_cm : float
        Standard deviation of the noise per coordinate, cm.
    seed : int
        Seed of the sampling and the noise.
    progress : bool
        Show a progress bar.

    Returns
    -------
    list of dict
        One row per case, sampling and method: ``case``, ``sampling``,
        ``method``, ``time_ms``, ``ne`` (eq. 32 over the face-area vertices, a
        fraction of the fitted inner-eye-corner distance), and the columns
        shared with :func:`run_landmarks` (``corr``, ``corr_pos``,
        ``corr_neg``, ``vertex_mm``, ``n_active``, ``precision``, ``recall``,
        ``coef_mae``).
    """
    rng = np.random.default_rng([int(seed), 4711])
    tris = face_area_triangles(model)
    eye_ids = model.landmarks[list(INNER_EYE_CORNERS)]
    region = np.arange(FACE_AREA)
    rows = []
    work = [(ci, c, s) for ci, c in enumerate(cases) for s in range(samplings)]
    for ci, c, s in progress_bar(work, "clouds", progress):
        rig = BlendshapeRig.from_face_model(model, c.identity)
        V = rig.evaluate(c.weights)
        P = sample_surface(V, tris, points, rng) + rng.normal(size=(points, 3)) * noise_cm
        target = PointCloudTarget(P)
        for spec in specs:
            m = spec.build("fitters")
            if "region" in m.param_names():
                m.set_params(region=region)
            t = time.perf_counter()
            try:
                r = m.fit(rig, target)
            except FacegeomError:  # a method that does not fit point clouds (eos: landmarks only)
                continue
            dt = time.perf_counter() - t
            row = {"case": ci, "sampling": s, "method": spec.label, "time_ms": dt * 1e3,
                   "ne": fm.pointcloud_normalized_error(r.vertices, target, eye_ids, region)}
            row.update(_common(rig, r, c.weights, V))
            rows.append(row)
    return rows


# --------------------------------------------------------------------------- meshes
def run_meshes(model, cases, specs, seed=0, progress=True):
    """The mesh experiment: fit every case's true face in correspondence, then measure fit throughput.

    Parameters
    ----------
    model : FaceModel
        The ICT face model (positions in cm).
    cases : list of SparseExpressionCase
        The targets; at least one (the throughput uses the first case's rig).
    specs : list of MethodSpec
        The fitters; one that refuses mesh targets (a
        :class:`~facegeom.errors.FacegeomError`) gets no row.
    seed : int
        Seed of the throughput targets.
    progress : bool
        Show a progress bar.

    Returns
    -------
    rows : list of dict
        One row per case and method: ``case``, ``method``, ``time_ms``,
        ``ersim`` and the columns shared with :func:`run_landmarks`.
    throughput : list of dict
        Per method: ``method``, ``fits_per_s`` and ``path``, on 2000 random
        sparse targets of the first rig (each shape active with probability
        0.08, weight U(0.2, 1)): all in one :func:`~facegeom.interfaces.fit_many`
        after a 10-target warm-up (``"batched"``) when the method batches mesh
        targets, else the first 100 one by one (``"one by one"``).
    """
    rows = []
    rigs = {}
    for ci, c in enumerate(progress_bar(cases, "meshes", progress)):
        rig = BlendshapeRig.from_face_model(model, c.identity)
        rigs[ci] = rig
        V = rig.evaluate(c.weights)
        for spec in specs:
            try:
                r, dt = _fit(spec, rig, MeshTarget(V))
            except FacegeomError:
                continue
            row = {"case": ci, "method": spec.label, "time_ms": dt * 1e3,
                   "ersim": fm.mesh_ersim(r.vertices, rig.neutral, V)}
            row.update(_common(rig, r, c.weights, V))
            rows.append(row)
    # throughput on one rig: many targets at once where a method has a batched path
    return rows, run_mesh_throughput(rigs[0], specs, seed, progress=progress)


def run_mesh_throughput(rig, specs, seed=0, count=2000, one_by_one=100, repeats=1, progress=False):
    """Mesh fits per second on one rig: ``count`` random sparse targets in correspondence.

    Each shape is active with probability 0.08, weight U(0.2, 1). A method that
    batches mesh targets (``"mesh"`` in :func:`~facegeom.interfaces.batched_targets`)
    fits them all in one :func:`~facegeom.interfaces.fit_many` after a
    10-target warm-up (``"batched"``); others fit the first ``one_by_one`` one by
    one. The rate is the median of ``repeats`` timed runs (``progress``: a bar over the methods). Returns
    one dict per method that accepts meshes: ``method``, ``fits_per_s``, ``path``.
    """
    rng = np.random.default_rng([int(seed), 31])
    W = np.where(rng.random((count, rig.n_shapes)) < 0.08, rng.uniform(0.2, 1.0, (count, rig.n_shapes)), 0.0)
    T = rig.neutral[None] + np.tensordot(W, rig.deltas, 1)
    throughput = []
    for spec in progress_bar(specs, "mesh speed", progress, unit="method"):
        m = spec.build("fitters")
        try:
            m.fit(rig, MeshTarget(T[0]))
        except FacegeomError:
            continue
        rates = []
        for _ in range(max(1, int(repeats))):
            if "mesh" in batched_targets(m):
                fit_many(m, rig, T[:10])
                t = time.perf_counter()
                fit_many(m, rig, T)
                n, dt, how = len(T), time.perf_counter() - t, "batched"
            else:
                n = min(one_by_one, len(T))
                t = time.perf_counter()
                for k in range(n):
                    m.fit(rig, MeshTarget(T[k]))
                dt, how = time.perf_counter() - t, "one by one"
            rates.append(n / dt)
        throughput.append({"method": spec.label, "fits_per_s": float(np.median(rates)), "path": how})
    return throughput


# --------------------------------------------------------------------------- temporal stability
def run_temporal(model, weights, specs, seed=0, noise_px=0.5, progress=True, name="take"):
    """Fit every frame of ``weights (T, B)`` (one identity, fixed camera, unknown pose) independently."""
    rng = np.random.default_rng([int(seed), 2024])
    rig = BlendshapeRig.from_face_model(model, model.random_identity(rng))
    fit_ids = model.landmarks[list(FIT_LANDMARKS_23)]
    cam = look_at_camera(rig.neutral, yaw=10, pitch=-5)
    unposed = PinholeCamera(cam.focal, cam.cx, cam.cy)
    T = weights.shape[0]
    fitted = {s.label: np.zeros_like(weights) for s in specs}
    for t in progress_bar(range(T), "temporal", progress):
        V = rig.evaluate(weights[t])
        uv = cam.project(V[fit_ids]) + rng.normal(size=(fit_ids.size, 2)) * noise_px
        for s in specs:
            fitted[s.label][t] = s.build("fitters").fit(rig, LandmarkTarget(uv, fit_ids, unposed)).weights
    rows = []
    for s in specs:
        for shape in KEY_SHAPES:
            j = rig.shape_index(shape)
            f, g = fitted[s.label][:, j], weights[:, j]
            corr = float(np.corrcoef(f, g)[0, 1]) if f.std() > 0 and g.std() > 0 else float("nan")
            rows.append({"take": name, "method": s.label, "shape": shape,
                         "jitter": float(np.sqrt(np.mean(np.diff(f, 2) ** 2))),
                         "truth_jitter": float(np.sqrt(np.mean(np.diff(g, 2) ** 2))),
                         "pearson": corr, "mae": float(np.abs(f - g).mean())})
    return rows, fitted


# --------------------------------------------------------------------------- summaries
def _mean(rows, method, key):
    v = np.array([r[key] for r in rows if r["method"] == method], dtype=float)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else float("nan")


def _median(rows, method, key):
    v = np.array([r[key] for r in rows if r["method"] == method], dtype=float)
    return float(np.median(v)) if v.size else float("nan")


def summarize(results: dict, specs) -> str:
    """The Markdown summary: one titled table per experiment present in ``results``.

    Parameters
    ----------
    results : dict
        Any of ``landmarks``, ``landmark_speed``, ``mesh_speed``, ``clouds`` and ``temporal``
        (lists of rows) and ``meshes`` (the rows and throughput of
        :func:`run_meshes`).
    specs : list of MethodSpec
        The methods, in table order; a method without rows in an experiment is
        left out of its table.

    Returns
    -------
    str
        The tables separated by blank lines: means over the rows (NaN ignored;
        NE in percent) and median times.
    """
    parts = []
    labels = [s.label for s in specs]
    if "landmarks" in results:
        rows = results["landmarks"]
        header = ["method", "NE unused 26 (%)", "NE used 23 (%)", "ERSim", "Corr", "Corr(+)", "Corr(-)",
                  "vertex (mm)", "active", "precision", "recall", "coef MAE", "time (ms)"]
        parts.append("Landmarks (23 used, 26 unused; pose estimated)\n\n" + format_table(header, [
            [m, 100 * _mean(rows, m, "ne_eval"), 100 * _mean(rows, m, "ne_fit"), _mean(rows, m, "ersim"),
             _mean(rows, m, "corr"), _mean(rows, m, "corr_pos"), _mean(rows, m, "corr_neg"),
             _mean(rows, m, "vertex_mm"), _mean(rows, m, "n_active"), _mean(rows, m, "precision"),
             _mean(rows, m, "recall"), _mean(rows, m, "coef_mae"), _median(rows, m, "time_ms")]
            for m in labels if any(r["method"] == m for r in rows)]))
    if "landmark_speed" in results:
        rows = results["landmark_speed"]
        header = ["method", "fits/s, known pose", "fits/s, pose estimated", "path"]
        targets = rows[0].get("targets") if rows else None
        per = f", {int(targets):,} targets a run" if targets else ""
        parts.append(f"Landmark throughput (one rig, 23 landmarks{per})\n\n" + format_table(header, [
            [r["method"], r.get("known_pose", float("nan")), r.get("estimated_pose", float("nan")), r.get("path", "-")]
            for r in rows]))
    if "mesh_speed" in results:
        header = ["method", "fits/s", "path"]
        parts.append("Mesh throughput (one rig, 9,409 vertices, 2,000 sparse targets)\n\n" + format_table(header, [
            [r["method"], r["fits_per_s"], r["path"]] for r in results["mesh_speed"]]))
    if "clouds" in results:
        rows = results["clouds"]
        header = ["method", "NE (%)", "vertex (mm)", "Corr", "active", "precision", "recall", "coef MAE", "time (ms)"]
        parts.append("Point clouds\n\n" + format_table(header, [
            [m, 100 * _mean(rows, m, "ne"), _mean(rows, m, "vertex_mm"), _mean(rows, m, "corr"),
             _mean(rows, m, "n_active"), _mean(rows, m, "precision"), _mean(rows, m, "recall"),
             _mean(rows, m, "coef_mae"), _median(rows, m, "time_ms")]
            for m in labels if any(r["method"] == m for r in rows)]))
    if "meshes" in results:
        rows, thr = results["meshes"]
        tp = {t["method"]: t for t in thr}
        header = ["method", "vertex (mm)", "ERSim", "Corr", "active", "precision", "recall", "coef MAE",
                  "fits/s", "path"]
        parts.append("Corresponding meshes\n\n" + format_table(header, [
            [m, _mean(rows, m, "vertex_mm"), _mean(rows, m, "ersim"), _mean(rows, m, "corr"),
             _mean(rows, m, "n_active"), _mean(rows, m, "precision"), _mean(rows, m, "recall"),
             _mean(rows, m, "coef_mae"), tp.get(m, {}).get("fits_per_s", float("nan")), tp.get(m, {}).get("path", "-")]
            for m in labels if any(r["method"] == m for r in rows)]))
    if "temporal" in results:
        rows = results["temporal"]
        header = ["method", "jitter (RMS 2nd diff.)", "truth's jitter", "Pearson r", "MAE"]
        parts.append("Temporal stability (key shapes: " + ", ".join(KEY_SHAPES) + ")\n\n" + format_table(header, [
            [m, _mean(rows, m, "jitter"), _mean(rows, m, "truth_jitter"), _mean(rows, m, "pearson"),
             _mean(rows, m, "mae")] for m in labels if any(r["method"] == m for r in rows)]))
    return "\n\n".join(parts)


def plot(results, specs, fitted, weights):
    """The experiments run, one panel each, as a matplotlib figure.

    Landmark accuracy and redundancy (two panels), the mean vertex error of the
    point-cloud and the mesh fits, and jawOpen over the take (temporal): only
    the panels of the experiments in ``results`` (and ``fitted``) are laid out,
    so none is left empty.

    Parameters
    ----------
    results : dict
        The rows per experiment, as from :func:`main`.
    specs : list of MethodSpec
        The methods, in bar order.
    fitted : dict of str -> (T, 1) array, or None
        The jawOpen coefficient of every method over the take (temporal).
    weights : (T, 1) array or None
        The true jawOpen coefficient over the take.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt

    labels = [s.label for s in specs]

    def present(rows):
        return [m for m in labels if any(r["method"] == m for r in rows)]

    def bars(title, ylabel, rows, key, scale=1.0):
        ms = present(rows)

        def draw(a):
            a.bar(ms, [scale * _mean(rows, m, key) for m in ms])
            a.set(ylabel=ylabel, title=title)
            a.tick_params(axis="x", rotation=45)
        return draw

    panels = []
    if results.get("landmarks"):
        rows = results["landmarks"]
        panels.append(bars("Landmarks: accuracy", "NE on the 26 unused landmarks (%)", rows, "ne_eval", 100.0))
        panels.append(bars("Landmarks: redundancy (eq. 33)", "Corr (cm^2)", rows, "corr"))
    if results.get("clouds"):
        panels.append(bars("Point clouds: accuracy", "mean vertex error, face area (mm)", results["clouds"],
                           "vertex_mm"))
    if results.get("meshes") and results["meshes"][0]:
        panels.append(bars("Corresponding meshes: accuracy", "mean vertex error, face area (mm)",
                           results["meshes"][0], "vertex_mm"))
    if fitted is not None and weights is not None:  # one key shape (jawOpen) over the take, truth and every method
        def temporal(a):
            a.plot(weights[:, 0], "k-", lw=2, label="truth")
            for m, W in fitted.items():
                a.plot(W[:, 0], label=m)
            a.set(xlabel="frame", ylabel="coefficient", title="Temporal stability: jawOpen")
            a.legend(fontsize=8)
        panels.append(temporal)
    if not panels:  # only throughputs (their numbers are in the summary): say so rather than draw empty axes
        def nothing(a):
            a.text(0.5, 0.5, "no accuracy experiment run: see the summary's throughput tables", ha="center",
                   va="center", transform=a.transAxes)
            a.set_axis_off()
        panels.append(nothing)
    fig, ax = plt.subplots(1, len(panels), figsize=(5.7 * len(panels), 4.6), squeeze=False)
    for a, draw in zip(ax[0], panels):
        draw(a)
    fig.tight_layout()
    return fig


def main(model, specs, experiments, count, seed, out, noise_px=1.0, cloud_cases=5, samplings=10, points=30000,
         take=None, echo=print, progress=True, plot_it=True, takes=None, realistic_count=0, identity_fitters=None,
         cloud_frame="model", contour="outline"):
    """Run the selected fitting experiments and write their report.

    Fitters whose plugin cannot be built (an optional peer such as eos) are
    skipped with a message.

    Parameters
    ----------
    model : FaceModel
        The ICT face model (positions in cm).
    specs : list of MethodSpec
        The fitters.
    experiments : collection of str
        Any of ``landmarks``, ``clouds``, ``meshes``, ``temporal``, ``speed`` (only the landmark and
        mesh throughputs, medians of 3 runs).
    count : int
        Number of targets (:func:`~facegeom.model.scenarios.fitting_cases`).
    seed : int
        Seed of the targets and the noise.
    out : path-like or None
        Output folder; ``None`` only echoes the summary.
    noise_px : float
        Landmark noise, pixels.
    cloud_cases : int
        The point clouds use the first ``cloud_cases`` targets.
    samplings : int
        Point clouds per target.
    points : int
        Points per cloud.
    take : (str, ndarray) or None
        A named take of ICT-ordered weights ``(T, E)`` for ``temporal``, which
        runs only with one, on the fitters named ``sem`` and ``l1reg``.
    echo : callable(str)
        Receives the messages, the summary and the list of files written.
    progress : bool
        Show progress bars.
    plot_it : bool
        Also write the plot.
    takes : list of (str, (T, E) array), optional
        Real takes for the realistic protocol (:mod:`facegeom.bench.fit_realistic`),
        which runs first, on ``realistic_count`` cases, for the experiments among
        ``landmarks``, ``meshes`` and ``clouds`` (clouds: ``cloud_cases`` cases).
    realistic_count : int
        Cases of the realistic protocol (0: not run).
    identity_fitters : dict, optional
        Identity fitters per experiment for the realistic protocol's ``fitted`` mode
        (default: :func:`facegeom.bench.fit_realistic.identity_fitters`; ``{}``: no fitted mode).
    cloud_frame : "model" or "any"
        The realistic clouds in the model's frame and units, or as another tool
        exports them (:func:`facegeom.bench.fit_realistic.run_clouds`).
    contour : "outline" or "fixed"
        The realistic photos' jaw contour on the face's outline in the view, or
        on fixed vertices (:func:`facegeom.bench.fit_realistic.run_landmarks`).

    Returns
    -------
    results : dict
        The rows per experiment (keys as in :func:`summarize`).
    table : str
        The summary of :func:`summarize`. Files written into ``out``:
        ``fit-landmarks.csv`` and ``fit-landmark-speed.csv``, ``fit-mesh-speed.csv``,
        ``fit-clouds.csv``, ``fit-meshes.csv`` (per case; the throughput is only
        in the summary), ``fit-temporal.csv`` (for the experiments run),
        ``fit-summary.md`` and ``fit.png``.
    """
    specs = available_specs(specs, echo)
    report = Report(out, "fit", echo)
    realistic_table = ""
    if takes and realistic_count:
        from facegeom.bench import fit_realistic

        if identity_fitters is None:
            identity_fitters = fit_realistic.identity_fitters(model)
        _, realistic_table = fit_realistic.main(model, specs, experiments, takes, realistic_count, seed, report,
                                                identity_fitters, cloud_cases, min(points, 10000), echo, progress,
                                                cloud_frame, contour)
    cases = fitting_cases(model, count, seed)
    results, fitted, tw = {}, None, None
    if "landmarks" in experiments:
        results["landmarks"] = run_landmarks(model, cases, specs, noise_px, seed, progress)
        report.csv(results["landmarks"], "landmarks")
        n_speed = landmark_throughput_targets(count)
        echo(throughput_heading("landmark", len(specs), n_speed))
        results["landmark_speed"] = run_landmark_throughput(model, specs, seed, count=n_speed, noise_px=noise_px,
                                                            progress=progress)
        report.csv(results["landmark_speed"], "landmark-speed")
    if "speed" in experiments:  # only the throughputs, each the median of 3 runs
        if "landmark_speed" not in results:
            echo(throughput_heading("landmark", len(specs), 1000, repeats=3))
            results["landmark_speed"] = run_landmark_throughput(model, specs, seed, noise_px=noise_px, repeats=3,
                                                                progress=progress)
            report.csv(results["landmark_speed"], "landmark-speed")
        echo(throughput_heading("mesh", len(specs), 2000, repeats=3))
        results["mesh_speed"] = run_mesh_throughput(BlendshapeRig.from_face_model(model, cases[0].identity), specs,
                                                    seed, repeats=3, progress=progress)
        report.csv(results["mesh_speed"], "mesh-speed")
    if "clouds" in experiments:
        results["clouds"] = run_clouds(model, cases[:cloud_cases], specs, samplings, points, seed=seed,
                                       progress=progress)
        report.csv(results["clouds"], "clouds")
    if "meshes" in experiments:
        results["meshes"] = run_meshes(model, cases, specs, seed, progress)
        report.csv(results["meshes"][0], "meshes")
    if "temporal" in experiments and take is not None:
        name, W = take
        tspecs = [s for s in specs if s.name in ("sem", "sem-ls", "l1reg")]
        results["temporal"], fitted = run_temporal(model, W, tspecs, seed, progress=progress, name=name)
        j = model.expression_index("jawOpen")
        tw = W[:, [j]]
        fitted = {k: v[:, [j]] for k, v in fitted.items()}
        report.csv(results["temporal"], "temporal")
    table = summarize(results, specs)
    if realistic_table:
        table = (realistic_table + "\n\nThe paper's protocol (sparse expressions, known identity, exact intrinsics)"
                 "\n\n" + table)
    clouds = f", {cloud_cases} x {samplings} point clouds of {points} points" if "clouds" in results else ""
    note = (f"paper protocol: {count} targets (seed {seed}), landmark noise {noise_px} px{clouds}; "
            + (f"realistic protocol: {realistic_count} cases from {len(takes)} takes; " if realistic_table else "")
            + machine_note())
    report.summary(table, note)
    if plot_it:
        report.plot(lambda: plot(results, specs, fitted, tw))
    report.done()
    return results, table
