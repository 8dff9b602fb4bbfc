"""``facegeom view drive``: every deformer side by side, live under marker edits.

Row: the source face (rest identity), one face per selected method, the true
target. Every face is coloured by its per-vertex distance to the true target (mm,
one shared scale); markers are point clouds (on each method's face: the handle
positions it is driven with, which the user moves).

The case is built like ``facegeom bench drive`` builds one (a seeded identity,
a named or random sparse expression from :mod:`facegeom.model.expressions`, a marker
layout of :mod:`facegeom.model.layouts`), or taken from the benchmark itself
(``bench_case``: row ``case`` of ``facegeom bench drive --seed``). Methods come
from the registry (``facegeom.deformers`` entry points): each is fitted once on
the source, and a marker edit only calls every method's factorized ``deform``.
"""
from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass

import numpy as np

from facegeom import registry
from facegeom.constants import CM_TO_MM, FACE_AREA
from facegeom.errors import FacegeomError, InputError
from facegeom.metrics import face_errors_mm
from facegeom.model import KINDS, layout, named_expression, random_sparse_expression
from facegeom.model.scenarios import driving_cases
from facegeom.registry import LINEUPS, MethodSpec, parse_methods
from facegeom.viewer.app import MARKER_COLOR, SELECTED_COLOR, BaseView, error_mm, nice_ceiling, row_offsets

__all__ = ["DriveCase", "make_drive_case", "DriveView", "DEFAULT_METHODS", "LAYOUTS"]

DEFAULT_METHODS = "rbf;biharmonic;tangent"
LAYOUTS = ["ict80", "landmarks68", "random80", "random40"]
NUDGE_RANGE_MM = 20.0
_RBF_KERNELS = ("thin_plate_spline", "cubic", "quintic", "linear", "gaussian", "multiquadric",
                "inverse_multiquadric", "inverse_quadratic")


@dataclass
class DriveCase:
    """One source/target pair with its markers (all in the data's units, cm)."""

    description: str
    source: np.ndarray  # (n, 3) the identity's neutral face
    target: np.ndarray  # (n, 3) the same identity with the expression (the truth)
    handles: np.ndarray  # (k,) marker vertex ids
    labels: np.ndarray  # (k, 3) the markers' target positions


def make_drive_case(model, seed: int = 0, expression: str = "happiness", intensity: float = 0.9,
                    layout_name: str = "ict80", layout_seed: int = 0, bench_case: int | None = None) -> DriveCase:
    """A face-driving case: seeded identity + expression, or case ``bench_case`` of ``bench drive --seed seed``."""
    if bench_case is not None:
        if bench_case < 0:
            raise InputError(f"--bench-case must be >= 0, got {bench_case}")
        c = driving_cases(model, bench_case + 1, seed)[bench_case]
        identity, expr = c.identity, c.expression
        desc = f"bench drive case {bench_case} (seed {seed}): {c.kind}"
    else:
        if expression not in KINDS:
            raise InputError(f"unknown expression {expression!r}; choose one of {', '.join(KINDS)}")
        rng = np.random.default_rng(int(seed))
        identity = model.random_identity(rng)
        if expression == "random-sparse":
            expr = random_sparse_expression(model.expression_names, rng)
        else:
            expr = named_expression(expression, float(intensity))
        desc = f"identity seed {seed}: {expression}" + ("" if expression == "random-sparse" else f" x{intensity:.2f}")
    handles = layout(model, layout_name, layout_seed)
    X = model.identity_neutral(identity)
    T = model.face(identity, expr)
    desc += f"; {layout_name} ({handles.size} markers)"
    return DriveCase(desc, X, T, handles, T[handles].copy())


def _rbf_kernels() -> tuple[str, ...]:
    try:
        cls = registry.get("deformers", "rbf")
        return tuple(getattr(sys.modules[cls.__module__], "KERNELS", _RBF_KERNELS))
    except FacegeomError:
        return _RBF_KERNELS


