"""``facegeom view rig`` and ``facegeom view transfer``: pose a blendshape rig by hand, and check a transfer.

- :class:`RigView`: a user's rig (what :func:`facegeom.model.load_rig` loads: an
  OBJ folder, a glTF file or an ``.npz``; every part in one mesh), posed with one
  slider per shape and coloured by each vertex's displacement from the neutral
  in mm. The rig is assumed to be in facegeom's frame: centimetres, Y up (what
  ``load_rig`` gives, whatever the file's own units and axes).
- :class:`TransferView`: a head after :func:`facegeom.methods.transfer.register_character`
  and :func:`~facegeom.methods.transfer.transfer_character`. Row: the ICT template
  (the model's neutral plus the weighted ICT expressions) | the character with its
  transferred shapes and the registered template drawn over it (semi-transparent,
  a checkbox hides it). One set of 53 sliders (the ICT names) drives both. The
  character is drawn in the model's frame (the registration's similarity undone:
  turned, scaled and moved onto the ICT face); its colours are its own
  displacements in mm (the head's units converted). The 68 iBUG landmarks sit on
  head vertices of the skin (the head vertex closest to each landmark of the
  registered template, or the ones a ``--landmarks`` file gave); the mouse drags
  one over the head's surface (it snaps to the closest free skin vertex under the
  cursor), :meth:`TransferView.save_landmarks` writes them as the ``landmark,vertex_id``
  CSV that ``facegeom transfer --landmarks`` reads, and a re-registration with
  them runs in a worker process while the window keeps drawing.
"""
from __future__ import annotations

import difflib
import time
from pathlib import Path

import numpy as np

from facegeom.constants import CM_TO_MM
from facegeom.errors import FacegeomError, InputError
from facegeom.viewer.app import MARKER_COLOR, SELECTED_COLOR, BaseView, color_u32, nice_ceiling

__all__ = ["RigView", "TransferView", "RegisterJob", "register_and_transfer", "write_landmarks_csv",
           "find_shape", "closest_free_vertices", "N_LANDMARKS", "LANDMARK_REGIONS"]

N_LANDMARKS = 68
#: iBUG 68-point regions: (first, last + 1, name), for the panel
LANDMARK_REGIONS = ((0, 17, "jaw line"), (17, 22, "right brow"), (22, 27, "left brow"), (27, 31, "nose bridge"),
                    (31, 36, "nostrils"), (36, 42, "right eye"), (42, 48, "left eye"), (48, 60, "outer lips"),
                    (60, 68, "inner lips"))
PICK_PX = 10.0  # a press this close (window pixels) to a landmark grabs it
SLIDER_ROWS = 14  # shape sliders visible at once in the scrollable list
ICT_LANDMARK_COLOR = (0.35, 0.35, 0.4)
OVERLAY_COLOR = (0.95, 0.55, 0.15)
OVERLAY_OPACITY = 0.35
GAP = 0.12  # space between the two copies of the transfer view, relative to the ICT face's width
QUICK_SHAPE, QUICK_WEIGHT = "shape", "weight"  # the quick pick's widget labels


def find_shape(names, name: str, what: str = "blendshape", path=None) -> int:
    """Index of ``name`` in ``names``; else :class:`InputError` (naming ``path``) listing a few close names.

    Parameters
    ----------
    names : sequence of str
        The shape names.
    name : str
        The name asked for (exact match first, then the suggestions ignore case).
    what : str
        How the shapes are called in the message.
    path : str or PathLike, optional
        The file the shapes come from, named first in the message.
    """
    names = list(names)
    if name in names:
        return names.index(name)
    close = difflib.get_close_matches(str(name), names, n=4, cutoff=0.5)
    if not close:
        low = {s.lower(): s for s in names}
        close = [low[s] for s in difflib.get_close_matches(str(name).lower(), list(low), n=4, cutoff=0.5)]
    hint = (f"; did you mean {', '.join(repr(s) for s in close)}?" if close else
            f"; there are {len(names)} ({', '.join(names[:5])}{', ...' if len(names) > 5 else ''})")
    raise InputError(f"no {what} called {name!r}{hint}", path)


def write_landmarks_csv(path, ids) -> Path:
    """Write the 68 landmarks as ``landmark,vertex_id`` (one row per landmark, 0-67), atomically.

    What ``facegeom transfer --landmarks`` and
    :func:`facegeom.methods.transfer.read_head_landmarks` read.

    Parameters
    ----------
    path : str or PathLike
        The CSV written (replaced as a whole: a reader never sees half a file).
    ids : (68,) int array
        Head vertex id per iBUG landmark, all known (>= 0) and distinct.

    Returns
    -------
    Path
    """
    from facegeom.io import atomic_path

    ids = np.asarray(ids, dtype=np.int64)
    if ids.shape != (N_LANDMARKS,) or (ids < 0).any():
        raise InputError(f"the landmarks must be {N_LANDMARKS} head vertex ids, got shape {ids.shape}", path)
    if np.unique(ids).size != ids.size:
        raise InputError("two landmarks lie on the same head vertex", path)
    path = Path(path)
    text = "landmark,vertex_id\n" + "".join(f"{k},{int(v)}\n" for k, v in enumerate(ids))
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text)
    return path


