"""Example inputs for every task, made from the face data: what ``facegeom data examples DIR`` writes.

Every file is built from the ICT face model the user has (no take, scan or
photo from elsewhere) with a fixed seed, so the same face data always gives
the same files. One person (a random ICT identity, "the person") plays in
most of them:

- ``face.obj``: the person's neutral face; ``target.obj`` the same face with
  a smile; ``markers.csv`` the 80 ``ict80`` markers of that smile (``drive``);
- ``landmarks.csv`` / ``photo.pts`` (+ a blank ``photo.png`` of the photo's
  size) / ``neutral_front.csv`` / ``neutral_side.csv``: the person seen by
  cameras (``fit``, ``identity``);
- ``face.jpg``: a rendered photograph of the person smiling; ``clip.mp4``: a
  rendered video of the person performing ``take.csv`` (``fit``, ``detect``,
  ``track``; drawn off-screen by polyscope);
- ``scan.ply``: a partial, noisy point cloud of the smile in millimetres,
  turned and moved as a scanner would leave it (``fit``, ``identity``);
- ``scan_mesh.obj``: the neutral face with defects (split vertices, a
  duplicate face, a stray piece) for ``clean``;
- ``take.csv``: a Live Link Face take (ARKit weights) of named expressions
  (``animate``, ``view``, ``bench``); ``capture.c3d``: the person performing
  it as an 80-marker optical capture in mm with head motion (``solve``);
- ``actor.csv`` / ``labels.csv``: another identity's markers performing named
  expressions and a stylised character's markers at a few of those frames
  (``retarget``);
- ``job.toml`` with ``job/landmarks/*.csv`` and ``job/truth/*.json``: a batch
  fit job that runs from the folder.

:func:`make_examples` builds the arrays, :func:`write_examples` writes them
all or none (:func:`facegeom.io.files.all_or_nothing`) with a ``README.txt``
listing each file, its units and the command that uses it.
"""
from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from facegeom.constants import CM_TO_MM, FACE_AREA
from facegeom.errors import InputError
from facegeom.io.c3d import write_c3d
from facegeom.io.files import all_or_nothing
from facegeom.io.fitfiles import write_weights
from facegeom.io.markers import write_markers
from facegeom.io.markerseq import write_marker_sequence
from facegeom.io.mesh import write_mesh
from facegeom.io.takes import ict_to_arkit, write_livelink_csv
from facegeom.model.camera import PinholeCamera, look_at_camera
from facegeom.model.expressions import named_expression, random_sparse_expression
from facegeom.model.landmarks import contour_candidates, silhouette_vertices
from facegeom.model.layouts import ict80
from facegeom.model.performance import make_character, make_sequence
from facegeom.model.rig import BlendshapeRig

__all__ = ["SEED", "CAMERA", "PHOTO_SIZE", "TAKE_FPS", "JOB_FITS", "ExampleFile", "Examples", "FILES",
           "make_examples", "write_examples", "check_folder", "readme_text", "example_paths",
           "existing_outputs"]

SEED = 7
"""The seed of every random choice (identities, noise, head motion, scan sampling)."""

CAMERA = {"focal": 1000.0, "cx": 320.0, "cy": 240.0, "width": 640, "height": 480}
"""The camera of ``landmarks.csv``, ``neutral_*.csv`` and the batch job's landmark files (pixels)."""

PHOTO_SIZE = (640, 480)
"""Width and height of ``photo.png``; ``photo.pts`` was seen with the camera ``--image photo.png`` implies."""

TAKE_FPS = 60.0
"""Frame rate of ``take.csv`` and ``capture.c3d``."""

TAKE_FRAMES = 120
CLIP_SIZE = (480, 360)
"""Width and height of ``clip.mp4``."""
ACTOR_FRAMES = 60
LABEL_FRAMES = (0, 12, 24, 35, 47, 59)
JOB_FITS = 8
SCAN_POINTS = 6000
NOISE_PX = 0.5  # landmark noise, pixels
NOISE_MM = 0.3  # scan and capture noise, mm

TAKE_EXPRESSIONS = ("happiness", "surprise", "blink", "jaw-open", "pucker")
ACTOR_EXPRESSIONS = ("happiness", "surprise", "pucker")


