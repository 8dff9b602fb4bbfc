"""What every view shares: polyscope start-up (window or headless), the row layout,
error colour maps, camera framing, screenshots and a scriptable ImGui panel.

A view is a plain object:

- ``build()`` registers its structures (after :func:`init_polyscope`);
- ``callback()`` draws the ImGui panel and applies what the user changed; polyscope
  calls it once per frame, and a test can run it with ``polyscope.frame_tick()``;
- every action behind a widget is also a method (``set_offset``, ``set_frame``...),
  and :class:`Widgets` lets a script set a widget's value for the next frame, so
  tests drive the very code path of the panel without a person.
"""
from __future__ import annotations

import json
import math
import os
import signal
import sys
import time
from collections import deque
from pathlib import Path

import numpy as np

from facegeom.constants import CM_TO_MM
from facegeom.errors import FacegeomError, InputError

__all__ = ["NO_DISPLAY", "display_available", "check_display", "init_polyscope", "parse_size", "Widgets",
           "BaseView", "error_mm", "row_offsets", "colormap_rgb", "color_u32", "scale_text", "COLOR_MAX_LABEL",
           "COLOR_MAX_RANGE"]

CMAP = "viridis"
FOV_DEG = 15.0
MARKER_COLOR = (0.95, 0.35, 0.1)
SELECTED_COLOR = (1.0, 0.0, 0.6)
TRUTH_COLOR = (0.78, 0.78, 0.8)
BUSY_FPS = 12  # frame rate cap while methods fit in worker processes (the renderer is software GL here)
COLORBAR_H = 74  # pixels kept free at the bottom of the window for the colour scale
# The colour scale's maximum (mm): one range, one label and one number format for the panel's slider and the
# drawn colour bar, so both always show the same value.
COLOR_MAX_LABEL = "colour max (mm)"
COLOR_MAX_RANGE = (0.01, 50.0)
SCALE_FORMAT = "%.3g"
# matplotlib's viridis (the faces' colour map) sampled at 0, 1/8, ..., 1: enough for a drawn colour bar
_VIRIDIS = np.array([[68, 1, 84], [72, 40, 120], [62, 74, 137], [49, 104, 142], [38, 130, 142],
                     [31, 158, 137], [53, 183, 121], [109, 205, 89], [253, 231, 37]], dtype=np.float64) / 255.0

NO_DISPLAY = ("no display found ($DISPLAY and $WAYLAND_DISPLAY are unset): add --screenshot PATH to render "
              "a PNG headless (EGL, no GPU needed), or run the viewer under a virtual display: xvfb-run -a facegeom "
              "view ...")


def display_available(environ=None, platform: str | None = None) -> bool:
    """Whether a window can be opened: on Linux, ``$DISPLAY`` or ``$WAYLAND_DISPLAY`` is set."""
    env = os.environ if environ is None else environ
    plat = sys.platform if platform is None else platform
    if not plat.startswith("linux"):
        return True
    return bool(env.get("DISPLAY") or env.get("WAYLAND_DISPLAY"))


def check_display(screenshot) -> None:
    """Raise :class:`InputError` (one line: how to run headless) if there is no display and no screenshot."""
    if screenshot is None and not display_available():
        raise InputError(NO_DISPLAY)


def init_polyscope(headless: bool = False) -> str:
    """Start polyscope once per process; ``headless`` renders off-screen (EGL). Returns the backend name."""
    import polyscope as ps

    if ps.is_initialized():
        return ps.get_render_engine_backend_name()
    ps.set_program_name("facegeom viewer")
    ps.set_use_prefs_file(False)
    ps.set_verbosity(0)
    ps.set_errors_throw_exceptions(True)
    if headless:
        ps.set_allow_headless_backends(True)
        ps.set_frame_tick_limit_fps_mode("ignore_limits")  # every scripted frame_tick runs the callback
    try:
        ps.init("openGL3_egl" if headless and sys.platform.startswith("linux") else "auto")
    except Exception:  # noqa: BLE001 - EGL missing: let polyscope try every backend
        try:
            ps.init()
        except Exception as exc:  # noqa: BLE001
            _forget_polyscope_shutdown()
            hint = (" (headless rendering needs EGL: apt install libegl1 libegl-mesa0 libgl1-mesa-dri)"
                    if headless else "")
            raise InputError(f"polyscope could not start a renderer: {exc}{hint}") from None
    return ps.get_render_engine_backend_name()


