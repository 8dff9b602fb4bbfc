"""A performance onto another character through the rig, measured where the truth is known.

Protocol (seeded, ``facegeom bench character``): per case,

- the **actor**: a random ICT identity performing a window of a real take (its
  ICT weights), seen as the 80 markers of the ``ict80`` layout with 0.2 mm of
  noise, the head turning and moving;
- the **character**: another random ICT identity, remeshed by pymeshlab to
  another topology (10,000-13,000 vertices) and given to ``facegeom transfer`` as a
  bare head; its **true** performance is the take's weights on its true shapes
  (the ICT expressions resampled at its vertices, barycentric);
- the **routes** (each a solve of the actor, curves smoothed as ``facegeom
  solve`` does by default, then weights played on a character rig by name):

  ``facegeom (actor's rig)``: solve on the actor's own rig (its true identity:
  what ``facegeom identity`` fits, at best), character rig by deformation
  transfer; ``facegeom (actor's identity fitted to a scan)``: what a user has,
  the actor's identity fitted as ``facegeom identity`` fits a point cloud
  (:class:`~facegeom.methods.identity.IdentityFitter` with the command's
  defaults: neutral target, ``expressions=False``; the rig
  :attr:`~facegeom.methods.identity.IdentityFit.rig`, the command's output) to
  a neutral scan of the actor -- :data:`SCAN_POINTS` points sampled by area on
  the face area of its true neutral, :data:`SCAN_NOISE_MM` mm of noise, in a
  random rigid pose (a scan is not aligned) -- then the same solve and transfer
  (the fit's own error, RMS of the fitted neutral against the true one over
  the face area, is the rows' ``identity_rms_mm``); ``facegeom, generic
  actor``: solve on the generic ICT face (no identity fit), deformation
  transfer; baselines ``copy weights, nearest transfer``: the generic solve
  copied onto a rig built by copying each delta from the nearest registered
  point (the common shortcut); and
  ``true weights, deformation transfer``: the take's own weights on the
  transferred rig (the transfer's share of the error); ``markers``: the
  paper's route, no rig: the actor's markers (head motion removed by its solve)
  retargeted by the tangent framework from :data:`KEYS` key frames whose labels
  are proposed automatically
  (:func:`facegeom.pipelines.character_markers.markers_onto_character`), the
  character's mesh driven by the tangent deformer. Labels proposed that way are
  an affine function of the actor's markers, which every retargeter here
  reproduces exactly (the tangent and RBF retargeters give the same frames),
  so the retargeters are compared with the labels an artist would pose: the
  character's **true** markers at the key frames (``markers, true labels``:
  tangent, and RBF, the baseline of the retargeting experiments).

Per route: the character's face error per frame (RMS over the vertices near
the face area, mm at the character's own size), median and 95th percentile
over frames; the weight error (mean absolute, against the take's); the jitter
(mean absolute second difference of the face's vertices over frames, mm per
frame squared) next to the truth's own.
"""
from __future__ import annotations

import time

import numpy as np
from scipy.spatial.transform import Rotation

from facegeom.bench.report import Report, format_table, machine_note
from facegeom.constants import CM_TO_MM, FACE_AREA

__all__ = ["make_character", "run_case", "run", "ROUTES"]

OWN, FITTED = "facegeom (actor's rig)", "facegeom (actor's identity fitted to a scan)"
GENERIC = "facegeom, generic actor"
COPY, TRUE_WEIGHTS = "copy weights, nearest transfer", "true weights, deformation transfer"
PROPOSED, TANGENT, RBF = "markers, labels proposed", "markers, true labels: tangent", "markers, true labels: RBF"
ROUTES = (OWN, FITTED, GENERIC, COPY, TRUE_WEIGHTS, PROPOSED, TANGENT, RBF)
MARKER_ROUTES = {TANGENT: "tangent", RBF: "rbf"}  # route -> retargeter, with the character's true labels
KEYS = 10  # the marker route's key frames (labels proposed from the actor's displacements)
EDGE_CM = 0.3  # the character's remesh: target edge length (10,000-13,000 vertices)
NOISE_MM = 0.2  # marker noise of the actor's capture
SCAN_POINTS = 5000  # the actor's neutral scan: points sampled by area on the face area
SCAN_NOISE_MM = 0.5  # the scan's noise (per coordinate)