@dataclass(frozen=True)
class ExampleFile:
    """One entry of ``README.txt``: a file (or a group of files) and what it is for.

    Attributes
    ----------
    name : str
        The path in the folder (``job/landmarks/*.csv`` for a group).
    what : str
        What the file holds.
    units : str
        Its units.
    command : str
        A command that uses it, run from the folder.
    """

    name: str
    what: str
    units: str
    command: str


FILES: tuple[ExampleFile, ...] = (
    ExampleFile("face.obj", "the person's face mesh: one ICT identity's neutral face (triangles)", "cm",
                "facegeom drive face.obj markers.csv -o driven.ply"),
    ExampleFile("markers.csv", "80 markers (vertex_id,x,y,z; the ict80 layout) on face.obj, moved to a smile",
                "cm", "facegeom drive face.obj markers.csv -o driven.ply"),
    ExampleFile("target.obj", "the true smiling face the markers come from (a mesh in correspondence)", "cm",
                "facegeom fit target.obj --identity -o target.json --mesh-out target_fit.obj"),
    ExampleFile("landmarks.csv", "68 landmarks (vertex_id,u,v) of the person surprised, seen by a camera turned 15 "
                "degrees (0.5 px noise); camera: focal 1000 px, principal point (320, 240), 640 x 480 photo",
                "pixels", "facegeom fit landmarks.csv --focal 1000 --cx 320 --cy 240 -o landmarks.json"),
    ExampleFile("photo.pts", "an iBUG 68-point annotation of the person smiling, head turned about 20 degrees, "
                "the jaw contour on the face's outline (0.5 px noise)", "pixels, 1-based",
                "facegeom fit photo.pts --image photo.png --identity -o photo.json"),
    ExampleFile("photo.png", "a blank 640 x 480 image: the size of the photo of photo.pts (--image takes the "
                "camera from it: focal 640 px, centre (319.5, 239.5))", "pixels",
                "facegeom fit photo.pts --image photo.png --identity -o photo.json"),
    ExampleFile("face.jpg", "a photograph of the person smiling, head turned 15 degrees (a render of the face "
                "model with painted brows and lips, eyeballs and a mouth; 640 x 480): its landmarks are found in it",
                "pixels", "facegeom fit face.jpg -o face_fit.json"),
    ExampleFile("clip.mp4", f"a video of the person performing take.csv ({TAKE_FRAMES} frames at {TAKE_FPS:g} fps, "
                f"{CLIP_SIZE[0]} x {CLIP_SIZE[1]}, H.264) with head motion and eye movements", "pixels",
                "facegeom track clip.mp4 -o clip.csv -o clip.npz --preview clip_preview.mp4"),
    ExampleFile("neutral_front.csv", "68 landmarks of the person's neutral face from the front (camera as "
                "landmarks.csv)", "pixels",
                "facegeom identity neutral_front.csv neutral_side.csv --focal 1000 --cx 320 --cy 240 -o person.npz"),
    ExampleFile("neutral_side.csv", "the same from 30 degrees to the side", "pixels",
                "facegeom identity neutral_front.csv neutral_side.csv --focal 1000 --cx 320 --cy 240 -o person.npz"),
    ExampleFile("scan.ply", f"a partial noisy point cloud of the smile ({SCAN_POINTS} points before a quarter of the "
                f"face's width is cut away, {NOISE_MM} mm noise), turned and moved", "mm",
                "facegeom fit scan.ply --kind points -o scan.json --mesh-out fitted.obj"),
    ExampleFile("scan_mesh.obj", "face.obj with defects: split (duplicate) vertices, a duplicate face and a small "
                "stray piece", "cm",
                "facegeom clean scan_mesh.obj clean.obj --largest-component --markers markers.csv "
                "--markers-out clean_markers.csv --map clean_map.csv --report clean_report.json"),
    ExampleFile("take.csv", f"a Live Link Face take of {TAKE_FRAMES} frames at {TAKE_FPS:g} fps: "
                f"{', '.join(TAKE_EXPRESSIONS)} one after the other", "ARKit weights 0-1",
                "facegeom animate --take take.csv -o anim_example.npz"),
    ExampleFile("capture.c3d", f"the person performing take.csv as an 80-marker optical capture (markers v<vertex "
                f"id>, ict80), with head motion, {NOISE_MM} mm noise and a few lost markers", "mm",
                "facegeom solve capture.c3d -o curves.npz"),
    ExampleFile("actor.csv", f"an actor's 80 markers (frame,marker,x,y,z) over {ACTOR_FRAMES} frames: "
                f"{', '.join(ACTOR_EXPRESSIONS)}", "cm",
                "facegeom retarget actor.csv labels.csv -o character.csv"),
    ExampleFile("labels.csv", f"a stylised character's markers (another identity) at frames "
                f"{', '.join(map(str, LABEL_FRAMES))} of actor.csv", "cm",
                "facegeom retarget actor.csv labels.csv -o character.csv"),
    ExampleFile("job.toml", "a batch job: sem-ls fits of the landmark files below (paths relative to the job file)",
                "", "facegeom batch job.toml"),
    ExampleFile("job/landmarks/*.csv", f"{JOB_FITS} landmark files (vertex_id,u,v) of the generic face with random "
                "sparse expressions under random head turns (camera as landmarks.csv)", "pixels",
                "facegeom batch job.toml"),
    ExampleFile("job/truth/*.json", "their true expression weights (the job's error metrics)", "weights 0-1",
                "facegeom batch job.toml"),
)
"""What ``README.txt`` lists, in its order."""


