"""A performance played on the user's own character through the rig: weights by name, head and eyes carried over.

The industry route (``facegeom solve ... --character RIG``, ``facegeom animate
--take TAKE --character RIG``): the actor's weights -- a solve on the actor's
rig, or the ARKit weights of a Live Link take -- drive the character's rig
through the one name map (:meth:`~facegeom.model.rig.BlendshapeRig.map_from`:
ICT and ARKit names in any spelling, a mapping file's gains), with

- the head's motion carried over about the performance's mean pose
  (:func:`relative_motion`: the character stands where its own rig puts it,
  not where the actor stood in the capture volume), the translations scaled
  by the character's size over the actor's (the root mean square radius of
  the neutrals), so a character twice the actor's size moves twice as far;
- the eyes: a character rig's eye-look shapes are driven like any other (its
  eyes, when :mod:`facegeom.methods.pieces` made them, turn inside those
  shapes); the Live Link output gets eye rotation columns from the ARKit
  eye-look weights, as the app relates them
  (:func:`facegeom.io.takes.eye_rotations`), and head columns from the head
  rotations (:func:`facegeom.io.takes.head_angles`).

The result is a :class:`~facegeom.pipelines.solve.SolvedCapture` on the
character, written by the usual writers (``.glb``: the character's mesh, its
shapes and the animation; ``.csv``: a Live Link take; ``.npz``: curves).
Shapes of the character nothing drives, and actor shapes that drive nothing,
are named in the notes.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.io.markerseq import MarkerSequence
from facegeom.io.shape_names import ARKIT_NAMES
from facegeom.methods.marker_solve import MarkerSolve
from facegeom.pipelines.solve import SolvedCapture, take_fps

__all__ = ["onto_character", "take_onto_character", "size_ratio", "read_head", "stored_registration"]


def size_ratio(character, actor) -> float:
    """The character's size over the actor's: the ratio of their neutrals' root mean square radii (1 if unknown)."""
    if actor is None:
        return 1.0
    from facegeom.registration import rms_radius  # (here: registration imports scipy.spatial)

    a = rms_radius(np.asarray(actor.neutral, dtype=np.float64))
    c = rms_radius(np.asarray(character.neutral, dtype=np.float64))
    return float(c / a) if a > 0 and np.isfinite(c / a) else 1.0


def _map_notes(m, character, what: str) -> list[str]:
    notes = []
    if m.unmapped_rig:
        notes.append(f"character shapes nothing in the {what} drives (held at 0): {', '.join(m.unmapped_rig)}")
    if m.unmapped_source:
        notes.append(f"{what} shapes the character has no shape for (dropped): {', '.join(m.unmapped_source)}")
    return notes


def relative_motion(rotations, translations) -> tuple[np.ndarray, np.ndarray]:
    """The head's motion about the performance's mean pose: ``(R_ref^T R_t, R_ref^T (t_t - t_ref))`` with
    ``R_ref`` the rotations' mean (the chordal mean) and ``t_ref`` the translations' median.

    A capture states where the actor stood in the volume and which way they faced; a character has its own
    placement (its rig's). Played relative to the mean pose, the character stands where its rig puts it
    whenever the actor is at that pose, and moves and turns as the actor does around it."""
    from scipy.spatial.transform import Rotation

    R = np.asarray(rotations, dtype=np.float64)
    t = np.asarray(translations, dtype=np.float64)
    if R.shape[0] == 0:
        return R, t
    ref = Rotation.from_matrix(R).mean().as_matrix()
    return np.einsum("ji,tjk->tik", ref, R), (t - np.median(t, axis=0)) @ ref


def onto_character(solved: SolvedCapture, character, actor=None) -> SolvedCapture:
    """The actor's solve ``solved`` played on ``character`` (a :class:`~facegeom.model.rig.BlendshapeRig`).

    ``actor``: the rig that was solved (default ``solved.rig``), for the size
    ratio of the head's translations. Raises :class:`InputError` when no shape
    of the character is reached by the actor's names.
    """
    s = solved.solve
    m = character.map_from(s.names)
    if m.is_empty:
        raise InputError(f"none of the character's shapes is reached by the actor's names ({', '.join(s.names[:4])}, "
                         f"...); give a mapping file with names=MAP.csv")
    k = size_ratio(character, actor if actor is not None else solved.rig)
    # each character curve is a mix of the actor's smoothed curves: it carries the strongest smoothing among them
    drives = np.asarray(m.matrix) != 0
    smoothing = np.where(drives, np.asarray(s.smoothing, dtype=np.float64)[None, :], 0.0).max(axis=1, initial=0.0)
    R, t = relative_motion(s.rotations, s.translations)
    out = replace(s, weights=m.apply(s.weights), raw_weights=m.apply(s.raw_weights), names=tuple(character.names),
                  rotations=R, translations=t * k, smoothing=smoothing,
                  info={**s.info, "character_scale": k, "head_motion": True})
    notes = list(solved.notes) + _map_notes(m, character, "actor's rig")
    notes.append(f"character: {int(m.matrix.any(axis=1).sum())} of its {len(character.names)} shapes driven; the "
                 f"head's motion about the performance's mean pose, its translations x{k:.3f} (the character's size "
                 "over the actor's); at that pose the character stands where its rig puts it")
    return replace(solved, solve=out, rig=character, notes=notes)