def make_character(model, seed: int):
    """A random ICT identity remeshed to another topology -> ``(V cm, F, true deltas (K, n, 3) cm, face mask (n,))``."""
    import igl
    import pymeshlab

    a = model.random_identity(np.random.default_rng([int(seed), 7]))
    V0 = model.identity_neutral(a)
    T = np.asarray(model.triangles, dtype=np.int64)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(V0, T))
    ms.meshing_isotropic_explicit_remeshing(targetlen=pymeshlab.PureValue(EDGE_CM), iterations=5)
    m = ms.current_mesh()
    V, F = m.vertex_matrix().astype(np.float64), m.face_matrix().astype(np.int64)
    _, tri, C = igl.point_mesh_squared_distance(V, V0, T)
    b = igl.barycentric_coordinates(C, V0[T[tri, 0]], V0[T[tri, 1]], V0[T[tri, 2]])
    b = np.where(np.isfinite(b), b, 1.0 / 3.0)
    D = np.asarray(model.expression_deltas, dtype=np.float64)
    truth = np.einsum("vj,kvjc->kvc", b, D[:, T[tri]])
    face = (T[tri] < FACE_AREA).all(axis=1)
    return V, F, truth, face


def _actor_capture(model, a_seed: int, W, rng):
    """The actor's markers: identity ``a_seed`` performing ``W (T, K)``, head motion, noise.

    Returns ``(X (T, p, 3), ids, the actor's rig)``.
    """
    from facegeom.model import BlendshapeRig
    from facegeom.model.layouts import ict80

    rig = BlendshapeRig.from_face_model(model, model.random_identity(np.random.default_rng([int(a_seed), 3])))
    ids = ict80(model)
    T = W.shape[0]
    F = rig.neutral[ids][None] + np.einsum("tb,bpi->tpi", W, rig.deltas[:, ids])
    R = Rotation.from_rotvec(np.cumsum(rng.normal(0, 0.01, (T, 3)), axis=0)).as_matrix()
    t = np.cumsum(rng.normal(0, 0.05, (T, 3)), axis=0)
    X = np.einsum("tij,tpj->tpi", R, F) + t[:, None] + rng.normal(0, NOISE_MM / CM_TO_MM, F.shape)
    return X, ids, rig


def _fitted_actor(model, actor, seed):
    """The actor's identity fitted to a neutral scan as ``facegeom identity`` fits a point cloud.

    The scan: :data:`SCAN_POINTS` points sampled by area on the face area of the
    actor's true neutral, :data:`SCAN_NOISE_MM` mm of Gaussian noise, turned at
    random and moved (model units, cm, as the command's readers deliver it).
    Returns ``(the user-specific rig, RMS of its neutral against the true one over the face area, mm)``.
    """
    from facegeom.bench.common import face_area_triangles, sample_surface
    from facegeom.methods.identity import IdentityFitter
    from facegeom.model import PointCloudTarget

    rng = np.random.default_rng(seed)
    P = sample_surface(actor.neutral, face_area_triangles(model), SCAN_POINTS, rng)
    P = P + rng.normal(0.0, SCAN_NOISE_MM / CM_TO_MM, P.shape)
    R = Rotation.random(random_state=int(rng.integers(1 << 31))).as_matrix()
    P = P @ R.T + rng.normal(0.0, 30.0, 3)
    fit = IdentityFitter(expressions=False).fit(model, PointCloudTarget(P))  # the command's defaults
    rig = fit.rig  # what the command writes (BlendshapeRig.from_face_model(model, fit.identity))
    d = rig.neutral[:FACE_AREA] - actor.neutral[:FACE_AREA]
    return rig, float(np.sqrt((d ** 2).sum(axis=1).mean()) * CM_TO_MM)


