"""``facegeom live --view``: the character following a live stream in the polyscope window.

The window's own frame loop drives the session: every frame it polls the source once without waiting
(:meth:`facegeom.pipelines.live.LiveSession.step` with no timeout), so the viewer keeps its frame rate
whatever the stream does, and a frame that arrives is on screen at the next redraw. The character is
coloured by each vertex's displacement from its neutral (mm) and turned by the head's rotation. The panel
shows the counts and latencies of :class:`~facegeom.pipelines.live.LiveStats`, the viewer's own frame
rate, and the strongest shapes. With ``--screenshot`` the session runs to its end (``--frames``,
``--seconds``, or the replay's last frame) and the last frame is rendered.
"""
from __future__ import annotations

import time

import numpy as np

from facegeom.constants import CM_TO_MM
from facegeom.viewer.app import BaseView

__all__ = ["LiveView"]

TOP = 5


class LiveView(BaseView):
    """One face, the character, following ``session``'s frames.

    Parameters
    ----------
    session : facegeom.pipelines.live.LiveSession
        Its sinks include ``character``.
    character : facegeom.pipelines.live.CharacterSink
    frames, seconds : optional
        End the session (and close the window) after that many frames passed on, or seconds.
    name : str
        How the panel names the character.
    """

    title = "facegeom live"
    colorbar_title = "displacement from the neutral (mm)"

    def __init__(self, session, character, frames: int | None = None, seconds: float | None = None,
                 name: str = "character"):
        super().__init__()
        self.session, self.character = session, character
        self.frames, self.seconds = frames, seconds
        self.name = name
        self.vmax = 10.0
        self._seen = -1
        self._t_end = None if seconds is None else time.monotonic() + float(seconds)
        self.ended = False

    def copies(self) -> list[str]:
        """The one face of the row."""
        return ["character"]

    def shown_faces(self) -> dict:
        """``character`` -> the face as drawn now."""
        return {"character": self.character.face()} if self._built else {}

    def build(self) -> None:
        """Register the character and frame the camera on it (room for its head turning)."""
        self._built = True
        rig = self.character.rig
        V = self.character.face()
        self.mesh("character", V, rig.triangles, np.zeros(3))
        N = np.asarray(rig.neutral)
        c, reach = N.mean(axis=0), float(np.linalg.norm(N - N.mean(axis=0), axis=1).max())
        self._grow_bounds(np.array([c - reach * np.array([1.0, 0.8, 0.3]), c + reach * np.array([1.0, 0.8, 0.3])]))
        self._show()

    def _show(self) -> None:
        import polyscope as ps

        if not ps.is_initialized() or not self._built:
            return
        rig = self.character.rig
        m = ps.get_surface_mesh("character")
        m.update_vertex_positions(self.character.face())
        on = np.flatnonzero(self.character.weights)
        d = np.tensordot(self.character.weights[on], rig.deltas[on], axes=1) if on.size else np.zeros((rig.n_vertices, 3))
        self.error_colors(m, np.linalg.norm(d, axis=1) * CM_TO_MM, self.vmax, name="displacement (mm)")

    def _limit_reached(self) -> bool:
        s = self.session
        return (s.stopped or (self.frames is not None and s.stats.frames_out >= self.frames)
                or (self._t_end is not None and time.monotonic() >= self._t_end)
                or bool(getattr(s.source, "done", False)))

    def pump(self, timeout: float = 0.0) -> None:
        """Poll the session once (waiting at most ``timeout``); redraw the character if a frame came."""
        if self.ended:
            return
        if self._limit_reached():
            self.ended = True
            return
        self.session.step(timeout)
        if self.character.frames != self._seen:
            self._seen = self.character.frames
            self._show()

    def wait(self, timeout: float | None = None) -> None:
        """Before a screenshot: run the session to its end (frames, seconds, or the replay's last frame), drawing
        every frame as the window would (so :meth:`viewer_fps` is the frame rate while receiving)."""
        import polyscope as ps

        while not self.ended:
            ps.frame_tick()  # the callback polls the stream once, as in the window
            if self.ended:
                break
            self.pump(0.002)  # at most 2 ms more waiting: the renderer, not the wait, sets the pace

    def callback(self) -> None:
        """The panel, then one poll of the stream; the window closes when the session has ended."""
        super().callback()
        self.pump(0.0)
        if self.ended and (self.frames is not None or self.seconds is not None):
            self._stop = True

    def panel(self) -> None:
        """Counts, latency, the viewer's frame rate, the strongest shapes."""
        import polyscope.imgui as psim

        st = self.session.stats
        psim.TextWrapped(f"{self.name}: {self.character.rig.n_shapes} shapes")
        psim.TextWrapped(st.line())
        fps = self.viewer_fps()
        psim.TextUnformatted(f"viewer {fps:.0f} fps" if fps else "viewer: starting")
        if self.ended:
            psim.TextUnformatted("the stream has ended")
        if self.color_max_slider():
            self._show()
        psim.Separator()
        w = self.character.weights
        order = np.argsort(-w, kind="stable")[:TOP]
        for k in order:
            if w[k] <= 1e-3:
                break
            psim.ProgressBar(float(np.clip(w[k], 0.0, 1.0)), (self.panel_width * 0.45, 0.0), f"{w[k]:.2f}")
            psim.SameLine()
            psim.TextUnformatted(self.character.rig.names[k])

    def viewer_fps(self, window: float = 1.0) -> float | None:
        """The window's frame rate over its last ``window`` seconds, or None before it has one."""
        t = list(self.frame_times)
        if len(t) < 3:
            return None
        recent = [x for x in t if x >= t[-1] - window]
        span = recent[-1] - recent[0]
        return (len(recent) - 1) / span if span > 0 else None

    def state(self) -> dict:
        """:meth:`BaseView.state` plus the session's counts and latencies and the viewer's frame rate."""
        out = super().state()
        st = self.session.stats
        out.update(frames_in=st.frames_in, frames_out=st.frames_out, malformed=st.malformed,
                   superseded=st.superseded, latency_ms=st.percentiles(), viewer_fps=self.viewer_fps(),
                   ended=self.ended)
        return out