def example_paths() -> list[str]:
    """Every file :func:`write_examples` writes, relative to the folder (``README.txt`` last)."""
    out = []
    for f in FILES:
        if "*" in f.name:
            folder = f.name.rsplit("/", 1)[0]
            suffix = f.name.rsplit(".", 1)[1]
            out += [f"{folder}/{k:02d}.{suffix}" for k in range(1, JOB_FITS + 1)]
        else:
            out.append(f.name)
    return out + ["README.txt"]


@dataclass
class Examples:
    """The arrays and texts of every example file (nothing written yet).

    Attributes
    ----------
    meshes : dict of str to (V (n, 3), F (m, 3))
        ``face.obj``, ``target.obj``, ``scan_mesh.obj``.
    markers : (ids (80,), positions (80, 3))
        ``markers.csv``.
    landmark_csvs : dict of str to (ids (L,), uv (L, 2))
        ``landmarks.csv``, ``neutral_*.csv`` and the job's landmark files.
    pts : (68, 2) float
        ``photo.pts``, 0-based pixels (written 1-based).
    scan : (N, 3) float
        ``scan.ply``, mm.
    take : (T, 52) float, tuple of str
        ``take.csv``'s ARKit weights and names.
    capture : (T, 80, 3) float, tuple of str
        ``capture.c3d``'s marker positions (mm, NaN = lost) and names.
    sequences : dict of str to (positions (T, p, 3), frames (T,), names)
        ``actor.csv`` and ``labels.csv``.
    truths : dict of str to (B,) float
        The job's true weights by file name.
    names : tuple of str
        The rig's shape names (for the truth files).
    nose_tip : int
        The vertex of the nose tip (landmark 30), for ``crop``.
    scene : dict
        What ``face.jpg`` and ``clip.mp4`` are rendered from when written: the model, the person's identity, the
        take's ICT weights, the head's motion and the gaze.
    """

    meshes: dict = field(default_factory=dict)
    markers: tuple = ()
    landmark_csvs: dict = field(default_factory=dict)
    pts: np.ndarray | None = None
    scan: np.ndarray | None = None
    take: tuple = ()
    capture: tuple = ()
    sequences: dict = field(default_factory=dict)
    truths: dict = field(default_factory=dict)
    names: tuple = ()
    nose_tip: int = 0
    scene: dict = field(default_factory=dict)