def run_case(model, W, a_seed: int, c_seed: int, fitter=None, progress=None) -> dict:
    """One actor / character pair on the take window ``W (T, 53)`` -> per route the metrics (see module)."""
    from facegeom.methods.marker_solve import solve_markers
    from facegeom.methods.transfer import register_character, transfer_character
    from facegeom.model import BlendshapeRig

    say = progress or (lambda line: None)
    rng = np.random.default_rng([int(a_seed), int(c_seed), 11])
    X, ids, actor = _actor_capture(model, a_seed, W, rng)
    generic = BlendshapeRig.from_face_model(model)
    t0 = time.perf_counter()
    fitted, identity_rms = _fitted_actor(model, actor, [int(a_seed), int(c_seed), 13])
    t_identity = time.perf_counter() - t0
    t0 = time.perf_counter()
    own = solve_markers(X, ids, actor, fitter, smooth="auto")
    solved = {"own": own.weights, "fitted": solve_markers(X, ids, fitted, fitter, smooth="auto").weights,
              "generic": solve_markers(X, ids, generic, fitter, smooth="auto").weights}
    stable = np.einsum("tji,tpj->tpi", own.rotations, X - own.translations[:, None])  # head motion removed
    t_solve = time.perf_counter() - t0
    V, F, truth, face = make_character(model, c_seed)
    t0 = time.perf_counter()
    ch = register_character(model, V, F)
    t_reg = time.perf_counter() - t0
    rigs = {e: transfer_character(model, ch, e).deltas for e in ("deformation", "nearest")}
    say(f"case actor {a_seed} / character {c_seed}: {V.shape[0]} vertices, registration {t_reg:.1f} s, identity "
        f"fit {t_identity:.1f} s ({identity_rms:.2f} mm), solves {t_solve:.1f} s")
    true_frames = np.einsum("tk,kvc->tvc", W, truth[:, face])
    from facegeom.pipelines.character_markers import markers_onto_character

    from facegeom.registry import parse_method

    mr = markers_onto_character(model, stable, actor.neutral[ids], ids, V, F, n_keys=KEYS, character=ch)
    marker_frames = {PROPOSED: mr.frames[:, face] - V[face][None]}
    mv, keys = mr.marker_vertices, mr.key_frames
    true_labels = V[mv][None] + np.einsum("lk,kpc->lpc", W[keys], truth[:, mv])
    for name, spec in MARKER_ROUTES.items():
        mt = markers_onto_character(model, stable, actor.neutral[ids], ids, V, F, keys=keys, labels=true_labels,
                                    character=ch, retargeter=parse_method(spec).build("retargeters"))
        marker_frames[name] = mt.frames[:, face] - V[face][None]
    routes = {OWN: (solved["own"], "deformation"), FITTED: (solved["fitted"], "deformation"),
              GENERIC: (solved["generic"], "deformation"), COPY: (solved["generic"], "nearest"),
              TRUE_WEIGHTS: (W, "deformation")}
    out = {}
    jitter_true = float(np.abs(np.diff(true_frames, 2, axis=0)).mean() * CM_TO_MM)
    for name in ROUTES:
        if name in routes:
            Wr, engine = routes[name]
            frames = np.einsum("tk,kvc->tvc", Wr, rigs[engine][:, face])
        else:
            Wr, frames = np.full_like(W, np.nan), marker_frames[name]
        err = np.sqrt(((frames - true_frames) ** 2).sum(axis=2).mean(axis=1)) * CM_TO_MM  # (T,) RMS mm
        out[name] = {"face_median_mm": float(np.median(err)), "face_p95_mm": float(np.percentile(err, 95)),
                     "weight_mae": float(np.abs(Wr - W).mean()) if np.isfinite(Wr).all() else float("nan"),
                     "jitter": float(np.abs(np.diff(frames, 2, axis=0)).mean() * CM_TO_MM), "jitter_true": jitter_true,
                     "identity_rms_mm": identity_rms if name == FITTED else float("nan")}
    return out


def run(model, takes, out=None, cases: int = 2, frames: int = 300, seed: int = 0, echo=print, progress=None) -> dict:
    """``cases`` actor / character pairs, each on a ``frames`` window of the real takes -> the summary (and files)."""
    from facegeom.io import ict_weights, read_take

    rng = np.random.default_rng(seed)
    Ws = [ict_weights(read_take(p), model.expression_names) for p in takes]
    rows = []
    for c in range(cases):
        W_all = Ws[c % len(Ws)]
        start = int(rng.integers(0, max(1, W_all.shape[0] - frames)))
        W = W_all[start:start + frames]
        res = run_case(model, W, 1000 + 2 * c + seed, 1001 + 2 * c + seed, progress=progress)
        for route, m in res.items():
            rows.append({"case": c, "take": str(takes[c % len(takes)]), "start": start, "route": route, **m})
    rep = Report(out, "character", echo)
    rep.csv(rows)
    table = []
    for route in ROUTES:
        r = [x for x in rows if x["route"] == route]
        table.append([route, f"{np.median([x['face_median_mm'] for x in r]):.3f}",
                      f"{np.median([x['face_p95_mm'] for x in r]):.3f}",
                      f"{np.median([x['weight_mae'] for x in r]):.4f}",
                      f"{np.median([x['jitter'] for x in r]):.4f} ({np.median([x['jitter_true'] for x in r]):.4f})"])
    ident_rms = float(np.median([x["identity_rms_mm"] for x in rows if x["route"] == FITTED]))
    note = (f"{cases} actor / character pairs (random ICT identities; the character remeshed to 10-13k vertices, "
            f"registered as a bare head), {frames}-frame windows of real takes, 80 markers with {NOISE_MM} mm noise; "
            f"face error: RMS over the character's face-area vertices per frame, median over frames (mm). "
            f"The actor's identity fitted to a neutral scan ({SCAN_POINTS} points on the face area, {SCAN_NOISE_MM} mm "
            f"noise, random rigid pose; `facegeom identity`'s defaults): its neutral {ident_rms:.2f} mm RMS from the "
            f"actor's over the face area (median over cases; per case: identity_rms_mm in the CSV). {machine_note()}.")
    rep.summary(format_table(["route", "face error median (mm)", "face error p95 (mm)", "weight MAE",
                              "jitter (truth) mm/frame^2"], table), note)
    return {"rows": rows, "files": rep.written}
