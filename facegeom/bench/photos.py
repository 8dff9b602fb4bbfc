"""Real annotated photos: how well each fitter predicts the landmarks it was not given (``facegeom bench photos``).

Real photos have no 3-D truth, but their annotations check themselves: fit on
some landmarks, predict the others through the fit's own camera, and measure how
far the prediction lands from the annotation, in inner-eye distances (the
distance between the annotated inner eye corners 39 and 42). A fitter that
explains the face predicts the points it did not see; one that follows the noise
or stops short does not.

The faces
---------
- ``aflw2000``: AFLW2000-3D's re-annotated 68 landmarks (2,000 faces in 450 x 450
  px crops of AFLW photos; non-commercial research terms, so they are downloaded
  on request through ``photos-registry.txt``, verified by SHA-256, and never
  shipped). Faces are kept by their yaw (``max_yaw``, default 30 degrees: past
  it the far eye closes up and the inner-eye distance is no normaliser). The
  even-numbered faces were used to choose the default landmark fit
  (:mod:`facegeom.methods.landmark_map`); ``part="held-out"`` scores the
  odd-numbered ones only.
- ``.pts`` files (or folders of them): any 68-point annotations in the iBUG /
  300-W convention; the photo's size comes from an image with the same name
  beside it, otherwise the camera is centred on the face's box with a focal
  length of three box sizes (a face filling a third of the photo).

The camera: the focal length of the photo's larger side (as ``facegeom fit
--image`` assumes), principal point at the centre, the pose estimated.

Protocols
---------
- ``split``: fit the 23 landmarks of the SEM paper's split, score the 26 other
  inner landmarks (:data:`~facegeom.model.FIT_LANDMARKS_23` /
  :data:`~facegeom.model.EVAL_LANDMARKS_26`).
- ``leave-4-out``: all 68 points in 17 folds of four (points ``j, j + 17,
  j + 34, j + 51``: one per region), each fold predicted from the other 64;
  the score is the RMS over all 68 predictions. As ``facegeom fit PHOTO.pts``
  does, the jaw contour is moved to the model's convention
  (:data:`~facegeom.model.landmarks.JAW_CONVENTION`) and its side marked as on
  the outline for the identity fit; predicted jaw points are moved back to the
  annotators' convention before they are scored.

Routes: every fitter with the generic face's rig; the joint identity fit
(``facegeom fit --identity``: identity, pose and expression together); every
fitter again on the rig of that fitted identity; and the pose alone (no
expression), the floor any fitter must beat.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facegeom.bench.report import Report, format_table
from facegeom.errors import FacegeomError, InputError
from facegeom.model import EVAL_LANDMARKS_26, FIT_LANDMARKS_23, BlendshapeRig, LandmarkTarget, PinholeCamera
from facegeom.model.landmarks import SIDE_CONTOUR, contour_candidates, silhouette_vertices, to_annotation_convention
from facegeom.model.landmarks import to_model_convention

__all__ = ["AnnotatedFace", "aflw2000_faces", "pts_faces", "folds", "run", "jaw_offsets", "PROTOCOLS", "PARTS",
           "POSE_ONLY", "JOINT"]

PROTOCOLS = ("split", "leave-4-out")
PARTS = ("all", "design", "held-out")
POSE_ONLY = "pose only"
JOINT = "identity (joint fit)"
AFLW_SIZE = 450  # AFLW2000-3D crops are 450 x 450 px
BOX_FOCAL = 3.0  # focal length in face-box sizes when the photo's size is unknown
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".ppm", ".tif", ".tiff")


@dataclass(frozen=True)
class AnnotatedFace:
    """One annotated photo: 68 points ``(68, 2)`` (0-based pixels), its size ``(w, h)`` if known, yaw if known."""

    name: str
    points: np.ndarray
    size: tuple | None = None
    yaw: float | None = None

    def camera(self) -> PinholeCamera:
        """The camera a user without calibration gets (see the module docstring)."""
        if self.size is not None:
            w, h = self.size
            return PinholeCamera(float(max(w, h)), (w - 1) / 2.0, (h - 1) / 2.0)
        lo, hi = self.points.min(axis=0), self.points.max(axis=0)
        c = 0.5 * (lo + hi)
        return PinholeCamera(BOX_FOCAL * float(max(hi - lo)), float(c[0]), float(c[1]))

    def inner_eye(self) -> float:
        """The annotated inner-eye distance (points 39 and 42), the error's unit."""
        return float(np.linalg.norm(self.points[39] - self.points[42]))