def closest_free_vertices(points, candidates, positions, taken=()) -> np.ndarray:
    """Per point the closest vertex among ``candidates``, every point on a different vertex.

    Parameters
    ----------
    points : (k, 3) float array
        Where the vertices are wanted.
    candidates : (c,) int array
        The vertex ids allowed (e.g. the skin's).
    positions : (n, 3) float array
        Every vertex's position (same frame as ``points``).
    taken : iterable of int
        Vertex ids already used by others.

    Returns
    -------
    (k,) int64
        The points closest to their vertex are served first; a point whose closest
        vertex is taken gets the next closest free one.
    """
    from scipy.spatial import cKDTree

    P = np.atleast_2d(np.asarray(points, dtype=np.float64))
    cand = np.asarray(candidates, dtype=np.int64)
    tree = cKDTree(np.asarray(positions, dtype=np.float64)[cand])
    used = {int(v) for v in taken}
    k = min(cand.size, len(used) + P.shape[0] + 1)
    d, j = tree.query(P, k=k)
    d, j = d.reshape(P.shape[0], -1), j.reshape(P.shape[0], -1)
    out = np.full(P.shape[0], -1, dtype=np.int64)
    for i in np.argsort(d[:, 0], kind="stable"):
        for jj in j[i]:
            v = int(cand[jj])
            if v not in used:
                out[i] = v
                used.add(v)
                break
        if out[i] < 0:
            raise InputError("fewer free vertices than landmarks to place")
    return out


def register_and_transfer(model, V, F, *, engine="deformation", landmarks=None, units="auto", path=None,
                          parts=None, roles=None, progress=None):
    """:func:`~facegeom.methods.transfer.register_character` then :func:`~facegeom.methods.transfer.transfer_character`.

    Parameters as :func:`facegeom.methods.transfer.transfer_head`; ``progress`` receives
    one line per step (and the transfer's line). Returns ``(Character, TransferResult)``.
    """
    from facegeom.methods.transfer import ENGINES, register_character, transfer_character

    say = progress or (lambda line: None)
    if engine not in ENGINES:
        raise InputError(f"unknown transfer engine {engine!r}; use one of {', '.join(ENGINES)}")
    ch = register_character(model, V, F, landmarks=landmarks, units=units, path=path, progress=progress,
                            parts=parts, roles=roles)
    res = transfer_character(model, ch, engine)
    say(f"transfer ({engine}): {len(res.names)} shapes onto {ch.vertices.shape[0]} vertices in {res.time_s:.2f} s")
    return ch, res


def _register_in_worker(conn, model, V, F, options) -> None:
    """The worker process of :class:`RegisterJob`: progress lines, then one answer, on ``conn``."""
    import traceback

    from threadpoolctl import threadpool_limits

    threadpool_limits(1)  # beside the window's renderer (see facegeom.viewer.workers)

    def send(msg):
        try:
            conn.send(msg)
        except (BrokenPipeError, OSError):
            pass

    try:
        out = register_and_transfer(model, V, F, progress=lambda line: send(("progress", line)), **options)
        send(("ok", out))
    except FacegeomError as exc:
        send(("failed", str(exc)))
    except Exception as exc:  # noqa: BLE001 - reported in the panel; the window stays
        last = traceback.extract_tb(exc.__traceback__)[-1:]
        where = f" ({last[0].filename}:{last[0].lineno})" if last else ""
        send(("failed", f"{type(exc).__name__}: {exc}{where}"))
    finally:
        conn.close()


class RegisterJob:
    """:func:`register_and_transfer` in a worker process (the same preloaded context as
    :class:`facegeom.viewer.workers.MethodWorker`): the registration's ~10 s of numerics
    never hold the window's frame loop. :meth:`poll` never blocks.

    Attributes
    ----------
    lines : list of str
        The progress lines received so far.
    result : tuple (Character, TransferResult) or None
        When it succeeded.
    error : str or None
        When it failed (the message).
    started : float
        ``time.monotonic()`` at the start.
    """

    def __init__(self, model, V, F, **options):
        from facegeom.viewer.workers import worker_context

        ctx = worker_context()
        self._conn, child = ctx.Pipe(duplex=False)
        self._proc = ctx.Process(target=_register_in_worker, args=(child, model, V, F, options), daemon=True,
                                 name="facegeom-viewer-register")
        self._proc.start()
        child.close()
        self.lines: list[str] = []
        self.result = None
        self.error: str | None = None
        self.started = time.monotonic()
        self.done = False

    def poll(self) -> bool:
        """Collect what arrived (progress lines, the answer); returns whether the job has finished."""
        if self.done:
            return True
        try:
            while self._conn.poll():
                kind, payload = self._conn.recv()
                if kind == "progress":
                    self.lines.append(str(payload))
                else:
                    self.done = True
                    if kind == "ok":
                        self.result = payload
                    else:
                        self.error = str(payload)
                    break
        except (EOFError, OSError):
            self.done = True
            self.error = "the registration worker ended without an answer"
        if self.done:
            self.close()
        return self.done

    def seconds(self) -> float:
        """Seconds since the job started."""
        return time.monotonic() - self.started

    def close(self) -> None:
        """Stop the worker (a registration still running is abandoned)."""
        if self._proc.is_alive():
            self._proc.terminate()
        self._proc.join(timeout=1.0)
        try:
            self._conn.close()
        except OSError:
            pass