def _rotation(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """Rotation about y (yaw), x (pitch), z (roll), degrees: ``Rz @ Rx @ Ry``."""
    a, b, c = np.deg2rad([yaw, pitch, roll])
    Ry = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    Rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    Rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    return Rz @ Rx @ Ry


def _performance(model, frames: int, names) -> np.ndarray:
    """Weights ``(frames, E)``: the named expressions one after the other, each rising and falling smoothly."""
    W = np.zeros((frames, model.n_expressions))
    t = np.arange(frames, dtype=np.float64)
    step = frames / len(names)
    width = 1.3 * step  # neighbours overlap a little
    for k, name in enumerate(names):
        x = (t - (k + 0.5) * step) / width
        env = np.where(np.abs(x) < 0.5, np.cos(np.pi * x) ** 2, 0.0)
        W += env[:, None] * model.expression_vector(named_expression(name))[None]
    return np.clip(W, 0.0, 1.0)


def _photo_landmarks(face, landmark_ids, camera, rng, candidates=None) -> np.ndarray:
    """The 68 landmarks of ``face`` seen by ``camera``, 0-based pixels, with noise; the jaw contour on the outline
    when ``candidates`` (:func:`contour_candidates`) are given."""
    ids = np.asarray(landmark_ids, dtype=np.int64)
    if candidates is not None:
        nose_u = camera.project(face[ids[[30]]])[0, 0]
        ids = silhouette_vertices(lambda i: camera.project(face[i]), ids, candidates, nose_u)
    return camera.project(face[ids]) + NOISE_PX * rng.standard_normal((ids.size, 2))


def _partial_scan(face, triangles, rng) -> np.ndarray:
    """Points sampled on the face area of ``face`` (cm), a quarter of its width cut away, noisy, in mm, moved."""
    F = triangles[(triangles < FACE_AREA).all(axis=1)]
    A, B, C = face[F[:, 0]], face[F[:, 1]], face[F[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(B - A, C - A), axis=1)
    pick = rng.choice(F.shape[0], SCAN_POINTS, p=area / area.sum())
    r1, r2 = rng.random((2, SCAN_POINTS))
    s = np.sqrt(r1)
    P = (1 - s)[:, None] * A[pick] + (s * (1 - r2))[:, None] * B[pick] + (s * r2)[:, None] * C[pick]
    x = face[:FACE_AREA, 0]
    cut = x.max() - 0.25 * (x.max() - x.min())  # the scanner did not see one side of the face
    P = P[P[:, 0] < cut] * CM_TO_MM
    P += NOISE_MM * rng.standard_normal(P.shape)
    R = _rotation(35.0, -10.0, 80.0)  # as a scanner's frame leaves a face: turned, on its side
    return P @ R.T + np.array([250.0, -120.0, 900.0])


def _scan_mesh(V, F, avoid, rng) -> tuple[np.ndarray, np.ndarray]:
    """``V, F`` with defects: 30 vertices split in two (half their faces on the copy), a duplicate face and a
    stray 4-triangle piece in front of the forehead. The original vertices keep their ids."""
    V, F = V.copy(), F.copy()
    n = V.shape[0]
    pool = np.setdiff1d(np.arange(FACE_AREA), avoid)
    split = rng.choice(pool, 30, replace=False)
    copies = []
    for k, v in enumerate(split):
        faces = np.flatnonzero((F == v).any(axis=1))
        moved = faces[: max(1, faces.size // 2)]
        F[moved] = np.where(F[moved] == v, n + k, F[moved])
        copies.append(V[v])
    V = np.r_[V, np.array(copies)]
    F = np.r_[F, F[:1]]  # a duplicate face
    top = V[:FACE_AREA][np.argmax(V[:FACE_AREA, 1])]
    c = top + np.array([0.0, -1.0, 2.0])  # a small piece floating 2 cm in front of the forehead
    ring = c + 0.4 * np.c_[np.cos(np.arange(4) * np.pi / 2), np.sin(np.arange(4) * np.pi / 2), np.zeros(4)]
    m = V.shape[0]
    V = np.r_[V, c[None], ring]
    F = np.r_[F, [[m, m + 1 + i, m + 1 + (i + 1) % 4] for i in range(4)]]
    return V, F


def _head_motion(T: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Smooth head rotations ``(T, 3, 3)`` (up to ~12 degrees) and translations ``(T, 3)`` (cm, up to ~2 cm)."""
    t = np.linspace(0.0, 1.0, T)
    freq = rng.uniform(0.5, 1.5, (6,))
    phase = rng.uniform(0.0, 2 * np.pi, (6,))
    wave = np.sin(2 * np.pi * freq[None] * t[:, None] + phase[None])
    angles = wave[:, :3] * np.array([12.0, 8.0, 5.0])
    R = np.stack([_rotation(*a) for a in angles])
    return R, wave[:, 3:] * np.array([2.0, 1.0, 1.5])


def make_examples(model, seed: int = SEED) -> Examples:
    """Build every example from the face model (nothing is written).

    Parameters
    ----------
    model : FaceModel
        The ICT face model (``n`` vertices in cm, ``E`` expressions, 68 landmarks).
    seed : int
        Seed of every random choice.

    Returns
    -------
    Examples
    """
    rng = np.random.default_rng([int(seed), 2718])
    ex = Examples(names=tuple(model.expression_names), nose_tip=int(model.landmarks[30]))
    person = model.random_identity(rng)
    neutral = model.identity_neutral(person)
    smile = model.face(identity=person, expression=named_expression("happiness", 0.9))
    ids = ict80(model)
    lm = np.asarray(model.landmarks, dtype=np.int64)
    ex.meshes["face.obj"] = (neutral, model.triangles)
    ex.meshes["target.obj"] = (smile, model.triangles)
    ex.markers = (ids, smile[ids])

    w, h = CAMERA["width"], CAMERA["height"]
    surprised = model.face(identity=person, expression=named_expression("surprise", 0.8))
    cam = look_at_camera(surprised, focal=CAMERA["focal"], image_size=(w, h), yaw=15.0, pitch=5.0)
    ex.landmark_csvs["landmarks.csv"] = (lm, _photo_landmarks(surprised, lm, cam, rng))
    for name, yaw in (("neutral_front.csv", 0.0), ("neutral_side.csv", 30.0)):
        cam = look_at_camera(neutral, focal=CAMERA["focal"], image_size=(w, h), yaw=yaw)
        ex.landmark_csvs[name] = (lm, _photo_landmarks(neutral, lm, cam, rng))

    # the photo: the camera `--image photo.png` implies (focal = the larger side, centre of the pixel grid)
    pw, ph = PHOTO_SIZE
    posed = look_at_camera(smile, focal=float(max(pw, ph)), image_size=(pw, ph), yaw=-20.0, pitch=-5.0)
    cam = PinholeCamera(float(max(pw, ph)), (pw - 1) / 2.0, (ph - 1) / 2.0, posed.R, posed.t)
    cands = contour_candidates(model.neutral, lm, region=np.arange(min(FACE_AREA, model.n_vertices)))
    ex.pts = _photo_landmarks(smile, lm, cam, rng, cands)

    ex.scan = _partial_scan(smile, model.triangles, rng)
    ex.meshes["scan_mesh.obj"] = _scan_mesh(neutral, model.triangles, ids, rng)

    W = _performance(model, TAKE_FRAMES, TAKE_EXPRESSIONS)
    ex.take = ict_to_arkit(W, model.expression_names)
    rig = BlendshapeRig.from_face_model(model, person)
    faces = rig.neutral[ids][None] + np.einsum("tb,bpi->tpi", W, rig.deltas[:, ids])
    R, t = _head_motion(TAKE_FRAMES, rng)
    X = np.einsum("tij,tpj->tpi", R, faces) + t[:, None] + np.array([0.0, 160.0, 0.0])  # a head 1.6 m up
    X = X * CM_TO_MM + NOISE_MM * rng.standard_normal(X.shape)
    X[rng.random(X.shape[:2]) < 0.01] = np.nan
    ex.capture = (X, tuple(f"v{i}" for i in ids))

    # the photograph and the video, rendered when written: the take's expressions, the capture's head motion
    t_s = np.arange(TAKE_FRAMES) / TAKE_FPS
    gaze = np.stack([0.25 * np.sin(2 * np.pi * 0.4 * t_s), 0.12 * np.sin(2 * np.pi * 0.3 * t_s + 1.0)], axis=1)
    ex.scene = {"model": model, "person": person, "weights": W, "rotations": R, "translations": t,
                "gaze": np.repeat(gaze[:, None], 2, axis=1), "smile": named_expression("happiness", 0.9)}

    Wa = _performance(model, ACTOR_FRAMES, ACTOR_EXPRESSIONS)
    seq = make_sequence(model, Wa, ids, actor_seed=int(seed), character=make_character(model, int(seed)))
    names = tuple(f"v{i}" for i in ids)
    frames = np.arange(ACTOR_FRAMES, dtype=np.int64)
    labelled = np.array(LABEL_FRAMES, dtype=np.int64)
    ex.sequences["actor.csv"] = (seq.source, frames, names)
    ex.sequences["labels.csv"] = (seq.target[labelled], labelled, names)

    generic = BlendshapeRig.from_face_model(model)
    for k in range(1, JOB_FITS + 1):
        wk = generic.weights_from_dict(random_sparse_expression(generic.names, rng, active=(2, 5)))
        face = generic.evaluate(wk)
        cam = look_at_camera(face, focal=CAMERA["focal"], image_size=(w, h), yaw=float(rng.uniform(-20, 20)),
                             pitch=float(rng.uniform(-10, 10)))
        ex.landmark_csvs[f"job/landmarks/{k:02d}.csv"] = (lm, _photo_landmarks(face, lm, cam, rng))
        ex.truths[f"job/truth/{k:02d}.json"] = wk
    return ex


JOB_TOML = """\
# A batch job: run it from this folder with `facegeom batch job.toml` (paths are relative to this file).
# sem-ls fits of every landmark file (vertex_id,u,v in pixels) on the generic ICT face, the head pose
# of each estimated from its landmarks; the results and batch-summary.csv (status, error against the
# true weights, time per input) go to job/fit. A rerun skips finished inputs.

operation = "fit"
method = "sem-ls"                       # any registered fitter: facegeom methods --kind fitters
inputs = "job/landmarks/*.csv"
output = "job/fit"
truth = "job/truth/{{stem}}.json"         # true weights per input -> error metrics in the summary

[shared]
kind = "landmarks"
focal = {focal}                          # the camera, pixels
cx = {cx}
cy = {cy}

[batch]
chunk = 4                               # landmark files per task
"""


def readme_text(ex: Examples | None = None) -> str:
    """The ``README.txt`` of the folder: every file, what it is, its units, a command that uses it."""
    lines = ["Example inputs for every facegeom task, made from your face data by `facegeom data examples`",
             "(fixed seed: the same face data gives the same files). Run the commands from this folder.",
             "Lengths: the ICT face is in centimetres; scan.ply and capture.c3d are in millimetres as scanners",
             "and capture systems write them (facegeom converts them). Markers named v<id> sit on vertex <id>.", ""]
    for f in FILES:
        units = f"  [{f.units}]" if f.units else ""
        lines += [f"{f.name}{units}", f"    {f.what}", f"    $ {f.command}", ""]
    if ex is not None and ex.scene.get("skipped"):
        lines += ["face.jpg and clip.mp4 were not written: rendering them needs an off-screen renderer (EGL:",
                  "apt install libegl1 libegl-mesa0 libgl1-mesa-dri) and PyAV (pip install 'facegeom[video]').", ""]
    nose = ex.nose_tip if ex is not None else "N"
    lines += ["More commands on these files are in the README's section \"Try it: every task on example inputs\",",
              f"e.g. the face cropped to 4 cm around the nose tip (vertex {nose}) and the capture solved to glTF:",
              f"    $ facegeom crop face.obj nose.obj --from-vertices {nose} --radius 4",
              "    $ facegeom solve capture.c3d -o curves.glb",
              "    $ facegeom view animate --input curves.glb --screenshot view_curves.png", ""]
    return "\n".join(lines)


def _write_pts(path: Path, points0: np.ndarray) -> None:
    """An iBUG ``.pts`` annotation of 0-based pixel points (written 1-based, as 300-W's are)."""
    rows = "".join(f"{x + 1.0:.3f} {y + 1.0:.3f}\n" for x, y in np.asarray(points0, dtype=np.float64))
    path.write_text(f"version: 1\nn_points: {len(points0)}\n{{\n{rows}}}\n", encoding="utf-8")


def _write_landmark_csv(path: Path, ids, uv) -> None:
    """A landmark CSV ``vertex_id,u,v`` (pixels)."""
    rows = "".join(f"{int(i)},{u:.4f},{v:.4f}\n" for i, (u, v) in zip(ids, np.asarray(uv, dtype=np.float64)))
    path.write_text("vertex_id,u,v\n" + rows, encoding="utf-8")


def _write_point_ply(path: Path, points) -> None:
    """A point cloud as a binary little-endian PLY of double ``x, y, z`` (no faces)."""
    P = np.ascontiguousarray(points, dtype="<f8")
    header = (f"ply\nformat binary_little_endian 1.0\ncomment facegeom example scan, millimetres\n"
              f"element vertex {P.shape[0]}\nproperty double x\nproperty double y\nproperty double z\nend_header\n")
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(P.tobytes())


def _write_blank_png(path: Path, width: int, height: int) -> None:
    """A uniform light-grey PNG of ``width x height`` pixels (matplotlib's writer, no figure)."""
    from matplotlib.image import imsave

    imsave(path, np.full((height, width), 0.88), cmap="gray", vmin=0.0, vmax=1.0, format="png",
           metadata={"Software": None})


def _scene_renderer(scene: dict, width: int, height: int):
    """The renderer, the person's painted skin and eyes for the example pictures (one renderer per size)."""
    from facegeom.pipelines.render import HAIR_TONES, SKIN_TONES, FaceRenderer, face_colours
    from facegeom.pipelines.video_clips import FaceProps

    model = scene["model"]
    key = ("renderer", width, height)
    if key not in scene:
        neutral = model.identity_neutral(scene["person"])
        scene[key] = (FaceRenderer(width, height), face_colours(model, neutral, SKIN_TONES[1], HAIR_TONES[1]),
                      FaceProps(model, scene["person"]))
    return scene[key]


def _place(model, V, width: int, height: int, fov: float = 50.0, fraction: float = 0.42):
    """A camera (vertical field of view ``fov`` degrees) at the distance where the face is ``fraction`` of the frame
    wide, looking at the face's landmarks' centre."""
    import math

    f = height / 2.0 / math.tan(math.radians(fov) / 2.0)
    L = V[np.asarray(model.landmarks)]
    width_cm = float(np.ptp(L[:, 0]))
    return f, L.mean(axis=0), f * width_cm / (fraction * width)


def _write_photo(path: Path, scene: dict) -> None:
    from PIL import Image

    model = scene["model"]
    w, h = PHOTO_SIZE
    renderer, colours, props = _scene_renderer(scene, w, h)
    V = model.face(identity=scene["person"], expression=scene["smile"])
    f, c, d = _place(model, V, w, h)
    R = _rotation(15.0, -4.0, 2.0)
    cam = renderer.camera_for(f).with_pose(R, -R @ c + np.array([0.0, 0.0, -d]))
    img = renderer.render(V, model.triangles, cam, color=colours, background=(0.42, 0.47, 0.52),
                          extra=props.meshes(V, np.array([[0.1, 0.05], [0.1, 0.05]])))
    Image.fromarray(img).save(path, format="JPEG", quality=92)


def _write_clip(path: Path, scene: dict) -> None:
    from facegeom.io.video import VideoWriter

    model = scene["model"]
    w, h = CLIP_SIZE
    renderer, colours, props = _scene_renderer(scene, w, h)
    neutral = model.identity_neutral(scene["person"])
    deltas = np.asarray(model.expression_deltas, dtype=np.float64)
    f, c, d = _place(model, neutral, w, h)
    camera = renderer.camera_for(f)
    say = scene.get("progress")
    T = len(scene["weights"])
    with VideoWriter(path, TAKE_FPS, w, h) as out:
        for k, W in enumerate(scene["weights"]):
            if say is not None and k % CLIP_PROGRESS_FRAMES == 0:
                say(f"  rendering the video clip.mp4: frame {k + 1} of {T}")
            V = neutral + np.tensordot(W, deltas, axes=1)
            R, t = scene["rotations"][k], scene["translations"][k]
            pose = camera.with_pose(R, -R @ c + t + np.array([0.0, 0.0, -d]))
            out.write(renderer.render(V, model.triangles, pose, color=colours, background=(0.42, 0.47, 0.52),
                                      extra=props.meshes(V, scene["gaze"][k])))


def _writers(ex: Examples) -> dict:
    """File name -> a function writing it to a given path."""
    out = {}
    for name, (V, F) in ex.meshes.items():
        out[name] = lambda p, V=V, F=F: write_mesh(p, V, F)
    out["markers.csv"] = lambda p: write_markers(p, *ex.markers)
    for name, (ids, uv) in ex.landmark_csvs.items():
        out[name] = lambda p, ids=ids, uv=uv: _write_landmark_csv(p, ids, uv)
    out["photo.pts"] = lambda p: _write_pts(p, ex.pts)
    out["photo.png"] = lambda p: _write_blank_png(p, *PHOTO_SIZE)
    out["face.jpg"] = lambda p: _write_photo(p, ex.scene)
    out["clip.mp4"] = lambda p: _write_clip(p, ex.scene)
    out["scan.ply"] = lambda p: _write_point_ply(p, ex.scan)
    out["take.csv"] = lambda p: write_livelink_csv(p, ex.take[0], ex.take[1], TAKE_FPS)
    out["capture.c3d"] = lambda p: write_c3d(p, ex.capture[0], ex.capture[1], fps=TAKE_FPS, unit="mm")
    for name, (P, frames, names) in ex.sequences.items():
        out[name] = lambda p, P=P, frames=frames, names=names: write_marker_sequence(p, P, frames, names)
    for name, w in ex.truths.items():
        out[name] = lambda p, w=w: write_weights(p, ex.names, w, {"source": "facegeom data examples"})
    out["job.toml"] = lambda p: p.write_text(JOB_TOML.format(**{k: repr(float(CAMERA[k])) for k in ("focal", "cx",
                                                                                                      "cy")}),
                                             encoding="utf-8")
    out["README.txt"] = lambda p: p.write_text(readme_text(ex), encoding="utf-8")
    return out


CLIP_PROGRESS_FRAMES = 30  # write_examples(progress=...): a line every this many frames of the rendered video
PICTURES = ("face.jpg", "clip.mp4")
"""The example files rendered by polyscope off-screen (skipped where no renderer starts)."""


def pictures_possible() -> bool:
    """Whether the example photograph and video can be rendered here (an off-screen renderer and PyAV)."""
    import importlib.util

    if importlib.util.find_spec("av") is None:
        return False
    from facegeom.pipelines.render import FaceRenderer

    try:
        FaceRenderer(*CLIP_SIZE)
    except InputError:
        return False
    return True


def existing_outputs(folder: str | os.PathLike) -> list[str]:
    """The example files already in ``folder`` (names relative to it), in :func:`example_paths` order."""
    folder = Path(folder)
    return [name for name in example_paths() if os.path.lexists(folder / name)]


def check_folder(folder: str | os.PathLike, force: bool = False) -> Path:
    """Refuse ``folder`` before any work: a file (or below one), a folder where a file goes, or (unless
    ``force``) example files already there.

    Returns
    -------
    Path
        ``folder``.

    Raises
    ------
    InputError
        Naming ``folder`` (and the first example files found there).
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise InputError("is a file, not a folder: give a folder for the examples", folder)
    for parent in folder.parents:
        if parent.exists() and not parent.is_dir():
            raise InputError(f"cannot make this folder: {parent} is a file", folder)
    for name in example_paths():  # a folder in the way of a file cannot be overwritten, even with force
        if (folder / name).is_dir():
            raise InputError(f"{name} is a folder here; the examples need that name for a file", folder)
    if not force:
        there = existing_outputs(folder)
        if there:
            shown = ", ".join(there[:3]) + (f" and {len(there) - 3} more" if len(there) > 3 else "")
            raise InputError(f"already holds example files ({shown}); pass force=True to overwrite them", folder)
    return folder


def write_examples(model, folder: str | os.PathLike, force: bool = False, seed: int = SEED,
                   progress=None) -> list[Path]:
    """Write every example file into ``folder``: all of them or, on any error, none.

    Parameters
    ----------
    model : FaceModel
        The ICT face model.
    folder : str or PathLike
        The folder; created (with its parents) when missing.
    force : bool
        Overwrite example files already there (other files are never touched).
    seed : int
        Seed of every random choice.
    progress : callable, optional
        Called with a line as the rendered pictures are made (the photograph, every
        :data:`CLIP_PROGRESS_FRAMES` frames of the video: the slow part, several seconds).

    Returns
    -------
    list of Path
        The files written, in :func:`example_paths` order.

    Raises
    ------
    InputError
        ``folder`` is a file (or below one), or already holds example files
        and ``force`` is False (naming the first few).
    """
    folder = check_folder(folder, force)
    names = example_paths()
    ex = make_examples(model, seed)
    ex.scene["progress"] = progress
    writers = _writers(ex)
    if not pictures_possible():  # no off-screen renderer here: everything else, and a line in README.txt says so
        names = [n for n in names if n not in PICTURES]
        ex.scene["skipped"] = True
    missing = sorted(set(names) - set(writers))
    if missing:  # pragma: no cover - FILES and the writers are kept in step
        raise RuntimeError(f"no writer for {missing}")
    created: list[Path] = []
    try:
        for d in sorted({(folder / n).parent for n in names}, key=lambda d: len(d.parts)):
            for q in [*reversed(d.parents), d]:  # outermost first
                if not q.exists():
                    q.mkdir()
                    created.append(q)
        paths = [folder / n for n in names]
        with all_or_nothing(paths) as tmps:
            for name, tmp in zip(names, tmps):
                writers[name](Path(tmp))
    except BaseException:
        for p in reversed(created):  # only what was made here, innermost first, and only if empty
            with contextlib.suppress(OSError):
                os.rmdir(p)
        raise
    return paths

