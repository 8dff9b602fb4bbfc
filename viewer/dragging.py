"""Markers grabbed with the mouse and dragged in the plane facing the camera: what the marker-editing views share.

:class:`MarkerDragging` is a mixin of a :class:`~facegeom.viewer.app.BaseView`:
a press within :data:`PICK_PX` pixels of a marker grabs it, the mouse's motion
moves it in the plane through the marker facing the camera (by the motion, so a
press a few pixels off does not make it jump), a release lets it go; meanwhile
polyscope's camera ignores the mouse. The view says which markers can be
grabbed and what a drag changes:

- ``marker_screen()`` -> ``{copy: (k, 2) window pixels}`` of the markers that can be grabbed now (empty: none);
- ``marker_world(copy, m)`` -> ``(3,)`` world position of marker ``m`` as drawn on ``copy``;
- ``drag_value(m)`` -> what a drag of marker ``m`` changes, as it is at the press;
- ``drag_set(m, start, delta)``: set it to ``start`` moved by the world vector ``delta (3,)``;
- ``refresh()``: redraw the markers (after a grab selects one).
"""
from __future__ import annotations

import numpy as np

from facegeom.viewer.app import SELECTED_COLOR, color_u32

__all__ = ["MarkerDragging", "PICK_PX"]

PICK_PX = 10.0  # a press this close (window pixels) to a marker's centre grabs it: markers are drawn ~5 px wide


class MarkerDragging:
    """Mouse picking and plane-constrained dragging of markers (see the module for what the view provides).

    Attributes
    ----------
    marker : int
        The selected marker (a grab selects the marker grabbed).
    hover : int or None
        The marker under the mouse, in the last frame.
    drags : int
        Drags completed.
    """

    marker = 0
    hover = None
    drags = 0
    _drag = None

    def marker_at(self, screen_xy, radius_px: float = PICK_PX):
        """``(copy, marker)`` of the marker nearest to window pixel ``screen_xy`` within ``radius_px``, or None."""
        best, where = float(radius_px), None
        q = np.asarray(screen_xy, float)
        for name, xy in self.marker_screen().items():
            if len(xy) == 0:
                continue
            d = np.linalg.norm(xy - q, axis=1)
            i = int(np.argmin(d))
            if d[i] <= best:
                best, where = float(d[i]), (name, i)
        return where

    def on_grab(self, marker: int) -> None:
        """A press grabbed ``marker``: select it and redraw."""
        self.marker = int(marker)
        self.refresh()

    def begin_drag(self, screen_xy) -> bool:
        """Grab the marker within :data:`PICK_PX` pixels of ``screen_xy``: select it and start dragging; the camera
        ignores the mouse until :meth:`end_drag`. Returns whether it did."""
        import polyscope as ps

        hit = self.marker_at(screen_xy)
        if hit is None:
            return False
        name, m = hit
        o, d = self.screen_ray(screen_xy)
        n = np.asarray(ps.get_view_camera_parameters().get_look_dir(), float)
        anchor = np.asarray(self.marker_world(name, m), float)  # the marker, in the copy's place
        grab = o + d * float((anchor - o) @ n) / float(d @ n)  # where the press meets the marker's plane
        self._drag = (m, anchor, grab, n, self.drag_value(m))
        ps.set_do_default_mouse_interaction(False)
        self.on_grab(m)
        return True

    def drag_to(self, screen_xy) -> None:
        """Move the dragged marker with the mouse: by the press-to-``screen_xy`` motion, in the plane through the
        marker facing the camera (the marker does not jump to the cursor when the press was a few pixels off)."""
        if self._drag is None:
            return
        m, anchor, grab, n, start = self._drag
        o, d = self.screen_ray(screen_xy)
        denom = float(d @ n)
        if abs(denom) < 1e-9:
            return
        hit = o + d * float((anchor - o) @ n) / denom
        self.drag_set(m, start, hit - grab)

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
        """Mouse dragging, once per frame.

        Polyscope reads the mouse for its camera before this callback runs, but only
        starts orbiting once the button has moved a few pixels: a press seen here
        switches its mouse handling off in time. The press position is ImGui's
        (where the button went down, even if the mouse moved in the same frame), and
        a release applies the last position first (a fast flick can move and release
        within one frame). Off the markers, or over a panel, the camera works as usual.
        """
        import polyscope.imgui as psim

        io = psim.GetIO()
        self.hover = None
        if self._drag is None:
            if not io.WantCaptureMouse:
                hit = self.marker_at(io.MousePos)
                self.hover = None if hit is None else hit[1]
                if psim.IsMouseClicked(0):
                    self.begin_drag(io.MouseClickedPos[0])
            if self.hover is not None or self._drag is not None:
                psim.SetMouseCursor(psim.ImGuiMouseCursor_Hand)
        elif psim.IsMouseDown(0):
            self.drag_to(io.MousePos)
            psim.SetMouseCursor(psim.ImGuiMouseCursor_Hand)
        else:
            self.end_drag(io.MousePos)

    def draw_marker_rings(self) -> None:
        """Rings around the selected marker (magenta) and the one under the mouse (black, thicker) on every copy
        whose markers can be grabbed, so the user sees what a press would grab."""
        import polyscope.imgui as psim

        dl = psim.GetBackgroundDrawList()
        for xy in self.marker_screen().values():
            if not 0 <= self.marker < len(xy):
                continue
            p = xy[self.marker]
            dl.AddCircle((float(p[0]), float(p[1])), 7.0, color_u32(SELECTED_COLOR), 0, 2.0)
            if self.hover is not None:
                p = xy[self.hover]
                dl.AddCircle((float(p[0]), float(p[1])), PICK_PX, color_u32((0.05, 0.05, 0.05)), 0, 2.5)