def _forget_polyscope_shutdown() -> None:
    """Polyscope's bindings shut it down at exit, which raises when it never started: a block after our one line.

    Python reports an exception of an exit callback through ``sys.unraisablehook``; that one report is dropped,
    any other goes to the hook as before.
    """
    previous = sys.unraisablehook

    def hook(unraisable):
        if isinstance(unraisable.exc_value, RuntimeError) and "has not been initialized" in str(unraisable.exc_value):
            return
        previous(unraisable)

    sys.unraisablehook = hook


def parse_size(text: str) -> tuple[int, int]:
    """``"1600x900"`` -> ``(1600, 900)``; :class:`InputError` naming ``--size`` otherwise."""
    try:
        w, h = (int(x) for x in str(text).lower().split("x"))
    except ValueError:
        raise InputError(f"--size must be WIDTHxHEIGHT in pixels, e.g. 1600x900, got {text!r}") from None
    if not (320 <= w <= 8192 and 240 <= h <= 8192):
        raise InputError(f"--size {text}: width must lie in [320, 8192] and height in [240, 8192]")
    return w, h


def error_mm(Y: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Per-vertex distance between two ``(n, 3)`` faces in mm (the data is in cm)."""
    return np.linalg.norm(np.asarray(Y) - np.asarray(T), axis=-1) * CM_TO_MM


def scale_text(x: float) -> str:
    """A number of the colour scale (mm) as the slider and the colour bar both print it."""
    return SCALE_FORMAT % float(x)


def row_offsets(V: np.ndarray, count: int, gap: float = 0.12) -> np.ndarray:
    """``(count, 3)`` shifts placing ``count`` copies of a face like ``V`` side by side along x."""
    width = float(np.ptp(np.asarray(V)[:, 0]))
    return np.c_[np.arange(count) * width * (1.0 + gap), np.zeros((count, 2))]


def colormap_rgb(t) -> np.ndarray:
    """Viridis at ``t`` in [0, 1] (clipped): ``(..., 3)`` RGB in [0, 1], piecewise linear between 9 samples."""
    t = np.clip(np.asarray(t, dtype=np.float64), 0.0, 1.0) * (len(_VIRIDIS) - 1)
    i = np.minimum(np.floor(t).astype(int), len(_VIRIDIS) - 2)
    f = (t - i)[..., None]
    return _VIRIDIS[i] * (1.0 - f) + _VIRIDIS[i + 1] * f


def color_u32(rgb, alpha: float = 1.0) -> int:
    """ImGui's packed 32-bit colour of ``rgb`` in [0, 1] with opacity ``alpha``."""
    import polyscope.imgui as psim

    r, g, b = (int(round(255 * float(np.clip(c, 0, 1)))) for c in rgb)
    return psim.IM_COL32(r, g, b, int(round(255 * alpha)))


def nice_ceiling(x: float) -> float:
    """Round up to 1, 2 or 5 times a power of ten (a colour scale maximum)."""
    if not np.isfinite(x) or x <= 0:
        return 1.0
    p = 10.0 ** math.floor(math.log10(x))
    for m in (1.0, 2.0, 5.0, 10.0):
        if x <= m * p * 1.0000001:
            return m * p
    return 10.0 * p


class Widgets:
    """Thin wrappers of ``polyscope.imgui`` widgets whose value a script can set for the next frame.

    ``set(label, value)`` queues a value: the next time the widget ``label`` is drawn it
    reports a change to ``value`` exactly as if the user had moved it. Buttons take ``True``.
    """

    def __init__(self):
        self.pending: dict[str, object] = {}
        self.rects: dict[str, list[float]] = {}  # label -> window pixels x0, y0, x1, y1 of its last draw
        self.shown: dict[str, str] = {}  # label -> the text a slider displayed in its last draw

    def set(self, label: str, value) -> None:
        """Queue ``value`` for the widget ``label``: its next draw reports a change to ``value``.

        Buttons take ``True``; a combo box takes the item itself, not its index.
        """
        self.pending[label] = value

    def _take(self, label, changed, value):
        import polyscope.imgui as psim

        (x0, y0), (x1, y1) = psim.GetItemRectMin(), psim.GetItemRectMax()
        self.rects[label] = [float(x0), float(y0), float(x1), float(y1)]
        if label in self.pending:
            return True, self.pending.pop(label)
        return changed, value

    def slider_float(self, label, v, lo, hi, fmt="%.3f", logarithmic=False):
        """A float slider over ``[lo, hi]`` showing ``v`` (printf format ``fmt``) -> ``(changed, value)``.

        ``logarithmic`` spaces the values logarithmically along the slider (a scale spanning decades).
        """
        import polyscope.imgui as psim

        flags = psim.ImGuiSliderFlags_Logarithmic if logarithmic else 0
        self.shown[label] = fmt % float(v)
        return self._take(label, *psim.SliderFloat(label, float(v), float(lo), float(hi), format=fmt, flags=flags))

    def slider_int(self, label, v, lo, hi):
        """An integer slider over ``[lo, hi]`` showing ``v`` -> ``(changed, value)``."""
        import polyscope.imgui as psim

        return self._take(label, *psim.SliderInt(label, int(v), int(lo), int(hi)))

    def input_int(self, label, v, step=1):
        """An integer box with -/+ buttons stepping by ``step`` -> ``(changed, value)``."""
        import polyscope.imgui as psim

        return self._take(label, *psim.InputInt(label, int(v), step))

    def checkbox(self, label, v):
        """A checkbox showing ``v`` -> ``(changed, checked)``."""
        import polyscope.imgui as psim

        return self._take(label, *psim.Checkbox(label, bool(v)))

    def combo(self, label, current: str, items: list[str]):
        """A combo box over ``items``; returns ``(changed, item)`` (a script sets the item itself)."""
        import polyscope.imgui as psim

        i = items.index(current) if current in items else 0
        changed, j = psim.Combo(label, i, list(items))
        changed, item = self._take(label, changed, items[j])
        return changed, item

    def button(self, label) -> bool:
        """A button -> whether it was pressed this frame; a value queued by :meth:`set` replaces the click."""
        import polyscope.imgui as psim

        pressed = psim.Button(label)
        (x0, y0), (x1, y1) = psim.GetItemRectMin(), psim.GetItemRectMax()
        self.rects[label] = [float(x0), float(y0), float(x1), float(y1)]
        if label in self.pending:
            return bool(self.pending.pop(label))
        return pressed


class BaseView:
    """A row of faces (shifted copies along x) with a panel; subclasses fill ``build`` and ``panel``."""

    title = "facegeom"
    panel_width = 420

    colorbar_title = "distance to the truth (mm)"

    def __init__(self):
        self.ui = Widgets()
        self.ticks = 0
        self.frozen = False  # True while taking a screenshot: no playback advance
        self.messages: list[str] = []
        self._bounds = None
        self._built = False  # set by build(): the structures are registered
        self.vmax = 5.0  # the colour scale's maximum (mm); views set it from their results
        self.polyscope_panels = False  # polyscope's own panels (structures, render options): one click away
        self.clock0 = time.monotonic()  # times in the state file are seconds since this
        self.frame_times: deque = deque(maxlen=5000)
        self.panel_rect = None  # (x, y, w, h) of the view's panel in the last frame
        self.state_path: Path | None = None
        self._state_written = 0.0
        self._exit_at: float | None = None
        self._stop = False

    @property
    def vmax(self) -> float:
        """The colour scale's maximum (mm): the faces' colours, the slider and the colour bar all use it.

        Setting it keeps it in :data:`COLOR_MAX_RANGE` and rounds it to the digits the slider and the bar
        print, so what is shown is exactly the scale the faces are coloured on.
        """
        return self._vmax

    @vmax.setter
    def vmax(self, value: float) -> None:
        """Set the maximum (mm), clipped to :data:`COLOR_MAX_RANGE` and rounded as it is printed."""
        lo, hi = COLOR_MAX_RANGE
        self._vmax = float(scale_text(min(max(float(value), lo), hi)))

    def color_max_slider(self) -> bool:
        """The panel's ``colour max (mm)`` slider (logarithmic over :data:`COLOR_MAX_RANGE`); sets :attr:`vmax`
        and returns whether it changed."""
        lo, hi = COLOR_MAX_RANGE
        changed, v = self.ui.slider_float(COLOR_MAX_LABEL, self.vmax, lo, hi, SCALE_FORMAT, logarithmic=True)
        if changed:
            self.vmax = v
        return changed

    def colorbar_labels(self) -> list[str]:
        """The five tick labels of the drawn colour bar, 0 to :attr:`vmax` (mm), printed as the slider prints."""
        return [scale_text(self.vmax * j / 4) for j in range(5)]

    # ------------------------------------------------------------------ structures
    def _grow_bounds(self, P: np.ndarray) -> None:
        lo, hi = P.min(axis=0), P.max(axis=0)
        if self._bounds is None:
            self._bounds = (lo, hi)
        else:
            self._bounds = (np.minimum(self._bounds[0], lo), np.maximum(self._bounds[1], hi))

    def mesh(self, name, V, F, shift, color=TRUTH_COLOR):
        """Register the surface mesh ``name`` at ``V + shift`` and grow the framed bounding box.

        Parameters
        ----------
        name : str
            Polyscope structure name.
        V : (n, 3) float array
            Vertex positions (cm).
        F : (m, 3) int array
            Triangles.
        shift : (3,) float array
            Offset of this copy in the row (see :func:`row_offsets`).
        color : (3,) float
            RGB in [0, 1].

        Returns
        -------
        polyscope.SurfaceMesh
        """
        import polyscope as ps

        P = np.asarray(V) + shift
        self._grow_bounds(P)
        m = ps.register_surface_mesh(name, P, F, color=color, smooth_shade=True, material="clay")
        return m

    def points(self, name, P, shift, color=MARKER_COLOR, radius=0.0035):
        """Register the point cloud ``name`` at ``P + shift`` (it does not grow the framed bounding box).

        Parameters
        ----------
        name : str
            Polyscope structure name.
        P : (k, 3) float array
            Point positions (cm).
        shift : (3,) float array
            Offset of this copy in the row.
        color : (3,) float
            RGB in [0, 1].
        radius : float
            Point radius relative to the scene's length scale (polyscope's default).

        Returns
        -------
        polyscope.PointCloud
        """
        import polyscope as ps

        Q = np.asarray(P) + shift
        pc = ps.register_point_cloud(name, Q, color=color, radius=radius)
        return pc

    def error_colors(self, mesh, err_mm, vmax, name="error (mm)", colorbar=False):
        """Colour ``mesh`` by ``err_mm`` on the shared scale ``[0, vmax]`` mm."""
        mesh.add_scalar_quantity(name, np.asarray(err_mm, dtype=np.float64), enabled=True, cmap=CMAP,
                                 vminmax=(0.0, float(vmax)), onscreen_colorbar_enabled=colorbar)

    def build(self) -> None:  # pragma: no cover - overridden
        """Register the view's structures; implemented by every view, which also sets ``self._built``."""
        raise NotImplementedError

    def rebuild(self) -> None:
        """Register every structure again (after a case or selection change), if polyscope is running."""
        import polyscope as ps

        if not ps.is_initialized() or not self._built:
            return
        ps.remove_all_structures()
        self.build()
        self.frame_camera()

    # ------------------------------------------------------------------ panel
    def panel(self) -> None:  # pragma: no cover - overridden
        """Draw the view's widgets and apply what changed; implemented by every view, called by :meth:`callback`."""
        raise NotImplementedError

    def callback(self) -> None:
        """The per-frame user callback: the panel, then input handling. Polyscope calls it inside a frame."""
        import polyscope as ps
        import polyscope.imgui as psim

        self.ticks += 1
        now = time.monotonic()
        self.frame_times.append(now - self.clock0)
        psim.PushItemWidth(self.panel_width * 0.45)
        try:
            if self.ui.button("reset view"):
                self.frame_camera()
            psim.SameLine()
            ch, on = self.ui.checkbox("polyscope panels", self.polyscope_panels)
            if ch:
                self.polyscope_panels = bool(on)
                ps.set_build_default_gui_panels(self.polyscope_panels)
            self.panel()
        except FacegeomError as exc:  # a bad choice in the panel: say so, keep the window
            self.note(f"error: {exc}")
        finally:
            psim.PopItemWidth()
        for m in self.messages[-3:]:
            psim.TextWrapped(m)
        busy = self.busy()
        if busy != getattr(self, "_busy", None):  # fewer frames while workers fit: they share the cores
            self._busy = busy
            ps.set_max_fps(BUSY_FPS if busy else 60)
        pos, size = psim.GetWindowPos(), psim.GetWindowSize()
        self.panel_rect = (float(pos[0]), float(pos[1]), float(size[0]), float(size[1]))
        self.draw_colorbar()
        if self._stop or (self._exit_at is not None and now >= self._exit_at):
            self.write_state()
            ps.unshow()
        elif self.state_path is not None and now - self._state_written > 0.2:
            self.write_state()

    def draw_colorbar(self) -> None:
        """The error colour scale, drawn by the view itself (ImGui draw list) at the bottom left of the window,
        so it is in the window and in every screenshot: viridis from 0 to ``vmax`` mm with five ticks."""
        import polyscope as ps
        import polyscope.imgui as psim

        W, H = ps.get_window_size()
        dl = psim.GetBackgroundDrawList()
        x0, y0, w, h = 24.0, float(H - COLORBAR_H + 24), 300.0, 14.0
        dl.AddRectFilled((x0 - 10, y0 - 22), (x0 + w + 14, y0 + h + 22), color_u32((1, 1, 1), 0.85), 4.0)
        n = len(_VIRIDIS) - 1
        for i in range(n):  # one gradient quad per segment between samples
            a, b = x0 + w * i / n, x0 + w * (i + 1) / n
            ca, cb = color_u32(_VIRIDIS[i]), color_u32(_VIRIDIS[i + 1])
            dl.AddRectFilledMultiColor((a, y0), (b + 0.5, y0 + h), ca, cb, cb, ca)
        black = color_u32((0.1, 0.1, 0.1))
        dl.AddText((x0, y0 - 19), black, self.colorbar_title)
        for j, label in enumerate(self.colorbar_labels()):
            x = x0 + w * j / 4
            dl.AddLine((x, y0 + h), (x, y0 + h + 4), black)
            tw = psim.CalcTextSize(label)[0]
            dl.AddText((min(max(x - tw / 2, x0 - 8), x0 + w + 8 - tw), y0 + h + 4), black, label)

    def note(self, message: str) -> None:
        """Add ``message`` to the view's messages (the last three are shown under the panel)."""
        self.messages.append(message)

    # ------------------------------------------------------------------ camera, run, screenshots
    def frame_camera(self, reserve_right: int | None = None) -> None:
        """Front view framing the whole row in the part of the window left of the panel."""
        import polyscope as ps

        if self._bounds is None:
            ps.reset_camera_to_home_view()
            return
        lo, hi = self._bounds
        c, ext = (lo + hi) / 2.0, hi - lo
        W, H = ps.get_window_size()
        pane = self.panel_width if reserve_right is None else reserve_right
        avail = max(W - pane - 30, W * 0.3)
        avail_h = max(H - 2 * COLORBAR_H, H * 0.5)  # the colour scale below, the same margin above
        ps.set_vertical_fov_degrees(FOV_DEG)  # a narrow field: the copies at the ends are not seen askew
        t = math.tan(math.radians(FOV_DEG) / 2.0)
        half_h = 1.04 * max(ext[1] / 2.0 * H / avail_h, ext[0] / 2.0 * H / avail)
        D = half_h / t  # distance to the front of the faces
        world_per_px = 2.0 * D * t / H
        target = np.array([c[0] + (W / 2.0 - avail / 2.0 - 10) * world_per_px, c[1], c[2]])
        ps.look_at(np.array([target[0], target[1], hi[2] + D]), target)

    def world_to_screen(self, p) -> np.ndarray:
        """Pixel coordinates (x right, y down; window pixels, as the mouse reports them) of world points.

        ``p`` is ``(3,)`` or ``(m, 3)``; the result ``(2,)`` or ``(m, 2)``.
        """
        import polyscope as ps

        cam = ps.get_view_camera_parameters()
        E = np.asarray(cam.get_view_mat())
        P = np.atleast_2d(np.asarray(p, float))
        q = P @ E[:3, :3].T + E[:3, 3]
        t = math.tan(math.radians(cam.get_fov_vertical_deg()) / 2.0)
        W, H = ps.get_window_size()
        x = q[:, 0] / (-q[:, 2] * t * (W / H))
        y = q[:, 1] / (-q[:, 2] * t)
        out = np.c_[(x + 1.0) / 2.0 * W, (1.0 - y) / 2.0 * H]
        return out[0] if np.ndim(p) == 1 else out

    def screen_ray(self, xy) -> tuple[np.ndarray, np.ndarray]:
        """The camera ray through window pixel ``xy``: ``(origin, unit direction)`` in world space
        (the exact inverse of :meth:`world_to_screen`)."""
        import polyscope as ps

        cam = ps.get_view_camera_parameters()
        E = np.asarray(cam.get_view_mat())
        R, tr = E[:3, :3], E[:3, 3]
        t = math.tan(math.radians(cam.get_fov_vertical_deg()) / 2.0)
        W, H = ps.get_window_size()
        dc = np.array([(2.0 * xy[0] / W - 1.0) * t * (W / H), (1.0 - 2.0 * xy[1] / H) * t, -1.0])
        d = R.T @ dc
        return -R.T @ tr, d / np.linalg.norm(d)

    def setup_scene(self, width: int = 1600, height: int = 900, headless: bool = False) -> None:
        """Global look: window size, front view, no ground, panel width; then build and frame."""
        import polyscope as ps

        ps.remove_all_structures()
        ps.set_window_size(int(width), int(height))
        ps.set_up_dir("y_up")
        ps.set_front_dir("z_front")
        ps.set_ground_plane_mode("none")
        ps.set_background_color((1.0, 1.0, 1.0))
        ps.set_build_default_gui_panels(self.polyscope_panels)  # off: the faces are not hidden behind them
        ps.set_right_gui_pane_width(self.panel_width)
        ps.set_do_default_mouse_interaction(True)
        self._bounds = None
        self.build()
        ps.set_user_callback(self.callback)
        self.frame_camera()

    def screenshot(self, path, include_ui: bool = True) -> Path:
        """Render the current state to ``path`` (PNG); the panel is drawn too unless ``include_ui`` is False.

        Written atomically (:func:`facegeom.io.atomic_path`: ``open()``'s mode,
        symbolic links written through); polyscope reports no failure, so the
        image is checked: a missing or empty file is an :class:`InputError`
        naming ``path`` and ``path`` is left as it was.
        """
        import polyscope as ps

        from facegeom.io import atomic_path

        path = Path(path)
        if path.parent and not path.parent.exists():
            path.parent.mkdir(parents=True, exist_ok=True)
        self.frozen = True
        try:
            with atomic_path(path) as tmp:  # an empty file: it stays empty if polyscope cannot write it
                ps.frame_tick()  # lay the panel out once before capturing it
                ps.screenshot(str(tmp), transparent_bg=False, include_UI=include_ui)
                if not tmp.is_file() or tmp.stat().st_size == 0:
                    raise InputError("the screenshot could not be written (no image came out of polyscope)", path)
        finally:
            self.frozen = False
        return path

    def image(self, include_ui: bool = False) -> np.ndarray:
        """The current render as an ``(H, W, 3)`` uint8 array (for tests)."""
        import polyscope as ps

        self.frozen = True
        try:
            return ps.screenshot_to_buffer(transparent_bg=False, include_UI=include_ui)[..., :3].copy()
        finally:
            self.frozen = False

    def shown_faces(self) -> dict:
        """Name -> ``(n, 3)`` world positions of every face as drawn (row shift included); views fill it."""
        return {}

    def pending(self) -> list[str]:
        """Methods still working in the background (none by default)."""
        return []

    def busy(self) -> bool:
        """Whether a method is fitting in the background (the frame rate is capped meanwhile)."""
        return bool(self.pending())

    def wait(self, timeout: float | None = None) -> None:
        """Block until background work (fits in worker processes) is done; views without any return at once."""

    def close(self) -> None:
        """Release background resources (worker processes); views without any have nothing to do."""

    def state(self) -> dict:
        """What a script or a test may check about the window, as plain JSON values.

        Keys: ``ticks`` (frames drawn), ``frame_times`` (seconds since the view was
        made, one per frame, the last 5000), ``window`` (width, height), ``view_matrix``
        (the camera's 4x4), ``panel`` (x, y, w, h of the view's panel), ``polyscope_panels``,
        ``vmax`` (the colour scale's maximum, mm), ``widgets`` (label -> window box of every
        panel widget drawn, so a script can click it), ``copies`` (name -> screen box x0, y0, x1, y1
        of that face as drawn) and ``time``. Views add their own keys.
        """
        import polyscope as ps

        out = {"time": time.monotonic() - self.clock0, "ticks": self.ticks,
               "frame_times": [round(t, 4) for t in self.frame_times], "vmax": float(self.vmax),
               "panel": self.panel_rect, "polyscope_panels": self.polyscope_panels,
               "widgets": {k: v for k, v in self.ui.rects.items()}}
        if ps.is_initialized():
            out["window"] = list(ps.get_window_size())
            out["view_matrix"] = np.asarray(ps.get_camera_view_matrix(), float).tolist()
            boxes = {}
            for name, P in self.shown_faces().items():
                xy = self.world_to_screen(P)
                boxes[name] = [float(xy[:, 0].min()), float(xy[:, 1].min()), float(xy[:, 0].max()),
                                  float(xy[:, 1].max())]
            out["copies"] = boxes
        return out

    def write_state(self) -> None:
        """Write :meth:`state` to ``state_path`` (JSON, atomically), if one is set."""
        if self.state_path is None:
            return
        from facegeom.io import atomic_path

        self._state_written = time.monotonic()
        with atomic_path(self.state_path) as tmp:
            Path(tmp).write_text(json.dumps(self.state()))

    def run(self, screenshot=None, width: int = 1600, height: int = 900, echo=print, show: bool = False,
            exit_after: float | None = None, state_path=None) -> Path | None:
        """Show the viewer (blocks until closed), or with ``screenshot`` render one PNG headless and return.

        ``show=True`` with ``screenshot``: when a display is present, render the PNG
        in the window and then keep the window open (the demo's last step).
        ``exit_after`` closes the window after that many seconds; ``state_path``
        receives :meth:`state` as JSON five times a second and when the window
        closes (also on SIGTERM / SIGINT, which close the window cleanly): scripts
        and tests watch the real window through it.
        """
        check_display(screenshot)
        if exit_after is not None and not (exit_after > 0):
            raise InputError(f"the time before the window closes must be positive, got {exit_after}")
        self.state_path = None if state_path is None else Path(state_path)
        window = screenshot is None or (show and display_available())
        t = time.perf_counter()
        try:
            init_polyscope(headless=not window)
            self.setup_scene(width, height, headless=not window)
            out = None
            if screenshot is not None:
                self.wait()
                out = self.screenshot(screenshot)
                echo(f"wrote {out} ({time.perf_counter() - t:.1f} s)")
                if not window:
                    return out
            import polyscope as ps

            def stop(signum, frame):  # handled on the next frame, inside polyscope's loop
                self._stop = True

            old = {s: signal.signal(s, stop) for s in (signal.SIGTERM, signal.SIGINT)}
            try:
                if exit_after is not None:
                    self._exit_at = time.monotonic() + float(exit_after)
                ps.show()
            finally:
                for s, h in old.items():
                    signal.signal(s, h)
            self.write_state()
            return out
        finally:
            self.close()
