"""``facegeom view character --route markers``: a take on the actor beside any head driven through markers, the
key frames' labels edited with the mouse.

The tangent framework's route (:mod:`facegeom.pipelines.character_markers`, what
``facegeom animate --character HEAD --route markers`` writes): the head is
registered once when the view opens, markers are placed on it, the actor's
markers are retargeted onto them from a few key frames' labels and the head's
mesh is driven through its markers every frame.

Row, left to right: ``actor`` (the generic ICT face playing the take's ICT
weights) | ``character`` (the head driven by the route, shown in the model's
frame: the registration's similarity undone, so any head faces the camera like
the actor). Both are coloured by their displacement from their own neutral (mm,
one scale); playback runs in real time, the frame slider scrubs.

Editing the labels: on a key frame, paused, the character's markers are drawn
(orange: proposed, blue: edited) and a marker is dragged with the mouse in the
plane facing the camera (:class:`~facegeom.viewer.dragging.MarkerDragging`).
The key frame shows the head driven by the new label positions at once; the
retargeter is fitted again for every frame in a worker thread
(:meth:`~facegeom.pipelines.character_markers.MarkerRoute.relabel`, a fraction
of a second: numpy and the factorizations release the GIL, the window keeps
drawing) and playback goes on with the old route until the new one arrives.
"save labels" (or the ``s`` key) writes every marker of every key frame to a
key-labels CSV (:mod:`facegeom.io.key_labels`), what ``facegeom animate --route
markers --key-labels`` reads.
"""
from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np

from facegeom.errors import FacegeomError, InputError
from facegeom.io.key_labels import write_key_labels
from facegeom.pipelines.character_markers import (key_labels_comment, markers_onto_character, resolve_keys,
                                                  take_markers)
from facegeom.pipelines.solve import take_fps
from facegeom.viewer.app import MARKER_COLOR, SELECTED_COLOR
from facegeom.viewer.character import TakeView, as_take
from facegeom.viewer.dragging import MarkerDragging

__all__ = ["MarkerCharacterView", "EDITED_COLOR", "DEFAULT_SAVE_PATH"]

EDITED_COLOR = (0.1, 0.45, 0.95)  # a marker moved from its proposal
DEFAULT_SAVE_PATH = "key-labels.csv"  # in the current folder, without --save-key-labels
KEYS_PER_ROW = 6  # "key k" buttons on one line of the panel
EDIT_MM = 1e-3  # a label read from a file counts as edited when it is this far (mm) from the proposal