def aflw2000_faces(folder=None, max_yaw: float = 30.0, part: str = "all", echo=print) -> list[AnnotatedFace]:
    """The AFLW2000-3D faces (re-annotated 68 points) with ``|yaw| <= max_yaw`` degrees, of ``part`` (``PARTS``).

    ``folder``: where the registry's files are; default: downloaded (verified)
    into the cache (:func:`facegeom.model.download.fetch_photo_annotations`).
    """
    if part not in PARTS:
        raise InputError(f"part must be one of {', '.join(PARTS)}, got {part!r}")
    if folder is None:
        from facegeom.model.download import fetch_photo_annotations

        folder = fetch_photo_annotations(echo=echo)
    folder = Path(folder)
    files = [folder / "AFLW2000-3D-Reannotated.pts68.npy", folder / "AFLW2000-3D.pose.npy"]
    for f in files:
        if not f.is_file():
            raise InputError(f"not found: {f.name} (run without a folder to download it)", folder)
    try:
        pts = np.load(files[0], allow_pickle=False)
        yaw = np.load(files[1], allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise InputError(f"cannot read the annotations ({exc.__class__.__name__})", folder) from None
    if pts.ndim != 3 or pts.shape[1:] != (2, 68) or yaw.shape != (pts.shape[0],):
        raise InputError(f"unexpected shapes {pts.shape} / {yaw.shape} (expected (N, 2, 68) / (N,))", folder)
    P = np.transpose(pts, (0, 2, 1)).astype(np.float64)
    keep = np.flatnonzero(np.abs(yaw) <= max_yaw)
    if part == "design":
        keep = keep[0::2]
    elif part == "held-out":
        keep = keep[1::2]
    return [AnnotatedFace(f"aflw2000-{i:04d}", P[i], (AFLW_SIZE, AFLW_SIZE), float(yaw[i])) for i in keep]


def pts_faces(paths) -> list[AnnotatedFace]:
    """68-point ``.pts`` annotations (files, or folders of them, sorted); an image of the same name gives the size."""
    from facegeom.io import image_size, read_pts

    files = []
    for p in map(Path, paths):
        if p.is_dir():
            files += sorted(x for x in p.iterdir() if x.suffix.lower() == ".pts")
        else:
            files.append(p)
    if not files:
        raise InputError("no .pts annotation given (files or folders of them)")
    out = []
    for f in files:
        uv = read_pts(f)
        if uv.shape[0] != 68:
            raise InputError(f"{uv.shape[0]} points: the photo benchmark needs the 68-point convention", f)
        size = None
        for suf in IMAGE_SUFFIXES:
            for img in (f.with_suffix(suf), f.with_suffix(suf.upper())):
                if img.is_file():
                    size = image_size(img)
                    break
            if size is not None:
                break
        out.append(AnnotatedFace(f.stem, uv, size))
    return out


def folds(protocol: str) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(fitted rows, predicted rows)`` of the 68 points for each fold of ``protocol``."""
    if protocol == "split":
        return [(np.array(FIT_LANDMARKS_23), np.array(EVAL_LANDMARKS_26))]
    if protocol == "leave-4-out":
        out = []
        for j in range(17):
            held = np.array([j, j + 17, j + 34, j + 51])
            out.append((np.setdiff1d(np.arange(68), held), held))
        return out
    raise InputError(f"protocol must be one of {', '.join(PROTOCOLS)}, got {protocol!r}")


def _score(face, pred_rows, pred) -> float:
    return float(np.sqrt(((pred - face.points[pred_rows]) ** 2).sum(axis=1).mean()) / face.inner_eye())


def _fit_face(face, model, rig, lm, specs, identity_fitter, protocol) -> dict:
    """Per route: ``(predictions (68, 2), seconds, converged or None)``, or the error that stopped it."""
    cam = face.camera()
    acc: dict = {}
    points = to_model_convention(face.points)  # as `facegeom fit PHOTO.pts` reads a 68-point annotation
    for fit_rows, held in folds(protocol):
        ids = lm[fit_rows]
        tg = LandmarkTarget(points[fit_rows], ids, cam)
        fitted = {}

        def joint():
            r = identity_fitter.fit(model, tg)
            fitted["rig"] = r.rig
            return r.cameras[0].project(r.vertices(0)[lm[held]]), bool(r.info.get("converged", True))

        _route(acc, POSE_ONLY, held, lambda: _pose_only(rig, tg, lm[held]))
        for s in specs:
            _route(acc, s.label, held, lambda s=s: _expression(s, rig, tg, lm[held]))
        _route(acc, JOINT, held, joint)
        for s in specs:
            route = f"{s.label} on the fitted identity"
            if "rig" in fitted:
                _route(acc, route, held, lambda s=s: _expression(s, fitted["rig"], tg, lm[held]))
            else:
                acc[route] = acc[JOINT]
    return acc


def _route(acc, route, held, fn):
    """Run one fold of ``route`` into ``acc`` (a failure sticks: the face counts as failed for the route)."""
    if isinstance(acc.get(route), Exception):
        return
    t0 = time.perf_counter()
    try:
        P, conv = fn()
    except FacegeomError as exc:
        acc[route] = exc
        return
    secs = time.perf_counter() - t0
    A, total, c = acc.get(route) or (np.full((68, 2), np.nan), 0.0, None)
    A[held] = P
    acc[route] = (A, total + secs, conv if c is None else (c and conv if conv is not None else c))


def _pose_only(rig, tg, held_ids):
    from facegeom.methods.fitting import fit_with_pose

    _, cam = fit_with_pose(rig, tg, lambda camera: np.zeros(rig.n_shapes), alternations=0)
    return cam.project(rig.neutral[held_ids]), None


def _expression(spec, rig, tg, held_ids):
    r = spec.build("fitters").fit(rig, tg)
    cam = r.info["camera"]
    conv = r.info.get("converged")
    return cam.project(r.vertices[held_ids]), (None if conv is None else bool(conv))


def run(model, faces, specs, protocol: str = "split", out=None, label: str = "", echo=print,
        progress: bool = True, identity_fitter=None) -> dict:
    """Score every route on ``faces`` -> ``{route: {"errors": (N,), "seconds": (N,), "converged": ..., ...}}``.

    Also writes ``photos.csv`` (one row per face and route) and
    ``photos-summary.md`` into ``out`` when given.
    """
    from facegeom.bench.common import progress_bar
    from facegeom.methods.identity import IdentityFitter

    folds(protocol)  # checks the name
    if not faces:
        raise InputError("no annotated faces to score")
    rig = BlendshapeRig.from_face_model(model)
    lm = np.asarray(model.landmarks, dtype=np.int64)
    ident = identity_fitter or IdentityFitter()
    routes = [POSE_ONLY] + [s.label for s in specs] + [JOINT] + [f"{s.label} on the fitted identity" for s in specs]
    res = {r: {"errors": [], "seconds": [], "converged": [], "failures": 0, "messages": []} for r in routes}
    csv_rows = []
    for face in progress_bar(faces, f"photos ({protocol})", progress, unit="face"):
        got = _fit_face(face, model, rig, lm, specs, ident, protocol)
        for route in routes:
            g = got.get(route)
            if isinstance(g, Exception) or g is None:
                res[route]["failures"] += 1
                res[route]["messages"].append(f"{face.name}: {g}")
                csv_rows.append({"face": face.name, "route": route, "error": "", "ms": "", "converged": "",
                                 "failure": str(g)})
                continue
            P, secs, conv = g
            P = to_annotation_convention(P, face.points)  # predicted jaw points where annotators put them
            rows = np.flatnonzero(np.isfinite(P[:, 0]))
            e = _score(face, rows, P[rows])
            res[route]["errors"].append(e)
            res[route]["seconds"].append(secs)
            res[route]["converged"].append(conv)
            csv_rows.append({"face": face.name, "route": route, "error": e, "ms": 1000 * secs,
                             "converged": "" if conv is None else int(conv), "failure": ""})
    for r in res.values():
        r["errors"] = np.array(r["errors"])
        r["seconds"] = np.array(r["seconds"])
    table = summary_table(res, [s.label for s in specs])
    if out is not None:
        rep = Report(out, "photos", echo)
        rep.csv(csv_rows)
        rep.summary(table, label)
    else:
        echo(table)
    return res


def summary_table(res, labels) -> str:
    """Mean / median error per route, against the best baseline of the same rig, converged share, failures, time."""
    def best(suffix):
        vals = [res[f"{m}{suffix}"]["errors"].mean() for m in labels
                if m.split(":")[0] not in ("sem-ls", "sem") and res[f"{m}{suffix}"]["errors"].size]
        return min(vals) if vals else np.nan
    base = {"": best(""), " on the fitted identity": best(" on the fitted identity")}
    rows = []
    for route, r in res.items():
        e = r["errors"]
        suffix = " on the fitted identity" if route.endswith(" on the fitted identity") or route == JOINT else ""
        conv = [c for c in r["converged"] if c is not None]
        rows.append([route, f"{100 * e.mean():.2f} %" if e.size else "-",
                     f"{100 * np.median(e):.2f} %" if e.size else "-",
                     f"{e.mean() / base[suffix]:.2f}x" if e.size and np.isfinite(base[suffix]) else "-",
                     f"{100 * np.mean(conv):.1f} %" if conv else "-", str(r["failures"]),
                     f"{1000 * np.median(r['seconds']):.0f}" if r["seconds"].size else "-"])
    return format_table(["route", "held-out error (mean)", "median", "vs best baseline (same rig)", "converged",
                         "failures", "ms / photo (median)"], rows)


def jaw_offsets(model, faces, echo=print) -> np.ndarray:
    """Where annotators put the jaw contour against the model's outline -> ``(N, 17, 2)`` (inter-ocular units).

    Each face's identity, pose and expression are fitted jointly to its 51
    inner points; the difference between each annotated contour point and the
    fitted face's outline (the contour vertex farthest out in the view, the
    chin's fixed) is expressed in the annotation's face frame
    (:data:`~facegeom.model.landmarks.JAW_CONVENTION`). Also echoes the mean
    and spread per point, and the mean made left-right symmetric.
    """
    from facegeom.constants import FACE_AREA
    from facegeom.methods.identity import IdentityFitter

    lm = np.asarray(model.landmarks, dtype=np.int64)
    cands = contour_candidates(np.asarray(model.neutral, dtype=np.float64), lm, region=np.arange(FACE_AREA))
    fitter = IdentityFitter()
    out = []
    for face in faces:
        r = fitter.fit(model, LandmarkTarget(face.points[17:], lm[17:], face.camera()))
        V, cam = r.vertices(0), r.cameras[0]
        seen = silhouette_vertices(lambda i: cam.project(V[i]), lm, cands, float(cam.project(V[lm[[30]]])[0, 0]))
        d = face.points[:17] - cam.project(V[seen[:17]])
        ex = face.points[45] - face.points[36]
        x = ex / np.linalg.norm(ex)
        out.append(np.c_[d @ x, d @ np.array([-x[1], x[0]])] / face.inner_eye())
    D = np.array(out)
    m, sd = D.mean(axis=0), D.std(axis=0)
    sym = np.c_[(m[:, 0] - m[::-1, 0]) / 2, (m[:, 1] + m[::-1, 1]) / 2]
    rows = [[j, f"{m[j, 0]:+.3f}", f"{m[j, 1]:+.3f}", f"{sd[j, 0]:.3f}", f"{sd[j, 1]:.3f}", f"({sym[j, 0]:+.2f}, "
             f"{sym[j, 1]:+.2f})"] for j in range(17)]
    echo(format_table(["jaw point", "dx mean", "dy mean", "dx sd", "dy sd", "symmetric (dx, dy)"], rows))
    echo(f"{len(D)} faces; inter-ocular units in the annotation's face frame (x: eye line, y: towards the chin)")
    return D
