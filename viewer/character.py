"""``facegeom view character``: a Live Link take on the actor beside the same take on the user's character.

Row, left to right:

- ``actor``: the generic ICT face (:meth:`facegeom.model.BlendshapeRig.from_face_model`)
  playing the take's ICT weights (:func:`facegeom.io.ict_weights`); it does not turn;
- ``character``: the user's rig playing the weights the name map gives it
  (:func:`facegeom.pipelines.character.take_onto_character`, what ``facegeom animate
  --take --character`` writes), turned by the frame's head rotation about the
  centroid of the rig's neutral.

Both are coloured by each vertex's displacement from their own neutral in mm
(the expression only: the head's turn moves no colour) on one shared scale.
Playback runs in real time at the take's frame rate (times the speed control);
the frame slider scrubs; the panel shows the frame's time in the take and the
five most active character shapes with their weights.

:class:`TakeView` is what this view shares with the marker route's
(:mod:`facegeom.viewer.character_markers`, ``--route markers``).
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from facegeom.constants import CM_TO_MM
from facegeom.errors import InputError
from facegeom.io.takes import ict_weights, read_take
from facegeom.model import BlendshapeRig
from facegeom.pipelines.character import take_onto_character
from facegeom.viewer.app import nice_ceiling
from facegeom.viewer.playback import PlaybackView, advance_in_real_time

__all__ = ["TakeView", "CharacterView", "SPEED_RANGE", "as_take"]

TOP = 5  # character shapes listed in the panel
GAP = 0.12  # space between the two faces, relative to the wider one's width
SPEED_RANGE = (0.1, 4.0)  # the speed control: times real time
SCALE_SAMPLES = 64  # frames sampled to choose the colour scale's maximum


def _center(V: np.ndarray) -> np.ndarray:
    return (V.min(axis=0) + V.max(axis=0)) / 2.0


def as_take(take):
    """A take given as a path (read with :func:`facegeom.io.takes.read_take`) or already read -> the ``Take``."""
    return read_take(take) if isinstance(take, (str, Path)) else take


class TakeView(PlaybackView):
    """A window of a Live Link take played in real time: the actor (the generic ICT face) | a character.

    What both routes of ``facegeom view character`` share: the actor playing the take's ICT weights, the
    row (the actor's neutral at the origin, the character to its right), the colours (each face's
    displacement from its own neutral in mm, one scale), real-time playback with scrubbing and a speed
    control. A subclass gives the character: :attr:`character_triangles`, :meth:`character_face` (as drawn,
    unshifted, cm) and :meth:`character_displacement_mm`, and sets :attr:`shifts` (:meth:`row_shifts`) and
    :attr:`vmax` (:meth:`_scale`) once they can be computed.

    Parameters
    ----------
    model : FaceModel
        The ICT face model: the actor is its generic face.
    take : facegeom.io.takes.Take
        The take, read.
    n_frames : int
        Frames of the window played.
    start : int
        Its first frame in the take.
    frame : int
        The frame of the window shown first, in ``[0, n_frames)``.
    fps : float
        The take's frame rate.

    Raises
    ------
    InputError
        ``frame`` outside the window.
    """

    title = "facegeom view character"
    colorbar_title = "displacement from the neutral (mm)"

    def __init__(self, model, take, n_frames: int, start: int, frame: int, fps: float):
        T = int(n_frames)
        self.check_frame(frame, T)
        super().__init__(T, frame)
        self.take, self.start = take, int(start)
        self.fps = float(fps)
        self.actor = BlendshapeRig.from_face_model(model)
        self.actor_weights = ict_weights(take, model.expression_names)[self.start:self.start + T]  # (T, E)
        self.times = np.asarray(take.times, dtype=np.float64)[self.start:self.start + T]
        self.speed = 1.0
        self._t0: float | None = None
        self._f0 = self.frame
        self.character_triangles = None  # (m, 3) the character's triangles: set by the subclass

    @staticmethod
    def check_frame(frame: int, n_frames: int) -> None:
        """Raise :class:`InputError` unless ``frame`` lies in the window of ``n_frames`` frames."""
        if not 0 <= int(frame) < int(n_frames):
            raise InputError(f"--frame {frame} is outside the window: it has {n_frames} frames (0..{n_frames - 1})")

    # ------------------------------------------------------------------ faces
    def row_shifts(self, character_neutral, lo: float, hi: float) -> dict:
        """Shifts putting the actor's neutral at the origin and the character (neutral ``(n, 3)`` cm, drawn over
        ``x in [lo, hi]`` at any frame) to its right, centres level."""
        A, C = np.asarray(self.actor.neutral), np.asarray(character_neutral, dtype=np.float64)
        wa = float(np.ptp(A[:, 0]))
        shift = -_center(C)
        shift[0] = wa / 2.0 + GAP * max(wa, hi - lo) - lo
        return {"actor": -_center(A), "character": shift}

    @staticmethod
    def _pose(rig, w) -> np.ndarray:
        """``neutral + w @ deltas`` over the shapes that are on -> ``(n, 3)`` cm."""
        on = np.flatnonzero(w)
        if on.size == 0:
            return np.array(rig.neutral, dtype=np.float64)
        return rig.neutral + np.tensordot(w[on], rig.deltas[on], axes=1)

    def _frame(self, t) -> int:
        return self.frame if t is None else int(t) % self.n_frames

    def actor_face(self, t: int | None = None) -> np.ndarray:
        """The actor at frame ``t`` (default: the current one): the ICT neutral plus the take's ICT weights
        times the ICT deltas, ``(n_actor, 3)`` cm, unshifted."""
        return self._pose(self.actor, self.actor_weights[self._frame(t)])

    def character_face(self, t: int | None = None) -> np.ndarray:  # pragma: no cover - overridden
        """The character at frame ``t`` as drawn (without the row shift), ``(n, 3)`` cm; every subclass's."""
        raise NotImplementedError

    def character_displacement_mm(self, t: int | None = None) -> np.ndarray:  # pragma: no cover - overridden
        """Per-vertex distance of the character from its neutral at frame ``t``, ``(n,)`` mm; every subclass's."""
        raise NotImplementedError

    def displacement_mm(self, t: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Per-vertex distance from the neutral at frame ``t`` (mm): ``(actor (n_actor,), character (n,))``."""
        t = self._frame(t)
        a = np.linalg.norm(self.actor_face(t) - self.actor.neutral, axis=1) * CM_TO_MM
        return a, self.character_displacement_mm(t)

    def _scale(self) -> float:
        """One colour scale for both faces: the 95th percentile, over up to 64 evenly spread frames, of the
        larger of the two faces' largest displacements, rounded up to 1, 2 or 5 times a power of ten."""
        peaks = []
        for t in np.unique(np.linspace(0, self.n_frames - 1, min(self.n_frames, SCALE_SAMPLES)).astype(int)):
            a, c = self.displacement_mm(int(t))
            peaks.append(max(float(a.max()), float(c.max())))
        top = float(np.percentile(peaks, 95)) if peaks else 0.0
        return nice_ceiling(top) if top > 0 else 5.0

    def time_s(self, t: int | None = None) -> float:
        """Seconds from the take's first row to frame ``t`` of the window (the take's own row times)."""
        t = self._frame(t)
        if self.times.size == self.n_frames and np.isfinite(self.times[t]):
            return float(self.times[t])
        return (self.start + t) / self.fps

    def copies(self) -> list[str]:
        """The faces of the row, left to right: ``actor``, ``character``."""
        return ["actor", "character"]

    def shown_faces(self) -> dict:
        """``actor`` and ``character`` -> their faces at the current frame as drawn (row shift included)."""
        if not self._built:
            return {}
        return {"actor": self.actor_face() + self.shifts["actor"],
                "character": self.character_face() + self.shifts["character"]}

    # ------------------------------------------------------------------ polyscope
    def build(self) -> None:
        """Register both faces at the current frame and frame the camera on them and the character's motion."""
        self._built = True
        self.mesh("actor", self.actor_face(), self.actor.triangles, self.shifts["actor"])
        self.mesh("character", self.character_face(), self.character_triangles, self.shifts["character"])
        for t in np.linspace(0, self.n_frames - 1, min(self.n_frames, 8)).astype(int):
            self._grow_bounds(self.character_face(int(t)) + self.shifts["character"])
        self.show_frame()

    def show_frame(self) -> None:
        """Move both faces to the current frame and colour them by their displacement (mm) on the shared
        scale. Does nothing before :meth:`build`."""
        import polyscope as ps

        if not ps.is_initialized() or not self._built or not ps.has_surface_mesh("character"):
            return
        a, c = self.displacement_mm()
        m = ps.get_surface_mesh("actor")
        m.update_vertex_positions(self.actor_face() + self.shifts["actor"])
        self.error_colors(m, a, self.vmax, name="displacement (mm)")
        m = ps.get_surface_mesh("character")
        m.update_vertex_positions(self.character_face() + self.shifts["character"])
        self.error_colors(m, c, self.vmax, name="displacement (mm)")

    # ------------------------------------------------------------------ playback
    def play(self, on: bool = True) -> None:
        """Start (``on=True``) or pause playback; playing keeps the take's frame rate (times :attr:`speed`)."""
        super().play(on)
        self._t0, self._f0 = (time.monotonic(), self.frame) if on else (None, self.frame)

    def set_speed(self, speed: float) -> None:
        """Playback speed, times real time (clipped to :data:`SPEED_RANGE`); the clock restarts at the frame."""
        lo, hi = SPEED_RANGE
        self.speed = float(min(max(float(speed), lo), hi))
        if self.playing:
            self._t0, self._f0 = time.monotonic(), self.frame

    def advance(self) -> None:
        """Real-time playback at the take's frame rate (:func:`~facegeom.viewer.playback.advance_in_real_time`)."""
        advance_in_real_time(self, self.fps)

    def set_frame(self, t: int) -> None:
        """Show frame ``t`` of the window (wrapped); while playing, the clock restarts there (slider, steps)."""
        super().set_frame(t)
        if self.playing:
            self._t0, self._f0 = time.monotonic(), self.frame

    def playback_panel(self) -> None:
        """Play/pause and one-frame steps, the frame slider (scrubbing) and the speed control (times real time)."""
        self.transport_panel()
        ch, v = self.ui.slider_float("speed", self.speed, *SPEED_RANGE, "%.2fx", logarithmic=True)
        if ch:
            self.set_speed(v)

    def take_text(self) -> str:
        """The panel's first line: the take, the window played and its length."""
        T = self.n_frames
        return (f"{Path(self.take.path).name}: frames {self.start}..{self.start + T - 1} of {self.take.n_frames} at "
                f"{self.fps:g} fps ({T / self.fps:.1f} s)")

    def state(self) -> dict:
        """:meth:`BaseView.state` plus ``frame``, ``n_frames``, ``fps``, ``speed``, ``playing`` and ``time_s``."""
        out = super().state()
        out.update(frame=self.frame, n_frames=self.n_frames, fps=self.fps, speed=self.speed, playing=self.playing,
                   time_s=self.time_s())
        return out


class CharacterView(TakeView):
    """Actor (the generic ICT face) | the user's character, one Live Link take played on both.

    Parameters
    ----------
    model : FaceModel
        The ICT face model: the actor is its generic face.
    take : str, PathLike or facegeom.io.takes.Take
        A Live Link take (read with :func:`facegeom.io.takes.read_take` when a path).
    character : BlendshapeRig
        The character's rig in facegeom's frame (cm, Y up), e.g. from :func:`facegeom.model.load_rig`;
        its name map (``--character-names``) decides how the take's ARKit weights drive its shapes.
    start : int
        First frame of the take played.
    frames : int, optional
        Frames played; default: the rest of the take from ``start``.
    frame : int
        The frame of the window shown first, in ``[0, frames)``.
    character_name : str, optional
        How the panel names the character (default: ``"character"``).

    Raises
    ------
    InputError
        ``start`` or the window outside the take, ``frame`` outside the window, a character none of whose
        shapes the take's names reach (from :func:`~facegeom.pipelines.character.take_onto_character`).
    """

    def __init__(self, model, take, character, start: int = 0, frames: int | None = None, frame: int = 0,
                 character_name: str | None = None):
        tk = as_take(take)
        played = take_onto_character(tk, character, start, frames)  # checks the window
        super().__init__(model, tk, played.solve.weights.shape[0], start, frame, played.fps)
        self.played = played
        self.notes = list(played.notes)
        self.character = character
        self.character_name = character_name or "character"
        self.character_triangles = character.triangles
        self.weights = np.asarray(played.solve.weights, dtype=np.float64)  # (T, K) the character's
        self.rotations = np.asarray(played.solve.rotations, dtype=np.float64)  # (T, 3, 3)
        self.names = list(played.solve.names)
        self.centroid = np.asarray(character.neutral, dtype=np.float64).mean(axis=0)  # the head turns about it
        self.turned_x = self._turned_x_range()
        lo, hi = self.turned_x  # far enough for the character's widest head turn
        self.shifts = self.row_shifts(character.neutral, lo + self.centroid[0], hi + self.centroid[0])
        self.vmax = self._scale()

    # ------------------------------------------------------------------ faces
    def _turned_x_range(self) -> tuple[float, float]:
        """The x range of the character's neutral about :attr:`centroid` over every frame's head rotation (cm):
        a turning head is wider than a still one, and must not run into the actor."""
        C = np.asarray(self.character.neutral, dtype=np.float64) - self.centroid
        rows = np.unique(np.round(self.rotations[:, 0, :], 4), axis=0)  # the x row of each frame's rotation
        lo, hi = float(C[:, 0].min()), float(C[:, 0].max())
        for i in range(0, rows.shape[0], 256):
            X = C @ rows[i:i + 256].T
            lo, hi = min(lo, float(X.min())), max(hi, float(X.max()))
        return lo, hi

    def character_pose(self, t: int | None = None) -> np.ndarray:
        """The character's expression at frame ``t``: ``neutral + weights[t] @ deltas``, ``(n, 3)`` cm, not turned."""
        return self._pose(self.character, self.weights[self._frame(t)])

    def character_face(self, t: int | None = None) -> np.ndarray:
        """The character at frame ``t`` as drawn (without the row shift): :meth:`character_pose` turned by the
        frame's head rotation ``R`` about :attr:`centroid`, ``c + (P - c) R^T``; ``(n, 3)`` cm."""
        t = self._frame(t)
        c = self.centroid
        return c + (self.character_pose(t) - c) @ self.rotations[t].T

    def character_displacement_mm(self, t: int | None = None) -> np.ndarray:
        """Per-vertex distance of :meth:`character_pose` from the neutral (mm), ``(n,)``: the expression only,
        the head turn is not counted."""
        return np.linalg.norm(self.character_pose(t) - self.character.neutral, axis=1) * CM_TO_MM

    def top_shapes(self, t: int | None = None, k: int = TOP) -> list[tuple[str, float]]:
        """The ``k`` character shapes with the largest weights at frame ``t`` (only those above 0.001):
        ``[(name, weight), ...]``, largest first."""
        w = self.weights[self._frame(t)]
        order = np.argsort(-w, kind="stable")[:k]
        return [(self.names[i], float(w[i])) for i in order if w[i] > 1e-3]

    # ------------------------------------------------------------------ polyscope
    def build(self) -> None:
        """:meth:`TakeView.build`, the character's widest head turn framed too."""
        super().build()
        lo, hi = self.turned_x
        self._grow_bounds(self.centroid + self.shifts["character"] + np.array([[lo, 0.0, 0.0], [hi, 0.0, 0.0]]))

    def panel(self) -> None:
        """The take and the character, the colour scale, the playback controls, the frame's time and head
        turn, and the five most active character shapes as bars with their weights."""
        import polyscope.imgui as psim

        t = self.frame
        psim.TextWrapped(self.take_text())
        ch = self.character
        psim.TextWrapped(f"{self.character_name}: {ch.n_shapes} shapes, {ch.n_vertices} vertices"
                         + (f", {len(ch.parts)} parts" if ch.parts else ""))
        psim.TextWrapped("left to right: actor (the ICT face, the take's ICT weights) | character (its rig, the "
                         "mapped weights, turned by the head rotation)")
        psim.TextUnformatted("colour: displacement from the neutral (mm), one scale")
        if self.color_max_slider():
            self.show_frame()
        self.playback_panel()
        psim.TextUnformatted(f"frame {t} (take frame {self.start + t}), {self.time_s():.2f} s")
        angle = np.degrees(np.arccos(np.clip((np.trace(self.rotations[t]) - 1.0) / 2.0, -1.0, 1.0)))
        psim.TextUnformatted(f"head turned {angle:.1f} deg")
        psim.Separator()
        top = self.top_shapes()
        if not top:
            psim.TextUnformatted("no character shape on (the neutral)")
        for name, w in top:
            psim.ProgressBar(float(np.clip(w, 0.0, 1.0)), (self.panel_width * 0.45, 0.0), f"{w:.2f}")
            psim.SameLine()
            psim.TextUnformatted(name)
        if self.notes:
            psim.Separator()
            for line in self.notes:
                psim.TextWrapped(line)

    def state(self) -> dict:
        """:meth:`TakeView.state` plus ``top`` (the most active character shapes: ``[[name, weight], ...]``)."""
        out = super().state()
        out["top"] = [[n, w] for n, w in self.top_shapes()]
        return out