class MarkerCharacterView(MarkerDragging, TakeView):
    """Actor | a head driven through markers retargeted from key frames whose labels the mouse edits.

    Parameters
    ----------
    model : FaceModel
        The ICT face model (the actor, the markers' layout, the registration's template).
    take : str, PathLike or facegeom.io.takes.Take
        A Live Link take.
    head_vertices : (n, 3) float array
        The head, in its own units and axes (e.g. from :func:`facegeom.cli.transfer.read_head`).
    head_faces : (m, 3) int array
    start : int
        First frame of the take played.
    frames : int, optional
        Frames played; default: the rest of the take from ``start``.
    frame : int
        The frame of the window shown first.
    keys : sequence of int, optional
        Key frames, take frames (as ``--keys F1,F2,...``); with the frames of ``key_labels``, the key frames.
        Neither: ``n_keys`` chosen by :func:`~facegeom.pipelines.character_markers.key_frames`.
    n_keys : int
        Key frames chosen when neither ``keys`` nor ``key_labels`` gives any.
    key_labels : facegeom.io.key_labels.KeyLabels, optional
        Labels read from a key-labels file (:func:`~facegeom.io.key_labels.read_key_labels`): its markers
        replace the proposal (those away from it count as edited); a file made for another head is refused.
    parts, roles
        The head's pieces, as :func:`~facegeom.methods.transfer.register_character` takes them.
    character : Character, optional
        The head already registered (the registration is skipped).
    character_name : str, optional
        How the panel and the saved labels name the head.
    save_path : str or PathLike, optional
        Where "save labels" writes (default :data:`DEFAULT_SAVE_PATH` in the current folder).
    progress, echo : callable, optional
        Lines of the registration and the route; what a save says (default ``print``).

    Raises
    ------
    InputError
        The window outside the take, ``frame`` outside the window, bad key frames or labels, a head the
        registration cannot use.
    """

    def __init__(self, model, take, head_vertices, head_faces, start: int = 0, frames: int | None = None,
                 frame: int = 0, keys=(), n_keys: int = 10, key_labels=None, parts=None, roles=None,
                 character=None, character_name: str | None = None, save_path=None, progress=None, echo=print):
        tk = as_take(take)
        X, X0, ids = take_markers(model, tk, start, frames)  # checks the window
        T = X.shape[0]
        self.check_frame(frame, T)  # before the registration's seconds are spent
        rel, labels = resolve_keys(key_labels, keys or (), start, start + T, len(ids))
        route = markers_onto_character(model, X, X0, ids, head_vertices, head_faces, keys=rel, n_keys=n_keys,
                                       labels=labels, parts=parts, roles=roles, progress=progress,
                                       character=character, first_frame=start,
                                       labels_path=None if key_labels is None else key_labels.path)
        if key_labels is not None:
            key_labels.check_vertices(route.marker_vertices)
        super().__init__(model, tk, T, start, frame, take_fps(tk))
        self.route = route
        self.echo = echo
        self.character_name = character_name or "character"
        self.save_path = Path(DEFAULT_SAVE_PATH if save_path is None else save_path).absolute()
        self.saved: str | None = None  # what the last save wrote (the panel says it)
        reg = route.character.registration
        self.registration = reg
        self.character_triangles = np.asarray(route.character.faces)
        self.neutral = self.to_display(route.character.vertices)  # (n, 3) model frame, cm
        self.keys = np.asarray(route.key_frames, dtype=np.int64)  # (L,) frames of the window
        self.labels = np.array(route.labels, dtype=np.float64)  # (L, p, 3) head units, what the user edits
        moved = np.linalg.norm(self.labels - route.proposed, axis=2) * reg.mm_per_unit > EDIT_MM
        self.edited = moved  # (L, p) markers moved from their proposal (a file's too, when they differ)
        self.version = 0  # bumped by every label change
        self.route_version = 0  # the labels' version the route was fitted with
        self._failed_version: int | None = None
        self._thread: threading.Thread | None = None
        self._job: tuple | None = None
        self.refit_s: float | None = None  # seconds of the last refit
        self.refits = 0  # refits installed
        self.failed: str | None = None
        self._cache: tuple = (None, None, None)  # (route id, frame, version), the head there, the route
        self._drag_key: int | None = None
        self.marker, self.hover, self.drags = 0, None, 0
        lo, hi = float(self.neutral[:, 0].min()), float(self.neutral[:, 0].max())
        self.shifts = self.row_shifts(self.neutral, lo, hi)
        self.radius = 0.011 * (hi - lo)  # the markers' radius (cm), as the other views'
        self.vmax = self._scale()

    # ------------------------------------------------------------------ the head
    def to_display(self, P) -> np.ndarray:
        """Head points ``(..., 3)`` (its units and axes) -> the model's frame (cm): ``R^T (P - t) / scale``."""
        r = self.registration
        return (np.asarray(P, dtype=np.float64) - r.t) @ r.R / r.scale

    def key_index(self, t: int | None = None) -> int | None:
        """The index of frame ``t`` (default: the current one) among the key frames, or None."""
        i = np.flatnonzero(self.keys == self._frame(t))
        return int(i[0]) if i.size else None

    def editable_key(self) -> int | None:
        """The key frame whose markers the mouse can move now: the current frame's, while paused; else None."""
        return None if self.playing else self.key_index()

    def stale(self, k: int) -> bool:
        """Whether key ``k``'s labels changed since the route was fitted (its new retargeting is not in yet)."""
        return not np.array_equal(self.labels[k], self.route.labels[k])

    def head_face(self, t: int | None = None) -> np.ndarray:
        """The head at frame ``t``, its units and axes, ``(n, 3)``: driven by the route, or at a key frame whose
        labels changed since, driven by those labels directly (the edit shows before the retargeting is in)."""
        t = self._frame(t)
        k = self.key_index(t)
        fresh = k is None or not self.stale(k)
        key = (id(self.route), t, -1 if fresh else self.version)  # the cache holds the route: its id stays its
        if self._cache[0] != key:
            V = self.route.drive(t, t + 1)[0] if fresh else self.route.deform(self.labels[k][None])[0]
            self._cache = (key, V, self.route)
        return self._cache[1]

    def character_face(self, t: int | None = None) -> np.ndarray:
        """The character at frame ``t`` as drawn (without the row shift): :meth:`head_face` in the model's frame,
        ``(n, 3)`` cm."""
        return self.to_display(self.head_face(t))

    def character_displacement_mm(self, t: int | None = None) -> np.ndarray:
        """Per-vertex distance of the head from its neutral at frame ``t``, in the head's own mm, ``(n,)``."""
        d = self.head_face(t) - self.route.character.vertices
        return np.linalg.norm(d, axis=1) * self.registration.mm_per_unit

    def marker_points(self, k: int) -> np.ndarray:
        """Key ``k``'s labels as drawn on the character (row shift included), ``(p, 3)`` cm."""
        return self.to_display(self.labels[k]) + self.shifts["character"]

    # ------------------------------------------------------------------ editing
    def _check(self, k: int, m: int | None = None) -> None:
        L, p = self.edited.shape
        if not 0 <= int(k) < L:
            raise InputError(f"key {k} is out of range [0, {L})")
        if m is not None and not 0 <= int(m) < p:
            raise InputError(f"marker index {m} is out of range [0, {p})")

    def _changed(self) -> None:
        """The labels changed: a new version, a refit asked for, the frame redrawn."""
        self.version += 1
        self.refit()
        self.show_frame()

    def set_label(self, k: int, m: int, position) -> None:
        """Put marker ``m`` of key ``k`` at ``position (3,)`` (head units): it counts as edited, the key frame
        shows it at once and the route is refitted in the background. Drags land here."""
        self._check(k, m)
        P = np.asarray(position, dtype=np.float64).reshape(3)
        if not np.isfinite(P).all():
            raise InputError("a label must be a finite position")
        self.labels[k, m] = P
        self.edited[k, m] = True
        self.marker = int(m)
        self._changed()

    def reset_marker(self, k: int | None = None, m: int | None = None) -> None:
        """Marker ``m`` (default: the selected one) of key ``k`` (default: the current one) back to its proposal."""
        k = self.key_index() if k is None else k
        m = self.marker if m is None else m
        if k is None:
            return
        self._check(k, m)
        self.labels[k, m] = self.route.proposed[k, m]
        self.edited[k, m] = False
        self._changed()

    def reset_key(self, k: int | None = None) -> None:
        """Every marker of key ``k`` (default: the current one) back to its proposal."""
        k = self.key_index() if k is None else k
        if k is None:
            return
        self._check(k)
        self.labels[k] = self.route.proposed[k]
        self.edited[k] = False
        self._changed()

    def go_to_key(self, k: int) -> None:
        """Pause on key frame ``k`` (wrapped over the keys), where its markers can be dragged."""
        self.play(False)
        self.set_frame(int(self.keys[int(k) % self.keys.size]))

    def step_key(self, step: int) -> None:
        """Pause on the next (``step=1``) or previous (``-1``) key frame from the current frame (wrapping)."""
        t = self.frame
        after = np.flatnonzero(self.keys > t) if step > 0 else np.flatnonzero(self.keys < t)
        if after.size:
            self.go_to_key(int(after[0] if step > 0 else after[-1]))
        else:
            self.go_to_key(0 if step > 0 else -1)

    # ------------------------------------------------------------------ the retargeting worker
    def refit(self) -> None:
        """Fit the route again for the newest labels in a worker thread, unless one is running (the newest labels
        go when it ends) or the route has them already. Never blocks."""
        if self._thread is not None or self.version in (self.route_version, self._failed_version):
            return
        route, labels, version, box = self.route, self.labels.copy(), self.version, {}

        def work():
            try:
                box["route"] = route.relabel(labels)
            except FacegeomError as exc:
                box["error"] = str(exc)
            except Exception as exc:  # noqa: BLE001 - a bug is reported in the panel, the window stays up
                box["error"] = f"{type(exc).__name__}: {exc}"

        self._job = (version, box, time.perf_counter())
        self._thread = threading.Thread(target=work, daemon=True, name="facegeom-relabel")
        self._thread.start()

    def poll(self) -> bool:
        """Install a finished refit (the view swaps to the new route), start the next one if the labels changed
        meanwhile. Never blocks. Returns whether the route changed."""
        if self._thread is None or self._thread.is_alive():
            return False
        self._thread.join()
        version, box, t0 = self._job
        self._thread = self._job = None
        changed = "route" in box
        if changed:
            self.route, self.route_version = box["route"], version
            self.refit_s, self.failed = time.perf_counter() - t0, None
            self.refits += 1
        else:
            self._failed_version, self.failed = version, box["error"]
            self.note(f"error: the retargeting failed: {box['error']}")
        self.refit()
        if changed:
            self.show_frame()
        return changed

    def refitting(self) -> bool:
        """Whether a refit is running or the route is behind the labels (one will start)."""
        return self._thread is not None or self.version not in (self.route_version, self._failed_version)

    def pending(self) -> list[str]:
        """``["retarget"]`` while the route is behind the labels."""
        return ["retarget"] if self.refitting() else []

    def busy(self) -> bool:
        """Never: a refit is a fraction of a second in a thread of this process, the frame rate is not capped."""
        return False

    def wait(self, timeout: float | None = 60.0) -> None:
        """Block until the route has the newest labels (or ``timeout`` seconds pass)."""
        t = time.monotonic()
        while self.refitting() and (timeout is None or time.monotonic() - t < timeout):
            self.refit()
            if self._thread is not None:
                self._thread.join(0.01)
            self.poll()

    def close(self) -> None:
        """Let a running refit end (a few seconds at most; the thread is a daemon)."""
        if self._thread is not None:
            self._thread.join(5.0)

    # ------------------------------------------------------------------ saving
    def save_labels(self, path=None) -> Path:
        """Write every marker of every key frame (take frames: key + start) to the key-labels CSV ``path``
        (default :attr:`save_path`), with the marker vertices; says where on the terminal and in the panel."""
        path = Path(self.save_path if path is None else path)
        take_name = Path(self.take.path).name
        write_key_labels(path, self.keys + self.start, self.labels, self.route.marker_vertices,
                         comment=key_labels_comment(self.character_name, self.neutral.shape[0], take_name))
        self.saved = f"wrote {path.absolute()} ({self.keys.size} key frames x {self.labels.shape[1]} markers, " \
                     f"{int(self.edited.sum())} edited)"
        self.echo(self.saved)
        return path

    def _save_from_panel(self) -> None:
        try:
            self.save_labels()
        except (FacegeomError, OSError) as exc:
            self.saved = None
            self.note(f"error: the labels could not be saved: {exc}")

    # ------------------------------------------------------------------ dragging (MarkerDragging's hooks)
    def marker_screen(self) -> dict:
        """``{"character": (p, 2)}`` window pixels of the markers that can be grabbed: the current key frame's
        while paused; ``{}`` elsewhere."""
        k = self.editable_key()
        if k is None or not self._built:
            return {}
        return {"character": self.world_to_screen(self.marker_points(k))}

    def marker_world(self, name: str, m: int) -> np.ndarray:
        """Marker ``m`` as drawn on the character, ``(3,)`` cm."""
        return self.marker_points(self.editable_key())[m]

    def drag_value(self, m: int) -> np.ndarray:
        """What a drag of marker ``m`` changes: its label at the current key frame (head units), at the press."""
        self._drag_key = self.editable_key()
        return self.labels[self._drag_key, m].copy()

    def drag_set(self, m: int, start, delta) -> None:
        """A drag moved marker ``m`` by ``delta`` (cm, the model's frame) since the press: its label becomes
        ``start`` plus that motion in the head's frame and units."""
        new = start + self.registration.delta_in_head(delta)
        if self._drag_key is not None and not np.array_equal(new, self.labels[self._drag_key, m]):
            self.set_label(self._drag_key, m, new)

    # ------------------------------------------------------------------ polyscope
    def build(self) -> None:
        """:meth:`TakeView.build`, and the markers (shown on a key frame while paused)."""
        super().build()
        k = self.key_index(self.frame)
        self.points("markers", self.to_display(self.labels[0 if k is None else k]), self.shifts["character"],
                    color=MARKER_COLOR, radius=self.radius)
        self.refresh()

    def show_frame(self) -> None:
        """Both faces at the current frame (:meth:`TakeView.show_frame`), then the markers (:meth:`refresh`)."""
        super().show_frame()
        self.refresh()

    def refresh(self) -> None:
        """The markers: drawn at the current key frame's labels while paused there (orange proposed, blue edited,
        magenta the selected one), hidden elsewhere."""
        import polyscope as ps

        if not ps.is_initialized() or not self._built or not ps.has_point_cloud("markers"):
            return
        pc = ps.get_point_cloud("markers")
        k = self.editable_key()
        pc.set_enabled(k is not None)
        if k is None:
            return
        pc.update_point_positions(self.marker_points(k))
        colors = np.where(self.edited[k][:, None], np.asarray(EDITED_COLOR), np.asarray(MARKER_COLOR))
        colors[self.marker] = SELECTED_COLOR
        pc.add_color_quantity("edited", colors, enabled=True)

    def play(self, on: bool = True) -> None:
        """:meth:`TakeView.play`; the markers show only while paused on a key frame (a drag ends)."""
        if on and self._drag is not None:
            self.end_drag()
        super().play(on)
        self.refresh()

    # ------------------------------------------------------------------ panel
    def callback(self) -> None:
        """A finished refit installed, :meth:`BaseView.callback`, then the mouse, the keys and the marker rings."""
        self.poll()
        super().callback()
        if not self.frozen:
            self.handle_mouse()
            self.handle_keys()
        self.draw_marker_rings()

    def handle_keys(self) -> None:
        """``s`` saves the labels (not while a widget has the keyboard)."""
        import polyscope.imgui as psim

        if psim.GetIO().WantCaptureKeyboard or self._drag is not None:
            return
        if psim.IsKeyPressed(psim.ImGuiKey_S, False):
            self._save_from_panel()

    def panel(self) -> None:
        """The take and the head, the colour scale, the playback controls, the key frames (go to one, step), the
        editing of the current key's markers, the retargeting's state and the save button."""
        import polyscope.imgui as psim

        ui, t = self.ui, self.frame
        psim.TextWrapped(self.take_text())
        psim.TextWrapped(f"{self.character_name}: {self.neutral.shape[0]} vertices, driven through "
                         f"{self.labels.shape[1]} markers retargeted from {self.keys.size} key frames")
        psim.TextWrapped("left to right: actor (the ICT face, the take's ICT weights) | character (the head driven "
                         "through its markers: the tangent framework's route)")
        psim.TextUnformatted("colour: displacement from the neutral (mm), one scale")
        if self.color_max_slider():
            self.show_frame()
        self.playback_panel()
        k = self.key_index()
        psim.TextUnformatted(f"frame {t} (take frame {self.start + t}), {self.time_s():.2f} s"
                             + ("" if k is None else f": key {k}"))
        psim.Separator()
        if psim.CollapsingHeader("Key frames", psim.ImGuiTreeNodeFlags_DefaultOpen):
            if ui.button("< prev key"):
                self.step_key(-1)
            psim.SameLine()
            if ui.button("next key >"):
                self.step_key(1)
            for i, f in enumerate(self.keys):
                if i % KEYS_PER_ROW:
                    psim.SameLine()
                if ui.button(f"key {i}"):
                    self.go_to_key(i)
                if psim.IsItemHovered():
                    psim.SetTooltip(f"frame {f} (take frame {self.start + f}), {int(self.edited[i].sum())} "
                                    f"markers edited")
            self.edit_panel()
        psim.Separator()
        if self.refitting():
            psim.TextColored((0.95, 0.6, 0.1, 1.0), "retargeting every frame for the new labels...")
        elif self.failed:
            psim.TextColored((1.0, 0.3, 0.3, 1.0), f"retargeting failed: {self.failed}")
        elif self.refit_s is not None:
            psim.TextUnformatted(f"retargeted for the edited labels in {self.refit_s:.2f} s")
        if ui.button("save labels"):
            self._save_from_panel()
        psim.SameLine()
        psim.TextUnformatted("(key s)")
        psim.TextWrapped(self.saved or f"writes {self.save_path} (every marker of every key frame)")

    def edit_panel(self) -> None:
        """The current key frame's markers: how to drag them, the selected one, the reset buttons."""
        import polyscope.imgui as psim

        ui, k = self.ui, self.editable_key()
        if k is None:
            psim.TextWrapped("pause on a key frame to drag its markers" if self.key_index() is not None
                             else "go to a key frame to edit its markers (orange: proposed, blue: edited)")
            return
        psim.TextWrapped(f"key {k}: drag a marker on the character with the left mouse button (a ring shows what a "
                         f"press grabs); {int(self.edited[k].sum())} of {self.labels.shape[1]} markers edited")
        m = self.marker
        moved = np.linalg.norm(self.labels[k, m] - self.route.proposed[k, m]) * self.registration.mm_per_unit
        psim.TextUnformatted(f"marker {m} (vertex {int(self.route.marker_vertices[m])}): {moved:.2f} mm from the "
                             f"proposal")
        if ui.button("reset marker"):
            self.reset_marker(k, m)
        psim.SameLine()
        if ui.button("reset key"):
            self.reset_key(k)

    def state(self) -> dict:
        """:meth:`TakeView.state` plus ``keys`` (window frames), ``key`` (the current frame's key or None),
        ``editable``, ``marker``, ``hover``, ``dragging``, ``drags``, ``edited`` (markers edited over all keys),
        ``edited_per_key``, ``busy`` (a refit running or due), ``refits``, ``refit_s``, ``failed`` and
        ``labels_path`` (where a save writes) and ``saved`` (what the last save wrote)."""
        out = super().state()
        out.update(keys=self.keys.tolist(), key=self.key_index(), editable=self.editable_key() is not None,
                   marker=int(self.marker), hover=self.hover, dragging=self._drag is not None, drags=self.drags,
                   edited=int(self.edited.sum()), edited_per_key=self.edited.sum(axis=1).tolist(),
                   busy=self.refitting(), refits=self.refits, refit_s=self.refit_s, failed=self.failed,
                   labels_path=str(self.save_path), saved=self.saved)
        return out
