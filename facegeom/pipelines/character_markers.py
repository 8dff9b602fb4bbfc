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
   skin with its markers as handles, ``deform_many`` in chunks of
   :data:`CHUNK_BYTES`, when the frames are read (:class:`MarkerRoute`). A
   head in pieces (eyes, teeth, tongue, lashes: no marker lies on them) has
   them follow the driven skin by their role
   (:class:`~facegeom.methods.pieces.PieceMotion`): lashes copy the skin
   beneath, the lower teeth and tongue the chin's rigid motion, the eyes and
   upper teeth the skull's.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from facegeom.errors import InputError

__all__ = ["MarkerRoute", "key_frames", "propose_labels", "character_markers", "markers_onto_character",
           "take_markers", "resolve_keys", "key_labels_comment", "CHUNK_BYTES"]

CHUNK_BYTES = 48 << 20  # vertices driven at once (float64): larger blocks are slower (page faults, cache)
LINEAR_FRAMES = 4096  # frames whose coefficients on the deformer's basis are computed at once (MarkerRoute.linear)


@dataclass
class MarkerRoute:
    """The character driven through markers (what :func:`markers_onto_character` returns).

    The frames are driven on demand, :data:`CHUNK_BYTES` at a time: :meth:`source` streams them (to
    :func:`facegeom.io.gltf.write_sequence_glb` or a mesh sequence) without holding ``T x n x 3``;
    :attr:`frames` drives and keeps them all.

    Attributes
    ----------
    markers : (T, p, 3) float64
        The retargeted character markers.
    marker_vertices : (p,) int64
        The character's marker vertices.
    key_frames : (L,) int64
        Frames of the window.
    labels : (L, p, 3) float64
        The character's markers at the key frames (proposed or given).
    times : dict
        Seconds per step (``registration``, ``retarget``, ``deformer_fit``; ``drive`` once :attr:`frames` is read).
    character : Character or None
        The registered head (:func:`~facegeom.methods.transfer.register_character`).
    deformer : Deformer
        Fitted on the character's skin with its markers as handles (skin-local ids when ``motion`` is given).
    actor : (T, p, 3) float64
        The actor's markers retargeted (model frame, cm).
    proposed : (L, p, 3) float64
        The labels proposed at the key frames (what :attr:`labels` holds where nothing was given).
    motion : PieceMotion or None
        How the head's other pieces follow the driven skin (None: the skin is the whole head).
    """

    markers: np.ndarray
    marker_vertices: np.ndarray
    key_frames: np.ndarray
    labels: np.ndarray
    times: dict = field(default_factory=dict)
    character: object = None
    deformer: object = None
    actor: np.ndarray | None = None
    proposed: np.ndarray | None = None
    motion: object = None
    _frames: np.ndarray | None = field(default=None, repr=False)

    def relabel(self, labels, retargeter=None) -> "MarkerRoute":
        """The same route with other labels ``(L, p, 3)`` at the same key frames (NaN: the proposal) -> a new route.

        Only the retargeter is fitted again (the registration and the deformer are kept): what an edit of a
        label costs (tens of milliseconds for a thousand frames).
        """
        from facegeom.io.key_labels import check_labels_on_head
        from facegeom.registry import parse_method

        L = np.asarray(labels, dtype=np.float64)
        if L.shape != self.proposed.shape:
            raise InputError(f"labels must be {self.proposed.shape} for the key frames, got {L.shape}")
        if np.isinf(L).any():
            raise InputError("labels contain inf")
        # edited labels meet the head as a file's do: not far outside it, not squashed to a point, line or plane
        check_labels_on_head(L, self.key_frames, self.character.vertices, self.proposed)
        L = np.where(np.isnan(L), self.proposed, L)
        t0 = time.perf_counter()
        rt = (retargeter or parse_method("tangent").build("retargeters")).fit(self.actor, self.key_frames, L)
        Y = rt.transform()
        times = {**{k: v for k, v in self.times.items() if k != "drive"}, "retarget": time.perf_counter() - t0}
        return MarkerRoute(Y, self.marker_vertices, self.key_frames, L, times, self.character, self.deformer,
                           self.actor, self.proposed, self.motion)

    @property
    def n_vertices(self) -> int:
        """The character's vertices ``n``."""
        return int(self.character.vertices.shape[0])

    def chunk_frames(self) -> int:
        """Frames driven at once: :data:`CHUNK_BYTES` of float64 vertices (at least one frame)."""
        return max(1, CHUNK_BYTES // (24 * self.n_vertices))

    def deform(self, Y) -> np.ndarray:
        """The character's vertices with its markers at ``Y (m, p, 3)`` (head units) -> ``(m, n, 3)``."""
        Y = np.asarray(Y, dtype=np.float64)
        many = getattr(self.deformer, "deform_many", None)
        S = many(Y) if many else np.stack([self.deformer.deform(y) for y in Y])
        return S if self.motion is None else self.motion.frames(S, self.character.vertices)

    def drive(self, a: int, b: int) -> np.ndarray:
        """The character's vertices at frames ``a .. b - 1`` of the window -> ``(b - a, n, 3)``."""
        return self.deform(self.markers[a:b])

    def source(self, scale: float = 1.0):
        """The frames as a :class:`~facegeom.io.frames.FrameSource` (driven chunk by chunk when read), times
        ``scale`` (e.g. the head's units -> metres for a ``.glb``)."""
        from facegeom.io.frames import FrameSource

        def frames(a: int, b: int) -> np.ndarray:
            X = np.array(self.drive(a, b), order="C")  # the deformer's (transposed) view, laid out once
            if scale != 1.0:
                X *= scale
            return X

        return FrameSource(self.markers.shape[0], self.n_vertices, frames, chunk_frames=self.chunk_frames(),
                           linear=lambda: self.linear(scale))

    def linear(self, scale: float = 1.0):
        """The frames' linear structure times ``scale`` (:class:`~facegeom.io.frames.LinearFrames`: every frame is
        ``(C[t] @ basis).T``), or None when the deformer has no ``linear_many`` or gives none (no dense map).

        The tangent deformer's frames are its marker-to-vertex map's rows (and the rest shape's coordinates and a
        row of ones) combined by per-frame coefficients: whatever is not linear in the markers (the robust rigid
        alignment, the soft labels' weight chosen per frame) is in the coefficients, so ``(T, 3, q)`` of them and
        the ``(q, n)`` basis hold the whole sequence. Computed :data:`LINEAR_FRAMES` frames at a time.
        """
        from facegeom.io.frames import LinearFrames

        many = getattr(self.deformer, "linear_many", None)
        if many is None:
            return None
        T = self.markers.shape[0]
        C, basis = None, None
        for a in range(0, T, LINEAR_FRAMES):
            got = many(self.markers[a:a + LINEAR_FRAMES])
            if got is None:
                return None
            if self.motion is not None:
                got = self.motion.linear(got[0], got[1], self.character.vertices)
            if C is None:
                basis = got[1]
                C = np.empty((T, 3, basis.shape[0]))
            C[a:a + LINEAR_FRAMES] = got[0]
        if scale != 1.0:
            C *= scale
        return LinearFrames(C, basis)

    @property
    def frames(self) -> np.ndarray:
        """``(T, n, 3)`` float64: every frame, driven once and kept."""
        if self._frames is None:
            t0 = time.perf_counter()
            T, step = self.markers.shape[0], self.chunk_frames()
            out = np.empty((T, self.n_vertices, 3))
            for a in range(0, T, step):
                out[a:a + step] = self.drive(a, min(T, a + step))
            self._frames = out
            self.times["drive"] = time.perf_counter() - t0
        return self._frames


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


def resolve_keys(given, listed, start: int, stop: int, n_markers: int):
    """The key frames and labels of the window ``start .. stop - 1`` of a take: the frames ``listed`` and those of
    the key-labels file ``given``, for :func:`markers_onto_character`.

    Parameters
    ----------
    given : facegeom.io.key_labels.KeyLabels or None
        A key-labels file as read (:func:`~facegeom.io.key_labels.read_key_labels`); its frames are key frames.
    listed : sequence of int
        More key frames (take frames).
    start, stop : int
        The window, take frames.
    n_markers : int
        Markers of the layout ``p``.

    Returns
    -------
    keys : (L,) int64 or None
        The union of both, sorted, as frames of the window; None when neither gives one (the route chooses).
    labels : (L, p, 3) float64 or None
        The file's labels at its frames, NaN elsewhere (those keep the proposal); None without a file.

    Raises
    ------
    InputError
        A frame outside the window (naming the file when it is the file's), a single key frame.
    """
    file_frames = [] if given is None else [int(f) for f in given.frames]
    chosen = sorted({int(f) for f in listed} | set(file_frames))
    outside = [f for f in chosen if not start <= f < stop]
    if outside:
        raise InputError(f"key frame {outside[0]} is outside the window, frames {start}..{stop - 1}",
                         given.path if outside[0] in file_frames else None)
    if len(chosen) == 1:
        raise InputError(f"the marker route needs at least 2 key frames, got only frame {chosen[0]}: list more "
                         f"or label more frames")
    if not chosen:
        return None, None
    keys = np.array(chosen, dtype=np.int64) - start
    if given is None:
        return keys, None
    if given.labels.shape[1:] != (n_markers, 3):
        raise InputError(f"the labels are for {given.labels.shape[1]} markers, the layout has {n_markers}", given.path)
    labels = np.full((len(chosen), n_markers, 3), np.nan)
    labels[np.searchsorted(chosen, file_frames)] = given.labels
    return keys, labels


def key_labels_comment(head_name: str, n_vertices: int, take_name: str) -> str:
    """The comment heading a key-labels file written for the head ``head_name`` and the take ``take_name``."""
    return (f"key labels for {head_name} ({n_vertices} vertices), take {take_name}: frame = take frame, marker = "
            f"index in the actor's 80-marker layout, x,y,z in the head's units")


def take_markers(model, take, start: int = 0, frames: int | None = None, marker_ids=None):
    """The generic ICT face performing a take, seen as markers -> ``(X (T, p, 3) cm, neutral markers (p, 3), ids)``.

    ``take``: a path or a read :class:`~facegeom.io.takes.Take`; ``marker_ids``: template vertices (default the
    ``ict80`` layout).
    """
    from facegeom.io import ict_weights, read_take
    from facegeom.model import BlendshapeRig
    from facegeom.model.layouts import ict80

    from facegeom.io.takes import Take

    tk = take if isinstance(take, Take) else read_take(take)
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
                           progress=None, character=None, labels_path=None, first_frame: int = 0) -> MarkerRoute:
    """Drive the head ``(V, F)`` by the actor's markers ``(T, p, 3)`` (model frame, cm) on template vertices
    ``marker_ids`` (see the module docstring); ``labels (L, p, 3)`` at ``keys`` (frames of the window) replace
    the proposal where they are not NaN.
    ``character``: the head already registered (:func:`~facegeom.methods.transfer.register_character` of
    ``(V, F)``), not registered again.

    Labels no head has are refused in one line before the work they would spoil
    (:func:`facegeom.io.key_labels.check_labels_on_head`: far outside the head, before the registration; squashed
    to a point, a line, a plane or a fraction of the face, before the retargeting), naming ``labels_path`` (their
    file) and the key frame plus ``first_frame`` (the window's first take frame)."""
    from facegeom.io.key_labels import check_labels_on_head
    from facegeom.methods.pieces import PieceMotion
    from facegeom.methods.transfer import register_character
    from facegeom.registry import parse_method

    say = progress or (lambda line: None)
    X = np.asarray(actor_markers, dtype=np.float64)
    if X.ndim != 3 or X.shape[1] != len(marker_ids) or X.shape[2] != 3 or X.shape[0] < 2:
        raise InputError(f"actor markers must be (T >= 2, {len(marker_ids)}, 3), got {X.shape}")
    if labels is not None and keys is not None:
        check_labels_on_head(np.asarray(labels, dtype=np.float64), np.asarray(keys).reshape(-1), V,
                             path=labels_path, first_frame=first_frame)
    times = {}
    t0 = time.perf_counter()
    ch = character or register_character(model, V, F, parts=parts, roles=roles, progress=progress)
    times["registration"] = time.perf_counter() - t0
    reg = ch.registration
    mv = character_markers(model, reg, ch.pieces[0].vertices, marker_ids, ch.vertices)
    keys = key_frames(X, min(n_keys, X.shape[0])) if keys is None else np.asarray(keys, dtype=np.int64)
    if keys.ndim != 1 or keys.size < 2 or np.unique(keys).size != keys.size or keys.min() < 0 \
            or keys.max() >= X.shape[0]:
        raise InputError(f"key frames must be at least 2 distinct frames of the {X.shape[0]}-frame window")
    proposed = propose_labels(X, keys, reg, actor_neutral_markers, ch.vertices[mv])
    if labels is None:
        labels = proposed
    labels = np.asarray(labels, dtype=np.float64)
    if labels.shape != (keys.size, len(mv), 3):
        raise InputError(f"labels must be ({keys.size}, {len(mv)}, 3) for the key frames, got {labels.shape}")
    check_labels_on_head(labels, keys, V, proposed, path=labels_path, first_frame=first_frame)
    labels = np.where(np.isnan(labels), proposed, labels)  # markers not given keep the proposal
    say(f"{keys.size} key frames ({', '.join(map(str, keys[:12]))}{', ...' if keys.size > 12 else ''}); "
        f"{len(mv)} markers on the character")
    t0 = time.perf_counter()
    rt = (retargeter or parse_method("tangent").build("retargeters")).fit(X, keys, labels)
    Y = rt.transform()
    times["retarget"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    motion = PieceMotion.build(model, reg, ch.vertices, ch.faces, ch.pieces)
    de = deformer or parse_method("tangent").build("deformers")
    if motion is None:
        de.fit(ch.vertices, ch.faces, mv)
    else:  # the markers lie on the skin: it is driven, the other pieces follow it
        de.fit(motion.rest, motion.skin_faces, motion.local(mv))
    times["deformer_fit"] = time.perf_counter() - t0
    say(f"retarget {times['retarget']:.2f} s, deformer fit {times['deformer_fit']:.2f} s")
    return MarkerRoute(Y, mv, keys, labels, times, ch, de, X, proposed, motion)