class _ShapeSlidersView(BaseView):
    """Weights by shape name with the panel's shape sliders; subclasses draw the faces in :meth:`refresh`."""

    colorbar_title = "displacement from the neutral (mm)"

    def __init__(self, names, path=None):
        super().__init__()
        self.names = [str(s) for s in names]
        self.weights = np.zeros(len(self.names))
        self.picked = self.names[0]
        self.path = path
        self._labels = [f"{s}##shape" if s in (QUICK_SHAPE, QUICK_WEIGHT) else s for s in self.names]

    def shape_index(self, name: str) -> int:
        """Index of shape ``name``; unknown names raise :class:`InputError` naming the file and close names."""
        return find_shape(self.names, name, path=self.path)

    def set_weight(self, name: str, w: float, refresh: bool = True) -> None:
        """Set the weight of shape ``name`` (clipped to [0, 1], the sliders' range) and pick it in the quick combo."""
        i = self.shape_index(name)
        self.weights[i] = float(np.clip(w, 0.0, 1.0))
        self.picked = self.names[i]
        if refresh:
            self.refresh()

    def set_weights(self, weights) -> None:
        """Set every weight at once: ``(K,)`` in the order of :attr:`names`, or a mapping name -> weight
        (the rest set to 0; the quick pick shows its first shape)."""
        if isinstance(weights, dict):
            w = np.zeros(len(self.names))
            for k, v in weights.items():
                w[self.shape_index(k)] = float(v)
            if weights:
                self.picked = self.names[self.shape_index(next(iter(weights)))]
        else:
            w = np.asarray(weights, dtype=np.float64)
            if w.shape != self.weights.shape:
                raise InputError(f"weights must have shape {self.weights.shape}, got {w.shape}")
        self.weights = np.clip(w, 0.0, 1.0)
        self.refresh()

    def reset_weights(self) -> None:
        """Every weight back to 0 (the neutral)."""
        self.weights[:] = 0.0
        self.refresh()

    def active(self) -> dict:
        """Shape name -> weight of every shape with a non-zero weight."""
        return {self.names[i]: float(self.weights[i]) for i in np.flatnonzero(self.weights)}

    def refresh(self) -> None:  # pragma: no cover - overridden
        """Push the posed faces and their colours to polyscope."""
        raise NotImplementedError

    def shapes_panel(self) -> None:
        """The quick pick (a combo and its weight), ``reset``, then one slider per shape in a scrolled list."""
        import polyscope.imgui as psim

        ui = self.ui
        ch, item = ui.combo(QUICK_SHAPE, self.picked, self.names)
        if ch and item in self.names:
            self.picked = item
        i = self.names.index(self.picked)
        ch, v = ui.slider_float(QUICK_WEIGHT, self.weights[i], 0.0, 1.0, "%.2f")
        if ch:
            self.set_weight(self.picked, v)
        if ui.button("reset"):
            self.reset_weights()
        psim.SameLine()
        psim.TextUnformatted(f"{len(self.active())} of {len(self.names)} shapes on")
        rows = min(len(self.names), SLIDER_ROWS)
        height = rows * psim.GetFrameHeightWithSpacing() + 8
        if psim.BeginChild("shape sliders", (0.0, float(height)), psim.ImGuiChildFlags_Borders):
            label_w = max(psim.CalcTextSize(s)[0] for s in self.names) + 2 * psim.GetStyle().ItemInnerSpacing[0]
            psim.PushItemWidth(-float(label_w))  # every name shown whole, the sliders take the rest
            changed = {}
            for name, label, w in zip(self.names, self._labels, self.weights):
                ch, v = ui.slider_float(label, w, 0.0, 1.0, "%.2f")
                if ch:
                    changed[name] = v
            for name, v in changed.items():
                self.set_weight(name, v, refresh=False)
            if changed:
                self.refresh()
            psim.PopItemWidth()
        psim.EndChild()

    def state(self) -> dict:
        """:meth:`BaseView.state` plus ``weights`` (name -> weight of the shapes that are on) and ``picked``."""
        out = super().state()
        out.update(weights=self.active(), picked=self.picked)
        return out