def take_onto_character(take, character, start: int = 0, frames: int | None = None) -> SolvedCapture:
    """A Live Link take (a :class:`~facegeom.io.takes.Take` or its path) played on ``character``.

    Its ARKit weights drive the character through the name map; its head
    rotations (when the file has them) become the head's motion. Frames
    ``start .. start + frames - 1`` (all from ``start`` when ``frames`` is None).
    """
    from facegeom.io.takes import read_take

    tk = read_take(take) if isinstance(take, (str, Path)) else take
    T_all = tk.n_frames
    if not 0 <= start < T_all:
        raise InputError(f"the take has {T_all} frames; start {start} is outside it", tk.path)
    stop = T_all if frames is None else start + frames
    if stop > T_all:
        raise InputError(f"the take has {T_all} frames; start {start} + frames {frames} runs past its end", tk.path)
    W = tk.weights[start:stop]
    m = character.map_from(ARKIT_NAMES)
    if m.is_empty:
        raise InputError("none of the character's shapes is an ARKit or ICT expression; give a mapping file with "
                         "names=MAP.csv")
    T = W.shape[0]
    if tk.rotations is not None:  # yaw about Y, pitch about X, roll about Z (intrinsic), radians
        R = _yxz_matrices(tk.rotations[start:stop, :3])
    else:
        R = np.repeat(np.eye(3)[None], T, axis=0)
    Wc = m.apply(W)
    solve = MarkerSolve(weights=Wc, names=tuple(character.names), rotations=R, translations=np.zeros((T, 3)),
                        raw_weights=Wc.copy(), smoothing=np.zeros(len(character.names)), rms=np.zeros(T),
                        lost=np.zeros(T, dtype=np.int64), time_s=0.0,
                        info={"take": tk.path, "head_motion": True,
                              "eye_rotations": None if tk.rotations is None else tk.rotations[start:stop, 3:]})
    seq = MarkerSequence(np.arange(start, stop, dtype=np.int64), (), np.zeros((T, 0, 3)), tk.path)
    notes = _map_notes(m, character, "take's")
    if tk.rotations is None or not np.any(tk.rotations[start:stop, :3]):
        notes.append(f"{Path(tk.path).name}: no head rotation in the take; the head stays still")
    fps = take_fps(tk)
    start_s = getattr(tk, "start_s", 0.0) + float(tk.times[start]) if tk.times.size else None
    return SolvedCapture(solve, seq, np.zeros(0, dtype=np.int64), "take", fps, True, character, notes,
                         start_s=start_s)


def _yxz_matrices(angles) -> np.ndarray:
    """Intrinsic Y, X, Z rotations -> ``(T, 3, 3)`` matrices: ``Rotation.from_euler("YXZ", angles).as_matrix()``.

    The same operations as scipy's (each angle's half-angle quaternion, composed in order, then the matrix of
    the quaternion), with numpy on all frames at once: scipy 1.17 takes 2 us a rotation (0.2 s for a
    100,000-frame take), this 0.3 to 0.5 us. Identical to scipy's where numpy's sine and cosine are the C
    library's (bit for bit on 100,000 random frames on the machine this was written on); within 1e-15 anywhere.
    """
    a = np.asarray(angles, dtype=np.float64).reshape(-1, 3)
    c, s = np.cos(a / 2), np.sin(a / 2)
    zero = np.zeros(a.shape[0])

    def compose(p, q):  # quaternions (x, y, z, w): p * q, as scipy's _compose_quat
        px, py, pz, pw = p
        qx, qy, qz, qw = q
        cx, cy, cz = py * qz - pz * qy, pz * qx - px * qz, px * qy - py * qx
        return (pw * qx + qw * px + cx, pw * qy + qw * py + cy, pw * qz + qw * pz + cz,
                pw * qw - (px * qx + py * qy + pz * qz))

    x, y, z, w = compose(compose((zero, s[:, 0], zero, c[:, 0]), (s[:, 1], zero, zero, c[:, 1])),
                         (zero, zero, s[:, 2], c[:, 2]))
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    R = np.empty((a.shape[0], 3, 3))
    R[:, 0, 0] = x2 - y2 - z2 + w2
    R[:, 1, 0] = 2 * (xy + zw)
    R[:, 2, 0] = 2 * (xz - yw)
    R[:, 0, 1] = 2 * (xy - zw)
    R[:, 1, 1] = - x2 + y2 - z2 + w2
    R[:, 2, 1] = 2 * (yz + xw)
    R[:, 0, 2] = 2 * (xz + yw)
    R[:, 1, 2] = 2 * (yz - xw)
    R[:, 2, 2] = - x2 - y2 + z2 + w2
    return R


def stored_registration(model, path, V, F):
    """The head's registration stored by ``facegeom transfer`` beside a rig ``.npz`` -> a Character, or None
    (another file kind, or a rig without one)."""
    import zipfile

    from facegeom.methods.transfer import REGISTRATION_KEYS, stored_character

    if Path(path).suffix.lower() != ".npz":
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in REGISTRATION_KEYS if k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError):
        return None  # read_head has read it: a problem here means no registration
    return stored_character(model, V, F, arrays, path)


def read_head(path):
    """A head file -> ``(V, F, parts or None)``: a mesh, a glTF scene, a USD file's mesh or a rig file's
    neutral."""
    from facegeom.io.mesh import read_mesh

    suffix = Path(path).suffix.lower()
    if suffix in (".glb", ".gltf"):
        from facegeom.io.gltf import read_gltf_rig

        g = read_gltf_rig(path, require_targets=False)
        return g.neutral, g.faces, (g.parts if len(g.parts) > 1 else None)
    if suffix == ".npz":
        from facegeom.model.rig import BlendshapeRig

        rig, _, _ = BlendshapeRig.read_npz(path)
        return rig.neutral, rig.triangles, rig.parts
    if suffix in (".usd", ".usda", ".usdc", ".usdz"):
        from facegeom.io.usd import read_usd_rig

        u = read_usd_rig(path)
        return u.neutral, u.faces, None
    V, F = read_mesh(path)
    return V, F, None
