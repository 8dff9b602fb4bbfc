"""Model objects from user files: the rig to fit and a fitting target read from disk.

The files are read by :mod:`facegeom.io` (:mod:`facegeom.io.mesh`,
:mod:`facegeom.io.fitfiles`); this module turns them into a
:class:`~facegeom.model.rig.BlendshapeRig` and a target of
:mod:`facegeom.model.targets`, as ``facegeom fit`` does.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.model.landmarks import SIDE_CONTOUR, to_model_convention

__all__ = ['face_template', 'load_rig', 'photo_camera', 'pts_vertex_ids', 'read_fit_target', 'rig_note', 'scan_scale']


#: scene formats of animation tools that a rig may come in but facegeom does not read (their own exporters
#: write glTF or USD with the blend shapes): named in the refusal instead of "not an npz"
SCENE_FORMATS_NOT_READ = {".fbx": "FBX", ".blend": "Blender", ".ma": "Maya", ".mb": "Maya", ".max": "3ds Max",
                          ".c4d": "Cinema 4D", ".abc": "Alembic", ".dae": "COLLADA"}


def load_rig(rig_path=None, face_model=None, *, neutral: str | None = None, names=None, units: str = "auto",
             up: str = "auto", notes: list | None = None):
    """The rig of ``facegeom fit`` / ``solve`` / ``animate``, from wherever it comes, in facegeom's frame.

    Parameters
    ----------
    rig_path : str, path or None
        A folder of OBJs (a neutral and one OBJ per shape, the shapes named by
        file stem; the neutral found by :func:`~facegeom.model.rig.find_neutral`),
        a glTF file (``.glb`` / ``.gltf``: every morphed mesh of its scene,
        :func:`facegeom.io.gltf.read_gltf_rig`; its parts are kept as the rig's
        ``parts``), or an ``.npz`` (:meth:`BlendshapeRig.save_npz`; any other
        file is read as one). ``None``: the ICT generic face of
        ``face_model()`` (a callable returning a
        :class:`~facegeom.model.face.FaceModel`) with its 53 expressions.
    neutral : str, optional
        The neutral's file stem in an OBJ folder (``Neutral`` or ``Neutral.obj``).
    names : str, path or NameMapping, optional
        A mapping CSV ``rig_shape,source_shape,gain``
        (:func:`facegeom.io.shape_names.read_name_mapping`): how ICT / ARKit /
        other names' weights drive the rig's shapes. The rig keeps its own shape
        names; the mapping is kept as its ``name_map`` and used wherever weights
        cross names (:meth:`BlendshapeRig.map_from`, :meth:`BlendshapeRig.map_to`).
    units : {"auto", "mm", "cm", "m"}
        The rig's length unit; ``auto``: what the file states (glTF: m;
        facegeom's npz: cm), else found from its size (:mod:`facegeom.model.units`).
    up : {"auto", "y", "z"}
        The rig's up axis; ``auto``: glTF's Y, else found from where its
        blendshapes move the face (:mod:`facegeom.model.units`).
    notes : list, optional
        Receives one line saying what was found (shapes, the neutral, units,
        up axis, naming convention, unmapped shapes by name); nothing for the
        ICT face without a mapping.

    Returns
    -------
    BlendshapeRig
        In cm with Y up and the face along +Z; ``rig.frame`` tells the rig's own
        units and axes (to write results back in them).

    Raises
    ------
    InputError
        One line naming the file: a missing rig, no neutral or two candidates
        in a folder (its OBJ files listed), shapes with another vertex count,
        an unreadable file, a mapping row naming no shape of the rig (the
        mapping file and line), ``neutral`` / ``units`` / ``up`` without a rig
        file, a bad ``units`` or ``up``.
    """
    from facegeom.io.shape_names import read_name_mapping
    from facegeom.model.rig import BlendshapeRig, find_neutral
    from facegeom.model.units import rig_frame

    name_map = None if names is None else (names if not isinstance(names, (str, os.PathLike))
                                           else read_name_mapping(names))
    if rig_path is None:
        given = [a for a, v in (("neutral=NAME", neutral is not None), ("units=mm|cm|m", str(units) != "auto"),
                                ("up=y|z", str(up) != "auto")) if v]
        if given:
            raise InputError(f"{' and '.join(given)} describe{'s' if len(given) == 1 else ''} a rig file or folder "
                             "(rig_path=), and none was given: the ICT face needs none of them")
        rig = BlendshapeRig.from_face_model(face_model())
        if name_map is not None:
            rig = rig.with_name_map(name_map)
            if notes is not None:
                notes.append(rig_note(rig, None))
        return rig
    rp = Path(rig_path)
    if not rp.exists():
        raise InputError("rig not found", rp)
    try:  # numpy's MemoryError (a rig too large for the memory left) is one line naming the rig, anywhere here
        stated_units = stated_up = None
        what = ""
        if rp.is_dir():
            neutral_path = find_neutral(rp, neutral)
            raw = BlendshapeRig.from_obj_folder(rp, neutral_path.stem)
            what = f"neutral {neutral_path.name}"
        else:
            if neutral is not None:
                raise InputError("neutral=NAME names the neutral OBJ of a rig folder; this rig is a file", rp)
            if rp.suffix.lower() in (".glb", ".gltf"):
                raw, stated_units, stated_up = _gltf_rig(rp)
            elif rp.suffix.lower() in (".usd", ".usda", ".usdc", ".usdz"):
                raw, stated_units, stated_up = _usd_rig(rp)
            elif rp.suffix.lower() in SCENE_FORMATS_NOT_READ:
                raise InputError(f"{SCENE_FORMATS_NOT_READ[rp.suffix.lower()]} files are not read as rigs; export the "
                                 "face with its blend shapes as glTF (.glb), USD (.usd*) or a folder of OBJs", rp)
            else:
                raw, stated_units, stated_up = BlendshapeRig.read_npz(rp)
            if raw.parts:
                what = (f"{len(raw.parts)} part{'s' if len(raw.parts) != 1 else ''} "
                        f"({', '.join(p.name for p in raw.parts)})")
        if name_map is not None:
            raw = raw.with_name_map(name_map)
        try:
            frame = rig_frame(raw.neutral, raw.triangles, raw.deltas, units, up, stated_units, stated_up)
        except InputError as exc:
            raise InputError(exc.reason, rp) from None
        rig = raw.in_frame(frame)
    except MemoryError as exc:
        raise InputError(f"not enough memory to load the rig ({str(exc) or 'MemoryError'})", rp) from None
    if notes is not None:
        notes.append(rig_note(rig, rp.name, what))
    return rig


def _gltf_rig(path: Path):
    """A glTF file's rig as stored -> ``(rig, units, up)`` (what the file states: glTF's metres and Y-up)."""
    from facegeom.io.gltf import read_gltf_rig
    from facegeom.model.rig import BlendshapeRig

    g = read_gltf_rig(path)
    try:
        rig = BlendshapeRig(g.neutral, g.deltas, g.names, g.faces, None, parts=g.parts)
    except InputError as exc:
        raise InputError(exc.reason, path) from None
    up = str(g.up_axis).lstrip("+").lower()
    return rig, g.units, up if up in ("y", "z") else None


def _usd_rig(path: Path):
    """A USD file's rig (its mesh's points and blend shapes) -> ``(rig, units, up)`` as the stage states them."""
    from facegeom.io.usd import read_usd_rig, unit_name
    from facegeom.model.rig import BlendshapeRig

    u = read_usd_rig(path)
    if u.deltas.shape[0] == 0:
        raise InputError("the USD mesh has no blend shapes: not a rig (as a head to rig, give it to "
                         "`facegeom transfer`)", path)
    try:
        rig = BlendshapeRig(u.neutral, u.deltas, u.names, u.faces, None)
    except InputError as exc:
        raise InputError(exc.reason, path) from None
    return rig, unit_name(u.meters_per_unit), u.up_axis.lower()


def rig_note(rig, name: str | None, what: str = "") -> str:
    """One line on a loaded rig (``name``: its file; None: the ICT face): shapes, ``what`` (its neutral, parts),
    units and up axis, naming convention, and by name the shapes no ICT expression drives and the ICT expressions
    it lacks (what solve, fit and animate speak)."""
    from facegeom.io.shape_names import ICT_NAMES

    m = rig.map_from(ICT_NAMES)
    label = "the ICT face" if name is None else f"rig {name}"
    parts = [f"{label}: {rig.n_shapes} shapes, {rig.n_vertices} vertices" + (f", {what}" if what else "")]
    if rig.frame is not None and name is not None:
        parts.append(rig.frame.describe())
    parts.append(f"names: {m.rig_convention}")
    if rig.name_map is not None:
        k = len(m.from_mapping)
        parts.append(f"{k} shape{'' if k == 1 else 's'} mapped by {rig.name_map.name}")
        if m.unresolved:
            parts.append(f"rows of {rig.name_map.name} naming no ICT or ARKit shape: "
                         + ", ".join(f"{s} (line {ln})" for s, ln in m.unresolved))
    if m.is_empty:
        parts.append("no shape has an ICT or ARKit name: results keep the rig's names (a mapping file, "
                     "names=MAP.csv, maps them)")
        return "; ".join(parts)
    unmatched = [n for n in m.unmapped_rig if n not in set(m.ambiguous)]
    if unmatched:
        parts.append(f"its shapes no ICT expression drives: {', '.join(unmatched)}")
    if m.ambiguous:  # two spellings of one shape (ARKit's and SRanipal's): one driven, the others listed
        parts.append(m.ambiguity_note())
    if m.unmapped_source:
        parts.append(f"ICT expressions it lacks: {', '.join(m.unmapped_source)}")
    return "; ".join(parts)


def read_fit_target(path: str | os.PathLike, rig, kind: str = "auto", focal=None, cx=None, cy=None,
                    scale="auto", notes: list | None = None):
    """Read a fitting target for ``rig`` as ``facegeom fit`` does -> ``(kind, target)``.

    ``kind`` ``auto``: ``.csv`` = landmarks (``vertex_id,u,v``), ``.pts`` =
    landmarks of the 68-point iBUG convention (:func:`pts_vertex_ids`), a mesh
    file with the rig's vertex count = mesh, anything else = a point cloud.
    Landmarks need the camera intrinsics ``focal, cx, cy`` (pixels). A ``.pts``
    annotation's jaw-contour points are moved from where annotators put
    them to where the model's contour vertices are
    (:func:`~facegeom.model.landmarks.to_model_convention`) when it has the
    68 points of that convention, and otherwise marked as on the face's
    outline (``LandmarkTarget.outline``: the identity fit lets them follow
    the outline in the view); a CSV's rows are the projections of their
    vertices.

    ``scale``: meshes and point clouds are multiplied by it into the rig's
    units; ``"auto"`` (default) = the power of ten that makes the scan the
    size of the rig's face (:func:`scan_scale`: a scan in mm for a rig in cm
    gets 0.1; one in the rig's units 1). A line saying what was done is
    appended to ``notes`` (a list) when the factor is not 1.
    """
    from facegeom.io import MESH_FORMATS, read_mesh
    from facegeom.io.fitfiles import TARGET_KINDS, read_landmarks, read_point_cloud, read_pts
    from facegeom.model.camera import PinholeCamera
    from facegeom.model.targets import LandmarkTarget, MeshTarget, PointCloudTarget

    if kind not in TARGET_KINDS:
        raise InputError(f"unknown target kind {kind!r}; choose one of {', '.join(TARGET_KINDS)}")
    tp = Path(path)
    from facegeom.io.images import IMAGE_SUFFIXES

    photo = tp.suffix.lower() in IMAGE_SUFFIXES
    if kind == "auto":
        if tp.suffix.lower() in (".csv", ".pts") or photo:
            kind = "landmarks"
        elif tp.suffix.lower() in MESH_FORMATS:
            from facegeom.io.formats import read_mesh_data

            data = read_mesh_data(tp)  # a malformed file is refused here, as every other command refuses it
            if data.n_faces == 0:  # vertices only: a point cloud
                kind = "points"
            else:
                V, _ = read_mesh(tp)
                kind = "mesh" if V.shape[0] == rig.n_vertices else "points"
        else:
            kind = "points"
    if kind == "landmarks":
        if focal is None or cx is None or cy is None:
            raise InputError("landmark targets need the camera: focal, cx and cy (pixels), or the photo they were "
                             "marked on to take them from", tp)
        outline = None
        if photo or tp.suffix.lower() == ".pts":
            uv = photo_landmarks(tp, notes) if photo else read_pts(tp)
            ids = pts_vertex_ids(rig, uv.shape[0], tp)
            outline = np.isin(ids, np.asarray(rig.landmark_ids)[list(SIDE_CONTOUR)])
            if uv.shape[0] == 68:  # the annotators' jaw contour, moved to the model's (JAW_CONVENTION)
                uv = to_model_convention(uv)
                outline = None  # now where the model's contour vertices are: no outline to follow
                if notes is not None and not photo:
                    notes.append(f"{tp.name}: jaw contour moved from where annotators mark it to the model's "
                                 f"(up 0.07-0.35 and in 0.1-0.2 inter-ocular distances)")
        else:
            ids, uv = read_landmarks(tp)
        if ids.max() >= rig.n_vertices:
            raise InputError(f"vertex_id {int(ids.max())} is out of range: the rig has {rig.n_vertices} vertices", tp)
        check_photo_landmarks(uv, cx, cy, tp)
        tgt = LandmarkTarget(uv, ids, PinholeCamera(focal, cx, cy), outline)
    elif kind == "mesh":
        V, _ = read_mesh(tp)
        if V.shape[0] != rig.n_vertices:
            raise InputError(f"the mesh has {V.shape[0]} vertices but the rig {rig.n_vertices}; use kind='points' "
                             f"for a scan without correspondence", tp)
        tgt = MeshTarget(V * _factor(V, rig, scale, tp, notes))
    else:
        P = read_point_cloud(tp)
        tgt = PointCloudTarget(P * _factor(P, rig, scale, tp, notes))
    return kind, tgt


def photo_landmarks(path: str | os.PathLike, notes: list | None = None) -> np.ndarray:
    """The 68 landmarks ``(68, 2)`` (0-based pixels, the annotators' convention) of the largest face in a photo.

    The photo is read as it is shown (EXIF orientation applied) and its faces found by
    :class:`facegeom.vision.faces.FaceFinder`; a line for ``notes`` says what was found.

    Raises
    ------
    InputError
        Not an image, or no face in it.
    """
    from facegeom.io.images import read_image
    from facegeom.vision.faces import FaceFinder

    tp = Path(path)
    faces = FaceFinder(iris=False).find(read_image(tp), all_faces=True)
    if not faces:
        raise InputError("no face found in the photo", tp)
    face = faces[0]
    if notes is not None:
        more = f"; {len(faces) - 1} smaller face{'s' if len(faces) > 2 else ''} ignored" if len(faces) > 1 else ""
        notes.append(f"{tp.name}: 68 landmarks found on a face {face.size:.0f} px between the outer eye corners "
                     f"(detector score {face.detection.score:.2f}){more}")
    return face.landmarks


#: Landmarks may lie this many photo sizes outside the photo (a face cut by the frame) before they are refused.
PHOTO_MARGIN = 1.0


def check_photo_landmarks(uv, cx, cy, path=None) -> None:
    """Refuse landmarks no photo of a face has, in one line naming the file.

    The photo is taken as ``[0, 2 cx] x [0, 2 cy]`` (the principal point at its
    centre, as :func:`photo_camera` puts it; not checked when ``cx`` or ``cy``
    is not positive). Refused: a landmark more than
    :data:`PHOTO_MARGIN` photo sizes outside it (a coordinate in another unit or
    from another image), and landmarks that all coincide or lie on one line
    (no face, no pose to estimate).
    """
    uv = np.asarray(uv, dtype=np.float64)
    w, h = 2.0 * float(cx), 2.0 * float(cy)
    out = np.zeros(len(uv), bool)
    if w > 0 and h > 0:  # a principal point at or left of the origin describes no photo to compare with
        out = (np.abs(uv[:, 0] - 0.5 * w) > (0.5 + PHOTO_MARGIN) * w) | \
              (np.abs(uv[:, 1] - 0.5 * h) > (0.5 + PHOTO_MARGIN) * h)
    if out.any():
        k = int(np.flatnonzero(out)[0])
        raise InputError(f"landmark {k + 1} at ({uv[k, 0]:.6g}, {uv[k, 1]:.6g}) px is far outside the "
                         f"{w:.0f} x {h:.0f} photo the camera describes: another unit, or another photo's "
                         f"coordinates?", path)
    if uv.shape[0] >= 2:
        sv = np.linalg.svd(uv - uv.mean(axis=0), compute_uv=False)
        if sv[0] <= 1e-9 * max(w, h, 1.0) or (sv.size > 1 and sv[1] <= 1e-3 * sv[0]):
            raise InputError("the landmarks all lie on one line (or at one point): no face to fit", path)


FILM_DIAGONAL_MM = 43.27  # a 35 mm film frame's diagonal (36 x 24 mm)


def photo_camera(focal, cx, cy, image) -> tuple[float, float, float, bool]:
    """Intrinsics completed from the photo the landmarks were marked on -> ``(focal, cx, cy, focal_assumed)``.

    ``cx, cy`` default to the photo's centre (``(width - 1) / 2``, ``(height - 1) / 2``,
    0-based pixels) and ``focal`` to what the photo's EXIF states (its 35 mm-equivalent
    focal length, which phones and cameras write: ``f * diagonal / 43.27 mm``), else to
    its larger side in pixels (a ~53 degree field of view; a focal length off by up to
    30 % costs little, the pose takes it up in the face's distance); ``focal_assumed``
    is True only in that last case. Given values are kept. ``image=None`` returns the
    values as they are.

    Raises
    ------
    InputError
        The photo cannot be read (:func:`facegeom.io.image_size`).
    """
    if image is None:
        return focal, cx, cy, False
    from facegeom.io import image_size
    from facegeom.io.images import focal_35mm

    w, h = image_size(image)
    assumed = False
    if focal is None:
        f35 = focal_35mm(image)
        if f35 is not None:
            focal = f35 * float(np.hypot(w, h)) / FILM_DIAGONAL_MM
        else:
            focal, assumed = float(max(w, h)), True
    return (focal, (w - 1) / 2.0 if cx is None else cx, (h - 1) / 2.0 if cy is None else cy, assumed)


def pts_vertex_ids(rig, count: int, path=None) -> np.ndarray:
    """The rig's vertex of every point of a ``.pts`` annotation of ``count`` points (the 68-point iBUG convention).

    68 points: the rig's 68 landmarks in order; 51: their inner points (17-67,
    no jaw contour); 49: the 49 inner points (also without the inner mouth
    corners 60 and 64), :data:`facegeom.model.landmarks.INNER_LANDMARKS_49`.

    Raises
    ------
    InputError
        The rig has no landmark table, or ``count`` is none of 68, 51, 49.
    """
    from facegeom.model.landmarks import INNER_LANDMARKS_49

    if rig.landmark_ids is None:
        raise InputError("the rig has no 68-landmark table to place a .pts annotation on; give a vertex_id,u,v CSV",
                         path)
    lm = np.asarray(rig.landmark_ids, dtype=np.int64)
    rows = {68: np.arange(68), 51: np.arange(17, 68), 49: np.array(INNER_LANDMARKS_49)}.get(int(count))
    if rows is None:
        raise InputError(f"a .pts annotation of {count} points: facegeom reads the 68-point iBUG convention (68 "
                         f"points, or its 51 or 49 inner ones)", path)
    return lm[rows]


def face_template(rig, vertices=None) -> np.ndarray:
    """The rig's face vertices ``(m, 3)``: the face area of ICT-topology rigs, every vertex of other rigs.

    ``vertices (n, ...)``: the same rows of any per-vertex array of the rig
    (a face, weights; default: its neutral).
    """
    from facegeom.constants import FACE_AREA, ICT_VERTICES

    V = rig.neutral if vertices is None else vertices
    return V[:FACE_AREA] if rig.n_vertices == ICT_VERTICES else V


def scan_scale(points, rig) -> float:
    """The power of ten that brings ``points (N, 3)`` to the size of the rig's face (:func:`face_template`)."""
    from facegeom.registration import units_factor

    return units_factor(points, face_template(rig))


def _factor(X, rig, scale, path, notes) -> float:
    if isinstance(scale, str):
        if scale != "auto":
            raise InputError(f"scale must be 'auto' or a positive number, got {scale!r}")
        try:
            f = scan_scale(X, rig)
        except InputError as exc:
            raise InputError(str(exc), path) from None
        if f != 1.0 and notes is not None:
            notes.append(f"{Path(path).name}: scaled by {f:g} into the rig's units (its size was {1 / f:g}x the "
                         f"rig face's)")
        return f
    f = float(scale)
    if not (f > 0 and f < float("inf")):
        raise InputError(f"scale must be a positive finite number, got {scale!r}")
    return f