class RigView(_ShapeSlidersView):
    """One blendshape rig posed by hand: every part in one mesh, coloured by the displacement from its neutral.

    Parameters
    ----------
    rig : BlendshapeRig
        In facegeom's frame (cm, Y up): what :func:`facegeom.model.load_rig` returns.
    name : str, optional
        How the panel names the rig (default: ``path``'s file name, else ``"rig"``).
    path : str or PathLike, optional
        The rig's file or folder, named in errors (an unknown shape name).
    weights : mapping name -> weight, optional
        The pose at start.
    """

    title = "facegeom view rig"

    def __init__(self, rig, name: str | None = None, path=None, weights=None):
        super().__init__(rig.names, path)
        self.rig = rig
        self.name = name or (Path(path).name if path is not None else "rig")
        per_shape = np.linalg.norm(np.asarray(rig.deltas), axis=2).max(axis=1) * CM_TO_MM  # (K,) mm
        self.shape_max_mm = per_shape
        self.vmax = nice_ceiling(float(np.percentile(per_shape, 90)) if per_shape.size else 1.0)
        self.shift = np.zeros(3)
        if weights:
            self.set_weights(dict(weights))

    def posed(self) -> np.ndarray:
        """The rig at the current weights, ``(n, 3)`` cm."""
        on = np.flatnonzero(self.weights)
        if on.size == 0:
            return np.asarray(self.rig.neutral)
        return self.rig.neutral + np.tensordot(self.weights[on], self.rig.deltas[on], axes=1)

    def displacement_mm(self) -> np.ndarray:
        """``(n,)`` per-vertex distance from the neutral at the current weights, mm."""
        return np.linalg.norm(self.posed() - self.rig.neutral, axis=1) * CM_TO_MM

    def copies(self) -> list[str]:
        """The one face of the row."""
        return ["rig"]

    def shown_faces(self) -> dict:
        """``rig`` -> the posed mesh as drawn."""
        return {"rig": self.posed() + self.shift} if self._built else {}

    def build(self) -> None:
        """Register the rig's mesh (posed) with its displacement colours."""
        self._built = True
        self.mesh("rig", self.posed(), self.rig.triangles, self.shift)
        self.refresh()

    def refresh(self) -> None:
        """Move the mesh to the current weights and colour it by the displacement (mm)."""
        import polyscope as ps

        if not ps.is_initialized() or not self._built or not ps.has_surface_mesh("rig"):
            return
        m = ps.get_surface_mesh("rig")
        m.update_vertex_positions(self.posed() + self.shift)
        self.error_colors(m, self.displacement_mm(), self.vmax, name="displacement (mm)")

    def panel(self) -> None:
        """The rig's summary, the colour scale, then the shape sliders."""
        import polyscope.imgui as psim

        r = self.rig
        psim.TextWrapped(f"{self.name}: {r.n_shapes} shapes, {r.n_vertices} vertices"
                         + (f", {len(r.parts)} parts" if r.parts else ""))
        psim.TextWrapped("the rig as loaded (facegeom's frame: cm, Y up); colour: each vertex's displacement "
                         "from the neutral (mm)")
        if self.color_max_slider():
            self.refresh()
        d = self.displacement_mm()
        psim.TextUnformatted(f"largest displacement {d.max():.2f} mm")
        psim.Separator()
        self.shapes_panel()

    def state(self) -> dict:
        """:meth:`_ShapeSlidersView.state` plus ``max_mm`` (the largest displacement shown)."""
        out = super().state()
        out["max_mm"] = float(self.displacement_mm().max())
        return out


