"""A performance onto the user's character through markers: the tangent framework's own route.

The paper's route, on a head no one rigged: the actor's markers are retargeted
onto the character's markers from a few labelled frames, and the character's
mesh is driven through its markers every frame.

1. **Markers on the character**: the ICT face is registered onto the head
   (:func:`~facegeom.methods.transfer.register_character`); each actor marker's
   template vertex, posed on the head, picks the closest skin vertex (no hand
   placement).
2. **Key frames** (:func:`key_frames`), unless listed: the frame nearest the
   neutral, then farthest-point sampling of the actor's marker displacements
   (each next key the frame farthest, in the RMS of all markers, from every key
   so far): the extremes of the performance are covered first, no two keys
   alike.
3. **Labels** (:func:`propose_labels`): at each key frame the actor's marker
   displacements from its neutral, carried into the character's frame and size
   by the registration's similarity, added to the character's markers -- a
   proposal the user may edit (``labels`` given as ``(L, p, 3)``).
4. **Retarget**: a retargeter (default the tangent framework's,
   ``registry`` name ``tangent``) fitted on the actor's sequence and the labels
   gives the character's markers every frame.
5. **Drive**: a deformer (default ``tangent``) fitted once on the character's
   mesh with its markers as handles, ``deform_many`` in chunks of
   :data:`CHUNK` frames.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from facegeom.errors import InputError

__all__ = ["MarkerRoute", "key_frames", "propose_labels", "character_markers", "markers_onto_character",
           "take_markers", "CHUNK"]

CHUNK = 500  # frames driven at once (memory: CHUNK x n x 3 floats)


@dataclass
class MarkerRoute:
    """The character driven through markers (what :func:`markers_onto_character` returns).

    Attributes
    ----------
    frames : (T, n, 3) float64
        The character's vertices per frame (its units and frame).
    markers : (T, p, 3) float64
        The retargeted character markers.
    marker_vertices : (p,) int64
        The character's marker vertices.
    key_frames : (L,) int64
    labels : (L, p, 3) float64
        The character's markers at the key frames (proposed or given).
    times : dict
        Seconds per step (``registration``, ``retarget``, ``deformer_fit``, ``drive``).
    character : Character or None
        The registered head (:func:`~facegeom.methods.transfer.register_character`).
    """

    frames: np.ndarray
    markers: np.ndarray
    marker_vertices: np.ndarray
    key_frames: np.ndarray
    labels: np.ndarray
    times: dict = field(default_factory=dict)
    character: object = None


def key_frames(X, count: int) -> np.ndarray:
    """``count`` key frames of the marker sequence ``X (T, p, 3)``: nearest the neutral first, then farthest points.

    The neutral is the per-marker median over frames (a performance rests
    there more than anywhere); distances are RMS over the markers. Sorted.
    """
    X = np.asarray(X, dtype=np.float64)
    T = X.shape[0]
    if not 1 <= count <= T:
        raise InputError(f"key frames: {count} asked of a {T}-frame sequence")
    D = (X - np.median(X, axis=0)[None]).reshape(T, -1)
    first = int(np.argmin((D * D).sum(axis=1)))
    chosen = [first]
    d = np.sqrt(((D - D[first]) ** 2).sum(axis=1))
    for _ in range(count - 1):
        k = int(np.argmax(d))
        chosen.append(k)
        d = np.minimum(d, np.sqrt(((D - D[k]) ** 2).sum(axis=1)))
    return np.sort(np.unique(chosen))


def character_markers(model, registration, skin_vertices, marker_ids, head_vertices) -> np.ndarray:
    """The character's marker vertices: the skin vertex closest to each marker's template vertex, posed on the head.

    Two markers never share a vertex (closed lips put an upper and a lower lip
    marker on one): in order of distance, each takes its closest vertex not
    taken yet.
    """
    skin = np.asarray(skin_vertices, dtype=np.int64)
    posed = registration.template[np.asarray(marker_ids, dtype=np.int64)]
    k = min(16, skin.size)
    d, j = cKDTree(head_vertices[skin]).query(posed, k=k)
    d, j = d.reshape(len(posed), k), j.reshape(len(posed), k)
    out = np.full(len(posed), -1, dtype=np.int64)
    taken: set[int] = set()
    for m in np.argsort(d[:, 0]):
        free = [c for c in j[m] if c not in taken]
        if not free:
            raise InputError("the head is too coarse for the marker layout: a marker finds no free vertex near it")
        out[m] = free[0]
        taken.add(int(free[0]))
    return skin[out]


def propose_labels(X, keys, registration, actor_neutral_markers, character_marker_positions) -> np.ndarray:
    """The character's markers at ``keys``: the actor's displacements there, turned and scaled by the registration.

    ``X (T, p, 3)`` in the model's units and frame (cm); the result in the head's.
    """
    dX = np.asarray(X, dtype=np.float64)[np.asarray(keys)] - actor_neutral_markers[None]
    return character_marker_positions[None] + registration.delta_in_head(dX)


def take_markers(model, take, start: int = 0, frames: int | None = None, marker_ids=None):
    """The generic ICT face performing a take, seen as markers -> ``(X (T, p, 3) cm, neutral markers (p, 3), ids)``.

    ``marker_ids``: template vertices (default the ``ict80`` layout).
    """
    from facegeom.io import ict_weights, read_take
    from facegeom.model import BlendshapeRig
    from facegeom.model.layouts import ict80

    tk = read_take(take)
    W = ict_weights(tk, model.expression_names)
    if not 0 <= start < W.shape[0]:
        raise InputError(f"the take has {W.shape[0]} frames; start {start} is outside it", tk.path)
    stop = W.shape[0] if frames is None else start + frames
    if stop > W.shape[0]:
        raise InputError(f"the take has {W.shape[0]} frames; start {start} + frames {frames} runs past its end",
                         tk.path)
    rig = BlendshapeRig.from_face_model(model)
    ids = ict80(model) if marker_ids is None else np.asarray(marker_ids, dtype=np.int64)
    X = rig.neutral[ids][None] + np.einsum("tb,bpi->tpi", W[start:stop], rig.deltas[:, ids])
    return X, rig.neutral[ids], ids


def markers_onto_character(model, actor_markers, actor_neutral_markers, marker_ids, V, F, *, labels=None,
                           keys=None, n_keys: int = 10, retargeter=None, deformer=None, parts=None, roles=None,
                           progress=None, character=None) -> MarkerRoute:
    """Drive the head ``(V, F)`` by the actor's markers ``(T, p, 3)`` (model frame, cm) on template vertices
    ``marker_ids`` (see the module docstring); ``labels (L, p, 3)`` at ``keys`` replace the proposal.
    ``character``: the head already registered (:func:`~facegeom.methods.transfer.register_character` of
    ``(V, F)``), not registered again."""
    from facegeom.methods.transfer import register_character
    from facegeom.registry import parse_method

    say = progress or (lambda line: None)
    X = np.asarray(actor_markers, dtype=np.float64)
    if X.ndim != 3 or X.shape[1] != len(marker_ids) or X.shape[2] != 3 or X.shape[0] < 2:
        raise InputError(f"actor markers must be (T >= 2, {len(marker_ids)}, 3), got {X.shape}")
    times = {}
    t0 = time.perf_counter()
    ch = character or register_character(model, V, F, parts=parts, roles=roles, progress=progress)
    times["registration"] = time.perf_counter() - t0
    reg = ch.registration
    mv = character_markers(model, reg, ch.pieces[0].vertices, marker_ids, ch.vertices)
    keys = key_frames(X, min(n_keys, X.shape[0])) if keys is None else np.asarray(keys, dtype=np.int64)
    if labels is None:
        labels = propose_labels(X, keys, reg, actor_neutral_markers, ch.vertices[mv])
    labels = np.asarray(labels, dtype=np.float64)
    if labels.shape != (keys.size, len(mv), 3):
        raise InputError(f"labels must be ({keys.size}, {len(mv)}, 3) for the key frames, got {labels.shape}")
    say(f"{keys.size} key frames ({', '.join(map(str, keys[:12]))}{', ...' if keys.size > 12 else ''}); "
        f"{len(mv)} markers on the character")
    t0 = time.perf_counter()
    rt = (retargeter or parse_method("tangent").build("retargeters")).fit(X, keys, labels)
    Y = rt.transform()
    times["retarget"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    de = (deformer or parse_method("tangent").build("deformers")).fit(ch.vertices, ch.faces, mv)
    times["deformer_fit"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    frames = np.empty((Y.shape[0],) + ch.vertices.shape)
    many = getattr(de, "deform_many", None)
    for a in range(0, Y.shape[0], CHUNK):
        block = Y[a:a + CHUNK]
        frames[a:a + CHUNK] = many(block) if many else np.stack([de.deform(y) for y in block])
    times["drive"] = time.perf_counter() - t0
    say(f"retarget {times['retarget']:.2f} s, deformer fit {times['deformer_fit']:.2f} s, {Y.shape[0]} frames driven "
        f"in {times['drive']:.2f} s")
    return MarkerRoute(frames, Y, mv, keys, labels, times, ch)
