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

import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from facegeom.constants import CM_TO_MM
from facegeom.errors import FacegeomError, InputError

__all__ = ["NO_DISPLAY", "display_available", "check_display", "init_polyscope", "parse_size", "Widgets",
           "BaseView", "error_mm", "row_offsets"]

CMAP = "viridis"
FOV_DEG = 15.0
MARKER_COLOR = (0.95, 0.35, 0.1)
SELECTED_COLOR = (1.0, 0.0, 0.6)
TRUTH_COLOR = (0.78, 0.78, 0.8)

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
            hint = (" (headless rendering needs EGL: apt install libegl1 libegl-mesa0 libgl1-mesa-dri)"
                    if headless else "")
            raise InputError(f"polyscope could not start a renderer: {exc}{hint}") from None
    return ps.get_render_engine_backend_name()


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


def row_offsets(V: np.ndarray, count: int, gap: float = 0.12) -> np.ndarray:
    """``(count, 3)`` shifts placing ``count`` copies of a face like ``V`` side by side along x."""
    width = float(np.ptp(np.asarray(V)[:, 0]))
    return np.c_[np.arange(count) * width * (1.0 + gap), np.zeros((count, 2))]


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

    def set(self, label: str, value) -> None:
        """Queue ``value`` for the widget ``label``: its next draw reports a change to ``value``.

        Buttons take ``True``; a combo box takes the item itself, not its index.
        """
        self.pending[label] = value

    def _take(self, label, changed, value):
        if label in self.pending:
            return True, self.pending.pop(label)
        return changed, value

    def slider_float(self, label, v, lo, hi, fmt="%.3f"):
        """A float slider over ``[lo, hi]`` showing ``v`` (printf format ``fmt``) -> ``(changed, value)``."""
        import polyscope.imgui as psim

        return self._take(label, *psim.SliderFloat(label, float(v), float(lo), float(hi), format=fmt))

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
        if label in self.pending:
            return bool(self.pending.pop(label))
        return pressed


class BaseView:
    """A row of faces (shifted copies along x) with a panel; subclasses fill ``build`` and ``panel``."""

    title = "facegeom"
    panel_width = 420

    def __init__(self):
        self.ui = Widgets()
        self.ticks = 0
        self.frozen = False  # True while taking a screenshot: no playback advance
        self.messages: list[str] = []
        self._bounds = None
        self._built = False  # set by build(): the structures are registered

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
        import polyscope.imgui as psim

        self.ticks += 1
        psim.PushItemWidth(self.panel_width * 0.45)
        try:
            self.panel()
        except FacegeomError as exc:  # a bad choice in the panel: say so, keep the window
            self.note(f"error: {exc}")
        finally:
            psim.PopItemWidth()
        for m in self.messages[-3:]:
            psim.TextWrapped(m)

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
        ps.set_vertical_fov_degrees(FOV_DEG)  # a narrow field: the copies at the ends are not seen askew
        t = math.tan(math.radians(FOV_DEG) / 2.0)
        half_h = 1.04 * max(ext[1] / 2.0, ext[0] / 2.0 * H / avail)
        D = half_h / t  # distance to the front of the faces
        world_per_px = 2.0 * D * t / H
        target = np.array([c[0] + (W / 2.0 - avail / 2.0 - 10) * world_per_px, c[1], c[2]])
        ps.look_at(np.array([target[0], target[1], hi[2] + D]), target)

    def world_to_screen(self, p) -> np.ndarray:
        """Pixel coordinates (x right, y down) of a world point in the current view."""
        import polyscope as ps

        cam = ps.get_view_camera_parameters()
        E = np.asarray(cam.get_view_mat())
        q = E @ np.r_[np.asarray(p, float), 1.0]
        t = math.tan(math.radians(cam.get_fov_vertical_deg()) / 2.0)
        W, H = ps.get_window_size()
        x = q[0] / (-q[2] * t * cam.get_aspect())
        y = q[1] / (-q[2] * t)
        return np.array([(x + 1.0) / 2.0 * W, (1.0 - y) / 2.0 * H])

    def setup_scene(self, width: int = 1600, height: int = 900, headless: bool = False) -> None:
        """Global look: window size, front view, no ground, panel width; then build and frame."""
        import polyscope as ps

        ps.remove_all_structures()
        ps.set_window_size(int(width), int(height))
        ps.set_up_dir("y_up")
        ps.set_front_dir("z_front")
        ps.set_ground_plane_mode("none")
        ps.set_background_color((1.0, 1.0, 1.0))
        ps.set_build_default_gui_panels(not headless)
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

    def run(self, screenshot=None, width: int = 1600, height: int = 900, echo=print, show: bool = False) -> Path | None:
        """Show the viewer (blocks until closed), or with ``screenshot`` render one PNG headless and return.

        ``show=True`` with ``screenshot``: when a display is present, render the PNG
        in the window and then keep the window open (the demo's last step).
        """
        check_display(screenshot)
        window = screenshot is None or (show and display_available())
        t = time.perf_counter()
        init_polyscope(headless=not window)
        self.setup_scene(width, height, headless=not window)
        out = None
        if screenshot is not None:
            out = self.screenshot(screenshot)
            echo(f"wrote {out} ({time.perf_counter() - t:.1f} s)")
            if not window:
                return out
        import polyscope as ps

        ps.show()
        return out
