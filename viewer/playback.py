"""``facegeom view retarget`` and ``facegeom view animate``: play a take on the actor beside the character.

The sequence is built as ``facegeom animate`` builds it (:mod:`facegeom.model.performance`):
a window of an ARKit take (or a synthetic take) performed by a seeded actor, and
the same performance on a seeded character with its own style, so the
character's true markers and faces are known.

- retarget: actor face + markers | the character's true face + true markers |
  per retargeter, the character's true face with the retargeted markers
  coloured by their error (mm).
- animate: actor | per retargeter, the character's neutral driven every frame by
  one deformer (fitted once) through the retargeted markers, coloured by the
  per-vertex error against the true face (mm) | the true character.

Both have play/pause, a frame slider and per-frame error plots.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from facegeom.constants import CM_TO_MM, FACE_AREA
from facegeom.errors import FacegeomError, InputError
from facegeom.methods.tangent_retarget import evenly_spread
from facegeom.model import layout
from facegeom.model import performance as sq
from facegeom.pipelines.animate import drive_frames, face_error_mm
from facegeom.registry import LINEUPS, parse_method, parse_methods
from facegeom.viewer.app import TRUTH_COLOR, BaseView, error_mm, nice_ceiling, row_offsets

__all__ = ["load_sequence", "PlaybackView", "RetargetView", "AnimateView", "CurvesView", "advance_in_real_time"]

TRUE_MARKER_COLOR = (0.15, 0.15, 0.15)


def load_sequence(model, take=None, takes=None, start: int = 0, frames: int = 100, seed: int = 0,
                  synthetic: bool = False, layout_name: str = "ict80") -> sq.Sequence:
    """An actor/character sequence: a window of a take (default: the first take found) or a synthetic one."""
    from facegeom.io import find_takes, ict_weights, read_take
    from facegeom.model import locate_takes

    if frames < 2:
        raise InputError(f"--frames must be at least 2, got {frames}")
    if synthetic:
        W, name = sq.synthetic_weights(model, np.random.default_rng([int(seed), 31337]), frames)
        name = f"synthetic:{name}"
    else:
        path = Path(take) if take else find_takes(locate_takes(takes))[0]
        W = ict_weights(read_take(path), model.expression_names)
        if start + frames > W.shape[0]:
            raise InputError(f"the take has {W.shape[0]} frames; --start {start} --frames {frames} runs past its end",
                             path)
        W, name = W[start:start + frames], f"{path.stem}@{start}"
    ids = layout(model, layout_name)
    return sq.make_sequence(model, W, ids, seed, sq.make_character(model, seed), name)


class PlaybackView(BaseView):
    """Frame state, play/pause and the frame slider; subclasses draw a frame in ``show_frame``."""

    def __init__(self, n_frames: int, frame: int = 0):
        """Start paused at ``frame``, one frame per tick.

        Parameters
        ----------
        n_frames : int
            Number of frames ``T`` of the sequence (at least 1).
        frame : int
            The first frame shown, wrapped into ``[0, T)``.
        """
        super().__init__()
        self.n_frames = int(n_frames)
        self.frame = int(frame) % self.n_frames
        self.playing = False
        self.speed = 1
        self._built = False

    def set_frame(self, t: int) -> None:
        """Show frame ``t`` (wrapped into ``[0, T)``)."""
        self.frame = int(t) % self.n_frames
        self.show_frame()

    def play(self, on: bool = True) -> None:
        """Start (``on=True``) or pause playback."""
        self.playing = bool(on)

    def advance(self) -> None:
        """One playback tick: ``speed`` frames forward when playing (not while a screenshot is taken)."""
        if self.playing and not self.frozen:
            self.set_frame(self.frame + self.speed)

    def show_frame(self) -> None:  # pragma: no cover - overridden
        """Move the registered structures to the current ``frame``; implemented by every playback view."""
        raise NotImplementedError

    def callback(self) -> None:
        """:meth:`BaseView.callback`, then one playback tick (:meth:`advance`)."""
        super().callback()
        self.advance()

    def playback_panel(self) -> None:
        """Play/pause and one-frame step buttons, the frame slider and the speed slider (frames per tick)."""
        self.transport_panel()
        ch, v = self.ui.slider_int("speed (frames/tick)", self.speed, 1, 8)
        if ch:
            self.speed = int(v)

    def transport_panel(self) -> None:
        """Play/pause and one-frame step buttons and the frame slider (every playback view's)."""
        import polyscope.imgui as psim

        ui = self.ui
        if ui.button("pause" if self.playing else "play"):
            self.play(not self.playing)
        psim.SameLine()
        if ui.button("<"):
            self.set_frame(self.frame - 1)
        psim.SameLine()
        if ui.button(">"):
            self.set_frame(self.frame + 1)
        ch, v = ui.slider_int("frame", self.frame, 0, self.n_frames - 1)
        if ch:
            self.set_frame(int(v))

    def plot(self, label: str, values: np.ndarray, unit: str = "mm", height: float = 60.0) -> None:
        """Per-frame values as a line plot, the current frame's value in the overlay, a bar under it for time."""
        import polyscope.imgui as psim

        v = np.asarray(values, dtype=np.float32)
        t = self.frame
        finite = v[np.isfinite(v)]
        top = float(finite.max()) * 1.05 if finite.size else 1.0
        psim.PlotLines(f"##{label}", np.nan_to_num(v, nan=0.0), overlay_text=f"{label}: {v[t]:.2f} {unit} at frame {t}",
                       scale_min=0.0, scale_max=max(top, 1e-6), graph_size=(self.panel_width - 30.0, height))
        psim.ProgressBar(t / max(self.n_frames - 1, 1), (self.panel_width - 30.0, 4.0), "")

    def _radius(self, V) -> float:
        return 0.011 * float(np.ptp(np.asarray(V)[:, 0]))

    def points(self, name, P, shift, color=(0.95, 0.35, 0.1), radius=0.2):
        """Like :meth:`BaseView.points`, but ``radius`` is absolute, in world units (cm)."""
        pc = super().points(name, P, shift, color=color)
        pc.set_radius(radius, relative=False)
        return pc


class RetargetView(PlaybackView):
    """Actor | character (truth) | one character per retargeter with its retargeted markers, played over time.

    Parameters
    ----------
    model : FaceModel
    seq : facegeom.model.performance.Sequence
    methods : str or list of MethodSpec
        Retargeter specs (``;``-separated, as for ``facegeom bench retarget``).
    labels : int
        Known character frames, evenly spread.
    """

    title = "facegeom view retarget"

    def __init__(self, model, seq, methods="copy;rbf;tangent", labels: int = 10, frame: int = 0):
        super().__init__(seq.n_frames, frame)
        self.model, self.seq = model, seq
        specs = (parse_methods(methods, "retargeters", LINEUPS["retarget"])
                 if isinstance(methods, str) else list(methods))
        if not specs:
            raise InputError("no retargeter given, e.g. --methods tangent")
        if not 2 <= labels <= seq.n_frames:
            raise InputError(f"--labels must lie in [2, {seq.n_frames}] (the frames), got {labels}")
        self.specs = specs
        self.labelled = evenly_spread(seq.n_frames, labels)
        self.actor = sq.actor_faces(model, seq)
        self.truth = sq.character_faces(model, seq)
        self.results: dict[str, np.ndarray] = {}
        self.frame_err: dict[str, np.ndarray] = {}
        self.time_ms: dict[str, float] = {}
        self.failed: dict[str, str] = {}
        for s in specs:
            try:
                r = s.build("retargeters")
                t = time.perf_counter()
                Y = r.fit(seq.source, self.labelled, seq.target[self.labelled]).transform()
                self.time_ms[s.label] = (time.perf_counter() - t) * 1e3
            except FacegeomError as exc:
                self.failed[s.label] = str(exc)
                continue
            self.results[s.label] = Y
            self.frame_err[s.label] = np.linalg.norm(Y - seq.target, axis=2).mean(axis=1) * CM_TO_MM
        errs = [np.percentile(np.linalg.norm(Y - seq.target, axis=2), 99) * CM_TO_MM for Y in self.results.values()]
        self.vmax = nice_ceiling(float(np.median(errs)) if errs else 5.0)  # a typical method's 99th percentile

    def copies(self) -> list[str]:
        """Names of the copies in the row, left to right: ``actor``, ``character``, then every retargeter
        that succeeded."""
        return ["actor", "character", *self.results]

    def build(self) -> None:
        """Register the row at the current frame: the actor's face and markers; the character's true face
        and true markers (dark) as ``character`` and again under each retargeter, which adds its
        retargeted markers; then :meth:`show_frame`."""
        self._built = True
        F, t = self.model.triangles, self.frame
        names = self.copies()
        self.shifts = dict(zip(names, row_offsets(self.truth[0], len(names))))
        r = self._radius(self.truth[0])
        self.mesh("actor", self.actor[t], F, self.shifts["actor"])
        self.points("actor markers", self.seq.source[t], self.shifts["actor"], radius=r)
        for name in ["character", *self.results]:
            self.mesh(f"{name} face", self.truth[t], F, self.shifts[name], color=TRUTH_COLOR)
            self.points(f"{name} true markers", self.seq.target[t], self.shifts[name], color=TRUE_MARKER_COLOR,
                        radius=0.6 * r)
        for label, Y in self.results.items():
            self.points(f"{label} markers", Y[t], self.shifts[label], radius=r)
        self.show_frame()

    def show_frame(self) -> None:
        """Move every face and marker set to the current frame; each retargeter's markers are coloured by
        their distance to the true markers (mm). Does nothing before :meth:`build`."""
        import polyscope as ps

        if not ps.is_initialized() or not self._built:
            return
        t, s = self.frame, self.seq
        ps.get_surface_mesh("actor").update_vertex_positions(self.actor[t] + self.shifts["actor"])
        ps.get_point_cloud("actor markers").update_point_positions(s.source[t] + self.shifts["actor"])
        for name in ["character", *self.results]:
            ps.get_surface_mesh(f"{name} face").update_vertex_positions(self.truth[t] + self.shifts[name])
            ps.get_point_cloud(f"{name} true markers").update_point_positions(s.target[t] + self.shifts[name])
        for label, Y in self.results.items():
            pc = ps.get_point_cloud(f"{label} markers")
            pc.update_point_positions(Y[t] + self.shifts[label])
            self.error_colors(pc, error_mm(Y[t], s.target[t]), self.vmax)

    def panel(self) -> None:
        """The sequence, the colour scale and the playback controls, then per retargeter its mean and
        worst-frame marker error (mm), its time and a per-frame error plot."""
        import polyscope.imgui as psim

        s = self.seq
        psim.TextWrapped(f"{s.name}: {s.n_frames} frames, {s.marker_ids.size} markers; {self.labelled.size} "
                         f"labelled character frames")
        psim.TextWrapped("left to right: " + " | ".join(self.copies()))
        psim.TextWrapped("dark dots: the character's true markers; coloured dots: retargeted markers, colour = "
                         "error (mm)")
        if self.color_max_slider():
            self.show_frame()
        self.playback_panel()
        labelled = " (labelled)" if self.frame in set(self.labelled.tolist()) else ""
        psim.TextUnformatted(f"frame {self.frame}{labelled}")
        psim.Separator()
        psim.TextUnformatted("mean marker error per frame (mm)")
        for spec in self.specs:
            label = spec.label
            if label in self.failed:
                psim.TextColored((1.0, 0.3, 0.3, 1.0), f"{label}: failed: {self.failed[label]}")
                continue
            e = self.frame_err[label]
            psim.TextUnformatted(f"{label}: mean {e.mean():.2f} mm, worst frame {e.max():.2f} mm, "
                                 f"{self.time_ms[label]:.1f} ms")
            self.plot(label, e)


class AnimateView(PlaybackView):
    """Actor | driven character per retargeter (error colours) | the true character, played over time.

    Parameters
    ----------
    model : FaceModel
    seq : facegeom.model.performance.Sequence
    retargeters : str or list of MethodSpec
        ``;``-separated retargeter specs.
    deformer : str or MethodSpec
        One deformer spec, fitted once on the character's neutral face.
    labels : int
        Known character frames.
    """

    title = "facegeom view animate"

    def __init__(self, model, seq, retargeters="tangent", deformer="tangent", labels: int = 10, frame: int = 0):
        super().__init__(seq.n_frames, frame)
        self.model, self.seq = model, seq
        specs = (parse_methods(retargeters, "retargeters", LINEUPS["animate"])
                 if isinstance(retargeters, str) else list(retargeters))
        if not specs:
            raise InputError("no retargeter given, e.g. --retargeters tangent")
        if not 2 <= labels <= seq.n_frames:
            raise InputError(f"--labels must lie in [2, {seq.n_frames}] (the frames), got {labels}")
        self.d_spec = parse_method(deformer) if isinstance(deformer, str) else deformer
        parse_methods(self.d_spec.name, "deformers", [])  # a clear error for an unknown deformer
        self.specs = specs
        self.labelled = evenly_spread(seq.n_frames, labels)
        self.actor = sq.actor_faces(model, seq)
        self.truth = sq.character_faces(model, seq)
        d = self.d_spec.build("deformers")
        t = time.perf_counter()
        d.fit(sq.character_neutral(model, seq.character), model.triangles, seq.marker_ids)
        self.fit_s = time.perf_counter() - t
        self.markers: dict[str, np.ndarray] = {}
        self.faces: dict[str, np.ndarray] = {}
        self.frame_err: dict[str, np.ndarray] = {}
        self.marker_err: dict[str, np.ndarray] = {}
        self.times: dict[str, tuple[float, float]] = {}
        self.failed: dict[str, str] = {}
        for s in specs:
            try:
                r = s.build("retargeters")
                t = time.perf_counter()
                M = r.fit(seq.source, self.labelled, seq.target[self.labelled]).transform()
                ret_ms = (time.perf_counter() - t) * 1e3
                V, drive_s = drive_frames(d, M)
            except FacegeomError as exc:
                self.failed[s.label] = str(exc)
                continue
            self.markers[s.label], self.faces[s.label] = M, V
            self.frame_err[s.label] = face_error_mm(V, self.truth, FACE_AREA)
            self.marker_err[s.label] = np.linalg.norm(M - seq.target, axis=2).mean(axis=1) * CM_TO_MM
            self.times[s.label] = (ret_ms, drive_s * 1e3 / seq.n_frames)
        errs = [np.percentile(error_mm(V[:, :FACE_AREA], self.truth[:, :FACE_AREA]), 99)
                for V in self.faces.values()]
        self.vmax = nice_ceiling(float(np.median(errs)) if errs else 5.0)  # a typical method's 99th pct.

    def copies(self) -> list[str]:
        """Names of the faces in the row, left to right: ``actor``, the character driven through each
        retargeter that succeeded, ``character`` (the truth)."""
        return ["actor", *self.faces, "character"]

    def build(self) -> None:
        """Register the row at the current frame: the actor with its markers, the true character with its
        true markers, and per retargeter the driven face with the retargeted markers; then :meth:`show_frame`."""
        self._built = True
        F, t = self.model.triangles, self.frame
        names = self.copies()
        self.shifts = dict(zip(names, row_offsets(self.truth[0], len(names))))
        r = self._radius(self.truth[0])
        self.mesh("actor", self.actor[t], F, self.shifts["actor"])
        self.points("actor markers", self.seq.source[t], self.shifts["actor"], radius=r)
        self.mesh("character", self.truth[t], F, self.shifts["character"])
        self.points("character true markers", self.seq.target[t], self.shifts["character"], radius=r)
        for label in self.faces:
            self.mesh(label, self.faces[label][t], F, self.shifts[label])
            self.points(f"{label} markers", self.markers[label][t], self.shifts[label], radius=r)
        self.show_frame()

    def show_frame(self) -> None:
        """Move every face and marker set to the current frame; each driven face is coloured by its
        per-vertex distance to the true face (mm). Does nothing before :meth:`build`."""
        import polyscope as ps

        if not ps.is_initialized() or not self._built:
            return
        t, s = self.frame, self.seq
        ps.get_surface_mesh("actor").update_vertex_positions(self.actor[t] + self.shifts["actor"])
        ps.get_point_cloud("actor markers").update_point_positions(s.source[t] + self.shifts["actor"])
        m = ps.get_surface_mesh("character")
        m.update_vertex_positions(self.truth[t] + self.shifts["character"])
        self.error_colors(m, np.zeros(self.truth.shape[1]), self.vmax)
        ps.get_point_cloud("character true markers").update_point_positions(s.target[t] + self.shifts["character"])
        for label, V in self.faces.items():
            m = ps.get_surface_mesh(label)
            m.update_vertex_positions(V[t] + self.shifts[label])
            self.error_colors(m, error_mm(V[t], self.truth[t]), self.vmax)
            ps.get_point_cloud(f"{label} markers").update_point_positions(self.markers[label][t] + self.shifts[label])

    def panel(self) -> None:
        """The sequence and deformer, the colour scale and the playback controls, then per retargeter its
        times and per-frame plots of the face error and the marker error (mm)."""
        import polyscope.imgui as psim

        s = self.seq
        psim.TextWrapped(f"{s.name}: {s.n_frames} frames, {s.marker_ids.size} markers; {self.labelled.size} "
                         f"labelled frames; deformer {self.d_spec.label} (fit {self.fit_s:.2f} s)")
        psim.TextWrapped("left to right: " + " | ".join(self.copies()))
        psim.TextUnformatted("colour: distance to the character's true face (mm)")
        if self.color_max_slider():
            self.show_frame()
        self.playback_panel()
        labelled = " (labelled)" if self.frame in set(self.labelled.tolist()) else ""
        psim.TextUnformatted(f"frame {self.frame}{labelled}")
        psim.Separator()
        for spec in self.specs:
            label = spec.label
            if label in self.failed:
                psim.TextColored((1.0, 0.3, 0.3, 1.0), f"{label}: failed: {self.failed[label]}")
                continue
            ret_ms, per_frame_ms = self.times[label]
            psim.TextUnformatted(f"{label}: retarget {ret_ms:.1f} ms, deform {per_frame_ms:.2f} ms/frame")
            self.plot(f"{label} face error", self.frame_err[label])
            self.plot(f"{label} marker error", self.marker_err[label], height=40.0)


def advance_in_real_time(view: "PlaybackView", fps: float) -> None:
    """One tick of real-time playback: the frame is the time since play was pressed (or the last jump, ``view._t0``
    at ``view._f0``) times ``fps`` times ``view.speed``, wrapped; nothing when paused or frozen."""
    if not view.playing or view.frozen:
        return
    if view._t0 is None:
        view._t0, view._f0 = time.monotonic(), view.frame
    t = view._f0 + int((time.monotonic() - view._t0) * fps * view.speed)
    if t % view.n_frames != view.frame:
        PlaybackView.set_frame(view, t)


class CurvesView(PlaybackView):
    """Play an animation file (what ``facegeom solve`` writes): a ``.glb``, ``.npz`` curves or a Live Link take.

    One face, played in real time at the file's frame rate; the panel shows the
    file, the frame and the strongest weights of the frame as bars.

    Parameters
    ----------
    anim : facegeom.pipelines.solve.RigAnimation
        From :func:`facegeom.pipelines.solve.read_animation`.
    frame : int
        The first frame shown.
    """

    title = "facegeom view animate"
    TOP = 10  # weights listed in the panel

    def __init__(self, anim, frame: int = 0):
        super().__init__(anim.n_frames, frame)
        self.anim = anim
        self.vmax = 1.0
        self._t0: float | None = None
        self._f0 = 0

    def draw_colorbar(self) -> None:
        """No colour scale: an animation file carries no truth to measure against."""

    def copies(self) -> list[str]:
        """The one face of the row."""
        return ["animation"]

    def shown_faces(self) -> dict:
        """``animation`` -> the face at the current frame."""
        return {"animation": self.anim.frame(self.frame)} if self._built else {}

    def build(self) -> None:
        """Register the face at the current frame and frame the camera on it (and its motion range)."""
        self._built = True
        a = self.anim
        self.shift = np.zeros(3)
        self.mesh("animation", a.frame(self.frame), a.triangles, self.shift)
        for t in np.linspace(0, a.n_frames - 1, min(a.n_frames, 8)).astype(int):
            self._grow_bounds(a.frame(int(t)))
        self.show_frame()

    def show_frame(self) -> None:
        """Move the face to the current frame. Does nothing before :meth:`build`."""
        import polyscope as ps

        if not ps.is_initialized() or not self._built:
            return
        ps.get_surface_mesh("animation").update_vertex_positions(self.anim.frame(self.frame) + self.shift)

    def play(self, on: bool = True) -> None:
        """Start (``on=True``) or pause playback; playing keeps the file's frame rate (``speed`` times it)."""
        super().play(on)
        self._t0, self._f0 = (time.monotonic(), self.frame) if on else (None, self.frame)

    def advance(self) -> None:
        """Real-time playback at the file's frame rate (see :func:`advance_in_real_time`)."""
        advance_in_real_time(self, self.anim.fps)

    def set_frame(self, t: int) -> None:
        """Show frame ``t`` (wrapped); while playing, the clock restarts there (the slider and steps)."""
        super().set_frame(t)
        if self.playing:
            self._t0, self._f0 = time.monotonic(), self.frame

    def panel(self) -> None:
        """The file, its frame rate and length, the playback controls and the frame's strongest weights."""
        import polyscope.imgui as psim

        a = self.anim
        psim.TextWrapped(f"{Path(a.path).name}: {a.n_frames} frames at {a.fps:g} fps "
                         f"({a.n_frames / a.fps:.1f} s), {len(a.names)} shapes")
        self.playback_panel()
        psim.TextUnformatted(f"frame {self.frame}  ({self.frame / a.fps:.2f} s)")
        psim.Separator()
        w = a.weights[self.frame]
        order = np.argsort(-np.abs(w))[: self.TOP]
        for k in order:
            if abs(w[k]) < 1e-3:
                break
            psim.ProgressBar(float(np.clip(w[k], 0.0, 1.0)), (self.panel_width * 0.45, 0.0), f"{w[k]:.2f}")
            psim.SameLine()
            psim.TextUnformatted(a.names[k])

    def state(self) -> dict:
        """:meth:`BaseView.state` plus ``frame``, ``n_frames``, ``fps`` and ``playing``."""
        out = super().state()
        out.update(frame=self.frame, n_frames=self.n_frames, fps=self.anim.fps, playing=self.playing)
        return out