class DriveView(BaseView):
    """Source | methods... | target, live under marker nudges and drags.

    Parameters
    ----------
    model : FaceModel
    methods : str or list of MethodSpec
        ``;``-separated specs as for ``facegeom bench drive`` (``[label=]name[:k=v,...]``).
    seed, expression, intensity, layout_name, layout_seed, bench_case
        The case (see :func:`make_drive_case`).
    """

    title = "facegeom view drive"

    def __init__(self, model, methods=DEFAULT_METHODS, seed: int = 0, expression: str = "happiness",
                 intensity: float = 0.9, layout_name: str = "ict80", layout_seed: int = 0,
                 bench_case: int | None = None):
        super().__init__()
        self.model = model
        specs = (parse_methods(methods, "deformers", LINEUPS["drive"]) if isinstance(methods, str)
                 else list(methods))
        if not specs:
            raise InputError("no method given: pass at least one deformer, e.g. --methods tangent")
        self.specs: dict[str, MethodSpec] = {s.label: s for s in specs}
        for name in registry.available("deformers"):  # every plugin can be switched on from the panel
            self.specs.setdefault(name, MethodSpec(name, name, {}))
        self.selected: list[str] = [s.label for s in specs]
        self.case_args = dict(seed=int(seed), expression=expression, intensity=float(intensity),
                              layout_name=layout_name, layout_seed=int(layout_seed), bench_case=bench_case)
        # panel parameters (applied to every tangent / rbf spec); start from the first spec's values
        tan = next((s.params for s in specs if s.name == "tangent"), {})
        self.tangent_d = int(tan.get("d", 2))
        self.tangent_beta = tan.get("beta", None)
        self.rbf_kernel = str(next((s.params.get("kernel") for s in specs if s.name == "rbf"
                                    and "kernel" in s.params), "thin_plate_spline"))
        self.kernels = list(_rbf_kernels())
        self.deformers: dict[str, object] = {}
        self.fit_s: dict[str, float] = {}
        self.deform_ms: dict[str, float] = {}
        self.results: dict[str, np.ndarray] = {}
        self.failed: dict[str, str] = {}
        self.marker = 0
        self._drag = None
        self._built = False
        self.load_case()

    # ------------------------------------------------------------------ model side (no polyscope)
    def load_case(self, **changes) -> None:
        """(Re)build the case, fit every selected method, deform with the labels; offsets reset."""
        self.case_args.update(changes)
        self.case = make_drive_case(self.model, **self.case_args)
        self.offsets = np.zeros_like(self.case.labels)
        self.marker = min(self.marker, self.case.handles.size - 1)
        self.deformers.clear()
        self.failed.clear()
        for label in self.selected:
            self.fit_method(label)
        self.update_deform(refresh=False)
        errs = [np.percentile(error_mm(Y, self.case.target)[:FACE_AREA], 99) for Y in self.results.values()]
        self.vmax = nice_ceiling(float(np.median(errs)) if errs else 5.0)  # a typical method's 99th pct.
        self.rebuild()

    def spec_for(self, label: str) -> MethodSpec:
        """The spec of method ``label`` with the panel's parameters applied.

        ``tangent`` specs get ``d`` and ``beta`` from ``tangent_d`` / ``tangent_beta``,
        ``rbf`` specs get ``kernel`` from ``rbf_kernel``; other specs keep their own
        parameters (copied). An unknown label raises ``KeyError``.
        """
        s = self.specs[label]
        params = dict(s.params)
        if s.name == "tangent":
            params.update(d=self.tangent_d, beta=self.tangent_beta)
        elif s.name == "rbf":
            params.update(kernel=self.rbf_kernel)
        return MethodSpec(s.label, s.name, params)

    def fit_method(self, label: str) -> None:
        """Build method ``label`` and fit it on the case's source face and handles (timed, in ``fit_s``).

        A :class:`~facegeom.errors.FacegeomError` is not raised: the message goes
        to ``failed[label]`` and the method's last face is dropped.
        """
        self.failed.pop(label, None)
        self.deformers.pop(label, None)
        try:
            d = self.spec_for(label).build("deformers")
            t = time.perf_counter()
            d.fit(self.case.source, self.model.triangles, self.case.handles)
            self.fit_s[label] = time.perf_counter() - t
            self.deformers[label] = d
        except FacegeomError as exc:
            self.failed[label] = str(exc)
            self.results.pop(label, None)

    def positions(self) -> np.ndarray:
        """The handle positions the methods are driven with: labels + user offsets, ``(k, 3)`` cm."""
        return self.case.labels + self.offsets

    def update_deform(self, refresh: bool = True) -> None:
        """One factorized ``deform`` per fitted method (timed), then refresh the faces."""
        P = self.positions()
        for label, d in self.deformers.items():
            try:
                t = time.perf_counter()
                Y = d.deform(P)
                self.deform_ms[label] = (time.perf_counter() - t) * 1e3
                self.results[label] = Y
            except FacegeomError as exc:
                self.failed[label] = str(exc)
        if refresh:
            self.refresh()

    def set_offset(self, marker: int, offset_cm) -> None:
        """Move marker ``marker`` to its label + ``offset_cm``; every method re-deforms. Sliders and drags land here."""
        k = self.case.handles.size
        if not 0 <= int(marker) < k:
            raise InputError(f"marker index {marker} is out of range [0, {k})")
        self.marker = int(marker)
        self.offsets[self.marker] = np.asarray(offset_cm, dtype=np.float64)
        self.update_deform()

    def nudge(self, marker: int, delta_mm) -> None:
        """Add ``delta_mm`` (3,) millimetres to marker ``marker``'s offset."""
        self.set_offset(marker, self.offsets[int(marker)] + np.asarray(delta_mm, float) / CM_TO_MM)

    def set_methods(self, labels: list[str]) -> None:
        """Select the methods shown (fitting the new ones)."""
        unknown = [x for x in labels if x not in self.specs]
        if unknown:
            raise InputError(f"no deformer {unknown[0]!r}; available: {', '.join(self.specs)}")
        new = [x for x in labels if x not in self.deformers]  # new ones, and failed ones again
        self.selected = list(labels)
        for label in new:
            self.fit_method(label)
        self.update_deform(refresh=False)
        self.rebuild()

    def set_params(self, **params) -> None:
        """Change the panel parameters (``tangent_d``, ``tangent_beta``, ``rbf_kernel``) and refit what they touch."""
        touched = set()
        for key, value in params.items():
            if key not in ("tangent_d", "tangent_beta", "rbf_kernel"):
                raise InputError(f"unknown viewer parameter {key!r}")
            setattr(self, key, value)
            touched.add("rbf" if key == "rbf_kernel" else "tangent")
        for label in self.selected:
            if self.specs[label].name in touched:
                self.fit_method(label)
        self.update_deform()

    def errors(self, label: str) -> dict:
        """``facegeom bench drive``'s error summary for one method's current face."""
        return face_errors_mm(self.results[label], self.case.target)

    # ------------------------------------------------------------------ scene
    def copies(self) -> list[str]:
        """Names of the faces in the row, left to right: ``source``, the selected methods, ``target``."""
        return ["source", *[x for x in self.selected], "target"]

    def build(self) -> None:
        """Register the row: source and target with their markers, one face per selected method with the
        handle positions it is driven with (a failed method's face is red), then :meth:`refresh`."""
        self._built = True
        c, F = self.case, self.model.triangles
        names = self.copies()
        self.shifts = dict(zip(names, row_offsets(c.source, len(names))))
        self.radius = 0.011 * float(np.ptp(c.source[:, 0]))
        self.mesh("source", c.source, F, self.shifts["source"])
        self.points("source markers", c.source[c.handles], self.shifts["source"], radius=self.radius)
        self.mesh("target", c.target, F, self.shifts["target"])
        self.points("target markers", c.labels, self.shifts["target"], radius=self.radius)
        for label in self.selected:
            V = self.results.get(label, c.source)
            m = self.mesh(label, V, F, self.shifts[label])
            if label in self.failed:
                m.set_color((0.9, 0.3, 0.3))
            self.points(f"{label} markers", self.positions(), self.shifts[label], radius=self.radius)
        self.refresh()

    def points(self, name, P, shift, color=MARKER_COLOR, radius=0.2):
        """Like :meth:`BaseView.points`, but ``radius`` is absolute, in world units (cm)."""
        pc = super().points(name, P, shift, color=color)
        pc.set_radius(radius, relative=False)
        return pc

    def refresh(self) -> None:
        """Push the current faces, markers and error colours to polyscope."""
        import polyscope as ps

        if not ps.is_initialized() or not self._built:
            return
        c = self.case
        self.error_colors(ps.get_surface_mesh("source"), error_mm(c.source, c.target), self.vmax)
        self.error_colors(ps.get_surface_mesh("target"), np.zeros(c.target.shape[0]), self.vmax)
        colors = np.tile(MARKER_COLOR, (c.handles.size, 1))
        colors[self.marker] = SELECTED_COLOR
        P = self.positions()
        for label in self.selected:
            if not ps.has_surface_mesh(label):
                continue
            pc = ps.get_point_cloud(f"{label} markers")
            pc.update_point_positions(P + self.shifts[label])
            pc.add_color_quantity("selected", colors, enabled=True)
            if label in self.results and label not in self.failed:
                m = ps.get_surface_mesh(label)
                m.update_vertex_positions(self.results[label] + self.shifts[label])
                self.error_colors(m, error_mm(self.results[label], c.target), self.vmax)

    # ------------------------------------------------------------------ dragging
    def _copy_of_cloud(self, name: str) -> str | None:
        for label in self.selected:
            if name == f"{label} markers":
                return label
        return None

    def begin_drag(self, screen_xy) -> bool:
        """Pick at ``screen_xy``; on a method's marker, select it and start dragging. Returns whether it did."""
        import polyscope as ps

        r = ps.pick(screen_coords=tuple(float(x) for x in screen_xy))
        label = self._copy_of_cloud(r.structure_name) if r.is_hit else None
        if label is None:
            return False
        m = int(r.structure_data.get("index", r.local_index))
        cam = ps.get_view_camera_parameters()
        anchor = self.positions()[m] + self.shifts[label]
        self._drag = (m, label, anchor, np.asarray(cam.get_look_dir(), float))
        self.marker = m
        ps.set_do_default_mouse_interaction(False)
        self.refresh()
        return True

    def drag_to(self, screen_xy) -> None:
        """Move the dragged marker under ``screen_xy``, in the plane through it facing the camera."""
        import polyscope as ps

        if self._drag is None:
            return
        m, label, anchor, n = self._drag
        o = np.asarray(ps.get_view_camera_parameters().get_position(), float)
        d = ps.screen_coords_to_world_ray(tuple(float(x) for x in screen_xy))
        denom = float(d @ n)
        if abs(denom) < 1e-9:
            return
        hit = o + d * float((anchor - o) @ n) / denom
        self.set_offset(m, hit - self.shifts[label] - self.case.labels[m])

    def end_drag(self) -> None:
        """Stop dragging and give the mouse back to polyscope's camera controls."""
        import polyscope as ps

        self._drag = None
        ps.set_do_default_mouse_interaction(True)

    def handle_mouse(self) -> None:
        """Mouse dragging, once per frame: a left click the panel does not take starts a drag
        (:meth:`begin_drag`), holding the button moves the marker (:meth:`drag_to`), releasing it ends the drag."""
        import polyscope.imgui as psim

        io = psim.GetIO()
        if self._drag is None:
            if psim.IsMouseClicked(0) and not io.WantCaptureMouse:
                self.begin_drag(io.MousePos)
        elif psim.IsMouseDown(0):
            self.drag_to(io.MousePos)
        else:
            self.end_drag()

    # ------------------------------------------------------------------ panel
    def callback(self) -> None:
        """:meth:`BaseView.callback`, then mouse dragging (not while a screenshot is taken)."""
        super().callback()
        if not self.frozen:
            self.handle_mouse()

    def panel(self) -> None:
        """Per-method timings and errors (mm), then the Case, Methods and Marker sections.

        Every change goes through the matching method (:meth:`load_case`,
        :meth:`set_methods`, :meth:`set_params`, :meth:`set_offset`).
        """
        import polyscope.imgui as psim

        ui, c = self.ui, self.case
        psim.TextUnformatted(c.description)
        psim.TextWrapped("left to right: " + " | ".join(self.copies()))
        psim.TextUnformatted("colour: distance to the true target (mm)")
        ch, v = ui.slider_float("colour max (mm)", self.vmax, 0.1, 50.0, "%.1f")
        if ch:
            self.vmax = float(v)
            self.refresh()
        psim.TextUnformatted("per method: last deform (ms), fit (s); error over the face area (mm)")
        for label in self.selected:
            if label in self.failed:
                psim.TextColored((1.0, 0.3, 0.3, 1.0), f"{label}: failed: {self.failed[label]}")
                continue
            if label not in self.results:
                continue
            e = self.errors(label)
            psim.TextUnformatted(f"{label}: deform {self.deform_ms.get(label, float('nan')):.2f} ms, "
                                 f"fit {self.fit_s.get(label, float('nan')):.2f} s")
            psim.TextUnformatted(f"    mean {e['mean_mm']:.2f} mm, RMS {e['rms_mm']:.2f} mm, max {e['max_mm']:.1f} mm")
        psim.Separator()

        if psim.CollapsingHeader("Case", psim.ImGuiTreeNodeFlags_DefaultOpen):
            a = self.case_args
            changes = {}
            ch, v = ui.input_int("identity seed", a["seed"])
            if ch:
                changes["seed"] = int(v)
            if a["bench_case"] is not None:
                ch, v = ui.input_int("bench case", a["bench_case"])
                if ch:
                    changes["bench_case"] = max(0, int(v))
                if ui.button("use a named expression instead"):
                    changes["bench_case"] = None
            else:
                ch, v = ui.combo("expression", a["expression"], list(KINDS))
                if ch:
                    changes["expression"] = v
                ch, v = ui.slider_float("intensity", a["intensity"], 0.0, 1.5, "%.2f")
                if ch and a["expression"] != "random-sparse":
                    changes["intensity"] = float(v)
            layouts = LAYOUTS if a["layout_name"] in LAYOUTS else [a["layout_name"], *LAYOUTS]
            ch, v = ui.combo("marker layout", a["layout_name"], layouts)
            if ch:
                changes["layout_name"] = v
            if a["layout_name"].startswith("random"):
                ch, v = ui.input_int("layout seed", a["layout_seed"])
                if ch:
                    changes["layout_seed"] = int(v)
            if changes:
                self.load_case(**changes)

        if psim.CollapsingHeader("Methods", psim.ImGuiTreeNodeFlags_DefaultOpen):
            chosen = list(self.selected)
            for label in self.specs:
                ch, on = ui.checkbox(label, label in self.selected)
                if ch:
                    chosen = [x for x in self.specs if (x in chosen or x == label) and (on or x != label)]
            if chosen != self.selected and chosen:
                self.set_methods(chosen)
            ch, v = ui.slider_int("tangent d", self.tangent_d, 1, 3)
            if ch:
                self.set_params(tangent_d=int(v))
            ch, hard = ui.checkbox("tangent: hard constraints (beta = None)", self.tangent_beta is None)
            if ch:
                self.set_params(tangent_beta=None if hard else 100.0)
            if self.tangent_beta is not None:
                ch, v = ui.slider_float("tangent log10 beta", math.log10(self.tangent_beta), -2.0, 4.0, "%.2f")
                if ch:
                    self.set_params(tangent_beta=float(10.0 ** v))
            ch, v = ui.combo("rbf kernel", self.rbf_kernel, self.kernels)
            if ch:
                self.set_params(rbf_kernel=v)

        if psim.CollapsingHeader("Marker", psim.ImGuiTreeNodeFlags_DefaultOpen):
            psim.TextWrapped("Drag a marker on any method's face with the left mouse button, or nudge it:")
            k = c.handles.size
            ch, v = ui.slider_int("marker", self.marker, 0, k - 1)
            if ch:
                self.marker = int(v)
                self.refresh()
            off = self.offsets[self.marker] * CM_TO_MM
            new = off.copy()
            for i, axis in enumerate("xyz"):
                ch, v = ui.slider_float(f"d{axis} (mm)", off[i], -NUDGE_RANGE_MM, NUDGE_RANGE_MM, "%.2f")
                if ch:
                    new[i] = v
            if not np.array_equal(new, off):
                self.set_offset(self.marker, new / CM_TO_MM)
            if ui.button("reset marker"):
                self.set_offset(self.marker, np.zeros(3))
            psim.SameLine()
            if ui.button("reset all"):
                self.offsets[:] = 0.0
                self.update_deform()
            psim.TextUnformatted(f"vertex {int(c.handles[self.marker])}, offset "
                                 f"{np.linalg.norm(self.offsets[self.marker]) * CM_TO_MM:.2f} mm")