class TransferView(_ShapeSlidersView):
    """The ICT template | the character with its transferred shapes, one set of sliders; landmarks to edit.

    Parameters
    ----------
    model : FaceModel
        The ICT face model (cm).
    character : facegeom.methods.transfer.Character
        From :func:`~facegeom.methods.transfer.register_character`.
    result : facegeom.methods.transfer.TransferResult
        From :func:`~facegeom.methods.transfer.transfer_character` (the 53 ICT shapes).
    head_path : str or PathLike, optional
        The head's file (named in the panel and errors).
    engine, units, roles
        How the head was registered and transferred (a re-registration uses them again); ``engine``
        defaults to the one ``result`` was made with.
    landmarks : (68,) int array, optional
        Head vertex ids the user gave (-1 where unknown); the others start at the
        skin vertex closest to the registered template's landmark.
    save_path : str or PathLike, optional
        Where :meth:`save_landmarks` writes the CSV; without it the panel says how
        to give one (``--save-landmarks``).
    weights : mapping name -> weight, optional
        The pose at start.
    background : bool
        Re-register in a worker process (the window keeps drawing); ``False``:
        in this process, blocking (scripts, screenshots).
    """

    title = "facegeom view transfer"

    def __init__(self, model, character, result, *, head_path=None, engine: str | None = None, units="auto",
                 roles=None, landmarks=None, save_path=None, weights=None, background: bool = False):
        super().__init__(result.names, head_path)
        self.model = model
        self.head_path = head_path
        self.head_name = Path(head_path).name if head_path is not None else "head"
        self.engine = result.engine if engine is None else engine
        self.units = units
        self.roles = dict(roles or {})
        self.save_path = None if save_path is None else Path(save_path)
        self.background = bool(background)
        self.overlay = True
        self.show_landmarks = True
        self.landmark = 0
        self.hover: int | None = None
        self._drag = None
        self.drags = 0
        self.saved = 0
        self.registrations = 1
        self.job: RegisterJob | None = None
        ict = np.asarray(model.expression_deltas)
        self.ict_index = np.array([list(model.expression_names).index(s) for s in self.names], dtype=np.int64)
        per_shape = np.linalg.norm(ict[self.ict_index], axis=2).max(axis=1) * CM_TO_MM
        self.vmax = nice_ceiling(float(np.percentile(per_shape, 90)))
        self.install(character, result, landmarks)
        if weights:
            self.set_weights(dict(weights))

    # ------------------------------------------------------------------ model side (no polyscope)
    def install(self, character, result, landmarks=None) -> None:
        """Take a (new) registration and transfer: the display frame, the skin and the landmarks.

        ``landmarks`` (68,) head vertex ids, -1 where unknown: those kept, the
        others placed at the skin vertex closest to the registered template's
        landmark (every landmark on its own vertex).
        """
        self.character, self.result = character, result
        reg = character.registration
        self.reg = reg
        self.skin = np.asarray(character.pieces[0].vertices, dtype=np.int64)
        self._skin_set = set(self.skin.tolist())
        self.skin_faces = np.asarray(character.faces)[np.asarray(character.pieces[0].faces, dtype=np.int64)]
        self.rest = self.to_display(character.vertices)
        self.template_rest = self.to_display(reg.template)
        ids = np.full(N_LANDMARKS, -1, dtype=np.int64) if landmarks is None else np.asarray(landmarks, np.int64)
        if ids.shape != (N_LANDMARKS,):
            raise InputError(f"the landmarks must be {N_LANDMARKS} head vertex ids, got shape {ids.shape}")
        missing = np.flatnonzero(ids < 0)
        if missing.size:
            want = reg.template[np.asarray(self.model.landmarks)[missing]]
            ids[missing] = closest_free_vertices(want, self.skin, character.vertices, taken=ids[ids >= 0])
        self.landmarks = ids
        self.initial_landmarks = ids.copy()
        x = self.model.neutral[:, 0]
        c = self.rest[:, 0]
        width = float(np.ptp(x))
        self.shifts = {"ict": np.zeros(3),
                       "character": np.array([float(x.max() - c.min()) + GAP * width, 0.0, 0.0])}
        self.radius = 0.009 * width

    def to_display(self, P) -> np.ndarray:
        """Head-frame points ``(..., 3)`` -> the model's frame (cm): ``R^T (P - t) / scale``."""
        r = self.character.registration
        return (np.asarray(P, dtype=np.float64) - r.t) @ r.R / r.scale

    def ict_delta(self) -> np.ndarray:
        """``(N, 3)`` the ICT face's displacement at the current weights, cm."""
        on = np.flatnonzero(self.weights)
        if on.size == 0:
            return np.zeros_like(self.model.neutral)
        return np.tensordot(self.weights[on], self.model.expression_deltas[self.ict_index[on]], axes=1)

    def head_delta(self) -> np.ndarray:
        """``(n, 3)`` the character's displacement at the current weights, head units and frame."""
        on = np.flatnonzero(self.weights)
        if on.size == 0:
            return np.zeros_like(self.character.vertices)
        return np.tensordot(self.weights[on], self.result.deltas[on], axes=1)

    def face(self, name: str) -> np.ndarray:
        """The face drawn as ``ict``, ``character`` or ``template`` (the overlay), model frame (cm), unshifted."""
        if name == "ict":
            return self.model.neutral + self.ict_delta()
        if name == "character":
            return self.to_display(self.character.vertices + self.head_delta())
        if name == "template":
            return self.template_rest + self.ict_delta()
        raise KeyError(name)

    def copies(self) -> list[str]:
        """The row, left to right."""
        return ["ict", "character"]

    def shown_faces(self) -> dict:
        """Copy name -> its face as drawn (shift included)."""
        return {n: self.face(n) + self.shifts[n] for n in self.copies()} if self._built else {}

    def landmark_points(self) -> np.ndarray:
        """``(68, 3)`` where the landmarks are drawn on the character (posed, shifted)."""
        return self.face("character")[self.landmarks] + self.shifts["character"]

    def region(self, k: int) -> str:
        """The iBUG region of landmark ``k`` (e.g. ``"outer lips"``)."""
        return next(name for a, b, name in LANDMARK_REGIONS if a <= k < b)

    def set_landmark(self, k: int, vertex: int) -> None:
        """Put landmark ``k`` on head vertex ``vertex`` (a skin vertex no other landmark uses) and select it."""
        k, vertex = int(k), int(vertex)
        if not 0 <= k < N_LANDMARKS:
            raise InputError(f"landmark {k} is out of range [0, {N_LANDMARKS})")
        if vertex not in self._skin_set:
            raise InputError(f"vertex {vertex} is not on the skin ({self.character.pieces[0].name!r})")
        holder = np.flatnonzero(self.landmarks == vertex)
        if holder.size and int(holder[0]) != k:
            raise InputError(f"vertex {vertex} already carries landmark {int(holder[0])}")
        self.landmark = k
        if self.landmarks[k] != vertex:
            self.landmarks[k] = vertex
            self.refresh()

    def move_landmark_to(self, k: int, point) -> int:
        """Put landmark ``k`` on the free skin vertex closest to ``point`` (display frame, shifted, as drawn).

        The drag lands here. Returns the vertex id.
        """
        P = self.face("character") + self.shifts["character"]
        others = np.delete(self.landmarks, int(k))
        v = int(closest_free_vertices(np.asarray(point, float)[None], self.skin, P, taken=others)[0])
        self.set_landmark(k, v)
        return v

    def save_landmarks(self, path=None) -> Path:
        """Write the 68 landmarks (``landmark,vertex_id``) to ``path`` (default: ``save_path``), atomically."""
        path = self.save_path if path is None else Path(path)
        if path is None:
            raise InputError("no file to save the landmarks to: start the viewer with --save-landmarks CSV")
        out = write_landmarks_csv(path, self.landmarks)
        self.saved += 1
        self.note(f"wrote {out} (68 landmarks)")
        return out

    def reregister(self) -> None:
        """Register and transfer again with the current landmarks (all 68 as correspondences).

        In background mode a worker process runs it and :meth:`poll` installs the
        result when it arrives (the panel shows "registering..." meanwhile);
        otherwise it runs here and blocks.
        """
        if self.job is not None and not self.job.done:
            self.note("a registration is already running")
            return
        ch = self.character
        options = dict(engine=self.engine, landmarks=self.landmarks.copy(), units=self.units, path=self.head_path,
                       parts=ch.parts, roles=self.roles or None)
        if self.background:
            self.job = RegisterJob(self.model, ch.vertices, ch.faces, **options)
            self.note("registering with the edited landmarks...")
            return
        t = time.perf_counter()
        new_ch, new_res = register_and_transfer(self.model, ch.vertices, ch.faces, progress=self.note, **options)
        self._finish(new_ch, new_res, options["landmarks"], time.perf_counter() - t)

    def _finish(self, character, result, landmarks, seconds) -> None:
        self.install(character, result, landmarks)
        self.registrations += 1
        self.note(f"registered again with the edited landmarks ({seconds:.1f} s)")
        self.rebuild_structures()

    def poll(self) -> bool:
        """Install a finished background registration (or report its failure); never blocks.
        Returns whether the view changed."""
        if self.job is None or not self.job.poll():
            return False
        job, self.job = self.job, None
        if job.error is not None:
            self.note(f"registration failed: {job.error}")
            return False
        ch, res = job.result
        self._finish(ch, res, self.landmarks.copy(), job.seconds())
        return True

    def registering(self) -> bool:
        """Whether a background registration is running."""
        return self.job is not None and not self.job.done

    def pending(self) -> list[str]:
        """``["registration"]`` while a background registration runs."""
        return ["registration"] if self.registering() else []

    def wait(self, timeout: float | None = 300.0) -> None:
        """Poll until a background registration has finished (and is installed)."""
        t = time.monotonic()
        while self.registering() and (timeout is None or time.monotonic() - t < timeout):
            self.poll()
            time.sleep(0.02)
        self.poll()

    def close(self) -> None:
        """Stop a running registration's worker."""
        if self.job is not None:
            self.job.close()
            self.job = None

    # ------------------------------------------------------------------ scene
    def build(self) -> None:
        """Register the ICT face, the character, the template overlay and both sets of landmarks."""
        import polyscope as ps

        self._built = True
        F = self.model.triangles
        self.mesh("ict", self.face("ict"), F, self.shifts["ict"])
        self.mesh("character", self.face("character"), self.character.faces, self.shifts["character"])
        ps.set_transparency_mode("simple")
        ov = self.mesh("template", self.face("template"), F, self.shifts["character"], color=OVERLAY_COLOR)
        ov.set_transparency(OVERLAY_OPACITY)
        ov.set_material("flat")
        ict_lm = self.points("ict landmarks", self.face("ict")[self.model.landmarks], self.shifts["ict"],
                             color=ICT_LANDMARK_COLOR)
        ict_lm.set_radius(self.radius * 0.8, relative=False)
        pc = self.points("landmarks", self.landmark_points(), np.zeros(3))
        pc.set_radius(self.radius, relative=False)
        self.refresh()

    def rebuild_structures(self) -> None:
        """Register every structure again after a re-registration, keeping the camera."""
        import polyscope as ps

        if not ps.is_initialized() or not self._built:
            return
        ps.remove_all_structures()
        self._bounds = None
        self.build()

    def refresh(self) -> None:
        """Push the posed faces, the overlay, the landmarks and the colours (mm) to polyscope."""
        import polyscope as ps

        if not ps.is_initialized() or not self._built or not ps.has_surface_mesh("character"):
            return
        d_ict = self.ict_delta()
        m = ps.get_surface_mesh("ict")
        m.update_vertex_positions(self.model.neutral + d_ict + self.shifts["ict"])
        self.error_colors(m, np.linalg.norm(d_ict, axis=1) * CM_TO_MM, self.vmax, name="displacement (mm)")
        d_head = self.head_delta()
        c = ps.get_surface_mesh("character")
        c.update_vertex_positions(self.to_display(self.character.vertices + d_head) + self.shifts["character"])
        self.error_colors(c, np.linalg.norm(d_head, axis=1) * self.reg.mm_per_unit, self.vmax,
                          name="displacement (mm)")
        ov = ps.get_surface_mesh("template")
        ov.update_vertex_positions(self.template_rest + d_ict + self.shifts["character"])
        ov.set_enabled(self.overlay)
        il = ps.get_point_cloud("ict landmarks")
        il.update_point_positions((self.model.neutral + d_ict)[self.model.landmarks] + self.shifts["ict"])
        il.set_enabled(self.show_landmarks)
        pc = ps.get_point_cloud("landmarks")
        pc.update_point_positions(self.landmark_points())
        colors = np.tile(MARKER_COLOR, (N_LANDMARKS, 1))
        colors[self.landmark] = SELECTED_COLOR
        pc.add_color_quantity("selected", colors, enabled=True)
        pc.set_enabled(self.show_landmarks)

    def set_overlay(self, on: bool) -> None:
        """Show or hide the registered template over the character."""
        self.overlay = bool(on)
        self.refresh()

    # ------------------------------------------------------------------ mouse
    def landmark_at(self, screen_xy, radius_px: float = PICK_PX):
        """The landmark nearest to window pixel ``screen_xy`` within ``radius_px`` (on the character), or None."""
        if not self.show_landmarks:
            return None
        xy = self.world_to_screen(self.landmark_points())
        d = np.linalg.norm(xy - np.asarray(screen_xy, float), axis=1)
        i = int(np.argmin(d))
        return i if d[i] <= radius_px else None

    def surface_point(self, screen_xy):
        """Where the camera ray through ``screen_xy`` first meets the character as drawn (any piece), or None."""
        o, d = self.screen_ray(screen_xy)
        P = self.face("character") + self.shifts["character"]
        T = P[np.asarray(self.character.faces)]
        a, e1, e2 = T[:, 0], T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]
        p = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, p)
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = o - a
        u = np.einsum("ij,ij->i", s, p) * inv
        q = np.cross(s, e1)
        v = (q @ d) * inv
        t = np.einsum("ij,ij->i", e2, q) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        if not hit.any():
            return None
        j = np.flatnonzero(hit)[np.argmin(t[hit])]
        return o + d * t[j]

    def begin_drag(self, screen_xy) -> bool:
        """Grab the landmark within :data:`PICK_PX` pixels of ``screen_xy``: select it and start dragging (the
        camera ignores the mouse until :meth:`end_drag`). Returns whether it did."""
        import polyscope as ps

        k = self.landmark_at(screen_xy)
        if k is None:
            return False
        n = np.asarray(ps.get_view_camera_parameters().get_look_dir(), float)
        self._drag = (k, self.landmark_points()[k], n)
        self.landmark = k
        ps.set_do_default_mouse_interaction(False)
        self.refresh()
        return True

    def drag_to(self, screen_xy) -> None:
        """Move the dragged landmark to the skin vertex under ``screen_xy``: the closest free skin vertex to where
        the camera ray meets the head; off the head, to where it meets the plane through the landmark facing
        the camera (the landmark slides along the outline)."""
        if self._drag is None:
            return
        k, anchor, n = self._drag
        point = self.surface_point(screen_xy)
        if point is None:
            o, d = self.screen_ray(screen_xy)
            denom = float(d @ n)
            if abs(denom) < 1e-9:
                return
            point = o + d * float((anchor - o) @ n) / denom
        self.move_landmark_to(k, point)

    def end_drag(self, screen_xy=None) -> None:
        """Finish the drag (at ``screen_xy`` if given) and give the mouse back to polyscope's camera."""
        import polyscope as ps

        if self._drag is not None and screen_xy is not None:
            self.drag_to(screen_xy)
        if self._drag is not None:
            self.drags += 1
        self._drag = None
        ps.set_do_default_mouse_interaction(True)

    def handle_mouse(self) -> None:
        """Landmark dragging, once per frame (as :meth:`facegeom.viewer.drive.DriveView.handle_mouse`: a press on a
        landmark switches the camera's mouse handling off in time; elsewhere the camera works as usual)."""
        import polyscope.imgui as psim

        io = psim.GetIO()
        self.hover = None
        if self._drag is None:
            if not io.WantCaptureMouse:
                self.hover = self.landmark_at(io.MousePos)
                if psim.IsMouseClicked(0):
                    self.begin_drag(io.MouseClickedPos[0])
            if self.hover is not None or self._drag is not None:
                psim.SetMouseCursor(psim.ImGuiMouseCursor_Hand)
        elif psim.IsMouseDown(0):
            self.drag_to(io.MousePos)
            psim.SetMouseCursor(psim.ImGuiMouseCursor_Hand)
        else:
            self.end_drag(io.MousePos)

    def draw_rings(self) -> None:
        """Rings around the selected landmark (magenta) and the one under the mouse (black)."""
        import polyscope.imgui as psim

        if not self.show_landmarks or not self._built:
            return
        dl = psim.GetBackgroundDrawList()
        P = self.landmark_points()
        p = self.world_to_screen(P[self.landmark])
        dl.AddCircle((float(p[0]), float(p[1])), 7.0, color_u32(SELECTED_COLOR), 0, 2.0)
        if self.hover is not None:
            p = self.world_to_screen(P[self.hover])
            dl.AddCircle((float(p[0]), float(p[1])), PICK_PX, color_u32((0.05, 0.05, 0.05)), 0, 2.5)

    # ------------------------------------------------------------------ panel
    def callback(self) -> None:
        """A finished registration installed, :meth:`BaseView.callback`, then the mouse and the rings."""
        if self.background:
            self.poll()
        super().callback()
        if not self.frozen:
            self.handle_mouse()
        self.draw_rings()

    def panel(self) -> None:
        """The registration's summary, the display options, the landmarks (select, save, re-register), the shapes."""
        import polyscope.imgui as psim

        ui, ch, reg = self.ui, self.character, self.reg
        nr = reg.report.get("nonrigid", {})
        psim.TextWrapped(f"{self.head_name}: {ch.vertices.shape[0]} vertices, {len(ch.pieces)} piece"
                         f"{'s' if len(ch.pieces) != 1 else ''}; engine {self.engine}")
        if "median_mm" in nr:
            psim.TextWrapped(f"registered template -> head (face area): median {nr['median_mm']:.2f} mm, "
                             f"95% {nr.get('p95_mm', float('nan')):.2f} mm")
        psim.TextWrapped("left: the ICT template | right: the character (transferred shapes), drawn in the ICT "
                         "frame; colour: displacement from the neutral (mm)")
        if self.color_max_slider():
            self.refresh()
        changed, on = ui.checkbox("registered template over the character", self.overlay)
        if changed:
            self.set_overlay(on)
        changed, on = ui.checkbox("landmarks", self.show_landmarks)
        if changed:
            self.show_landmarks = bool(on)
            self.refresh()
        psim.Separator()

        if psim.CollapsingHeader("Landmarks", psim.ImGuiTreeNodeFlags_DefaultOpen):
            psim.TextWrapped("Drag a landmark over the character's skin with the left mouse button (it snaps to the "
                             "closest skin vertex), or pick one here:")
            changed, v = ui.slider_int("landmark", self.landmark, 0, N_LANDMARKS - 1)
            if changed:
                self.landmark = int(np.clip(v, 0, N_LANDMARKS - 1))
                self.refresh()
            k = self.landmark
            moved = int(np.count_nonzero(self.landmarks != self.initial_landmarks))
            psim.TextUnformatted(f"{k}: {self.region(k)}, vertex {int(self.landmarks[k])}; {moved} moved")
            if self.save_path is not None:
                if ui.button("save landmarks"):
                    self.save_landmarks()
                psim.SameLine()
                psim.TextUnformatted(str(self.save_path.name))
            else:
                psim.TextWrapped("to save them, start with --save-landmarks CSV (the file "
                                 "`facegeom transfer --landmarks` reads)")
            if self.registering():
                job = self.job
                psim.TextColored((0.95, 0.6, 0.1, 1.0), f"registering... {job.seconds():.1f} s")
                if job.lines:
                    psim.TextWrapped(job.lines[-1])
            elif ui.button("re-register with these landmarks"):
                self.reregister()
        psim.Separator()
        if psim.CollapsingHeader("Shapes (ICT names)", psim.ImGuiTreeNodeFlags_DefaultOpen):
            self.shapes_panel()

    def state(self) -> dict:
        """:meth:`_ShapeSlidersView.state` plus ``landmarks`` (68 head vertex ids), ``landmark`` (selected),
        ``hover``, ``dragging``, ``drags``, ``overlay``, ``registering``, ``registrations`` (done so far),
        ``saved``, ``save_path`` and ``landmarks_px`` (68 window pixels x, y of the drawn landmarks, so a
        script can grab one)."""
        import polyscope as ps

        out = super().state()
        if ps.is_initialized() and self._built:
            out["landmarks_px"] = np.round(self.world_to_screen(self.landmark_points()), 2).tolist()
        out.update(landmarks=self.landmarks.tolist(), landmark=int(self.landmark), hover=self.hover,
                   dragging=self._drag is not None, drags=self.drags, overlay=self.overlay,
                   registering=self.registering(), registrations=self.registrations, saved=self.saved,
                   save_path=None if self.save_path is None else str(self.save_path))
        return out
