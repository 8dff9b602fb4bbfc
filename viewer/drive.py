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

Or the user's own files (:func:`read_drive_files`, ``facegeom view drive MESH
MARKERS``): the mesh and the marker CSV are read and checked by the very readers
``facegeom drive MESH MARKERS`` uses, and every method is built as that command
builds it (:class:`DriveSpec`: its ``--proxy`` policy, the deformer's own default
parameters), so the ``tangent`` face is what ``facegeom drive MESH MARKERS -o OUT``
writes. There is no true target then: the row is the mesh | one face per method,
coloured by how far each vertex moved (mm, the mesh's unit found from its size).
"""
from __future__ import annotations

import inspect
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from facegeom import registry
from facegeom.constants import CM_TO_MM, FACE_AREA
from facegeom.errors import FacegeomError, InputError
from facegeom.metrics import face_errors_mm
from facegeom.model import KINDS, layout, named_expression, random_sparse_expression
from facegeom.model.scenarios import driving_cases
from facegeom.registry import LINEUPS, MethodSpec, parse_methods
from facegeom.viewer.app import (
    MARKER_COLOR,
    SELECTED_COLOR,
    TRUTH_COLOR,
    BaseView,
    error_mm,
    nice_ceiling,
    row_offsets,
)
from facegeom.viewer.dragging import MarkerDragging

__all__ = ["DriveCase", "make_drive_case", "read_drive_files", "DriveSpec", "DriveView", "DEFAULT_METHODS",
           "FILE_METHODS", "LAYOUTS"]

DEFAULT_METHODS = "rbf;biharmonic;tangent"
#: The methods shown for the user's files: ``facegeom drive``'s default deformer first, then the other two of
#: :data:`DEFAULT_METHODS` to compare with (``facegeom.cli.view`` takes the first from the drive command itself).
FILE_METHODS = "tangent;rbf;biharmonic"
LAYOUTS = ["ict80", "landmarks68", "random80", "random40"]
NUDGE_RANGE_MM = 20.0
KEY_STEP_MM = 0.5  # one arrow-key press (x4 with shift)
NEAR_CM = 1.0  # "near the marker": rest-shape vertices within this distance of its vertex (state file)
FAILED_COLOR = (0.9, 0.3, 0.3)
_RBF_KERNELS = ("thin_plate_spline", "cubic", "quintic", "linear", "gaussian", "multiquadric",
                "inverse_multiquadric", "inverse_quadratic")


@dataclass
class DriveCase:
    """One source/target pair with its markers (in the data's units: cm for the face model, the file's own for
    the user's files).

    Attributes
    ----------
    description : str
        One line for the panel.
    source : (n, 3) float64
        The mesh driven (the identity's neutral face, or the user's mesh).
    target : (n, 3) float64 or None
        The same identity with the expression (the truth); ``None`` for the user's files (no truth).
    handles : (k,) int64
        Marker vertex ids.
    labels : (k, 3) float64
        The markers' positions (where the handles are driven to).
    triangles : (m, 3) int64 or None
        The mesh's triangles; ``None``: the face model's.
    unit_mm : float
        Millimetres per unit of the coordinates (10: the face model's cm).
    files : tuple of str
        ``(MESH, MARKERS)`` of the user's files; empty for a built-in case.
    """

    description: str
    source: np.ndarray  # (n, 3) the identity's neutral face
    target: np.ndarray | None  # (n, 3) the same identity with the expression (the truth), None for user files
    handles: np.ndarray  # (k,) marker vertex ids
    labels: np.ndarray  # (k, 3) the markers' target positions
    triangles: np.ndarray | None = None  # (m, 3); None: the face model's
    unit_mm: float = CM_TO_MM
    files: tuple = field(default_factory=tuple)


def read_drive_files(mesh, markers) -> DriveCase:
    """The user's mesh and markers as a :class:`DriveCase`, read and checked as ``facegeom drive MESH MARKERS``
    reads them (:func:`facegeom.io.read_mesh`, :func:`facegeom.io.read_markers` with the mesh's vertex count).

    The unit (for the millimetres the panel and the colours speak in) is found from the mesh's size
    (:func:`facegeom.model.units.find_units`: mm, cm or m); the coordinates are not changed.

    Raises
    ------
    InputError
        A file missing, unreadable or malformed, a marker vertex id out of the mesh's range or repeated: one
        line naming the file (the messages of ``facegeom drive``).
    """
    from facegeom.io import read_markers, read_mesh
    from facegeom.model.units import TO_CM, find_units

    V, F = read_mesh(mesh)
    ids, pos = read_markers(markers, n_vertices=V.shape[0])
    try:
        unit, _ = find_units(V)
    except (FacegeomError, ValueError, FloatingPointError):  # a degenerate mesh: no size to tell a unit by
        unit = "cm"
    desc = (f"{Path(mesh).name} ({V.shape[0]} vertices, {F.shape[0]} triangles; unit: {unit}, from its size) "
            f"driven by {Path(markers).name} ({ids.size} markers)")
    return DriveCase(desc, V, None, ids, pos, triangles=F, unit_mm=TO_CM[unit] * CM_TO_MM,
                     files=(str(mesh), str(markers)))


@dataclass(frozen=True)
class DriveSpec(MethodSpec):
    """A deformer spec built as ``facegeom drive`` builds its method: wrapped in its ``--proxy`` policy.

    ``proxy`` is the ``--proxy`` text (``auto``, ``off`` or a vertex count): with ``auto`` (the command's
    default) meshes above :data:`facegeom.pipelines.proxy.PROXY_ABOVE` vertices are solved on a decimated
    proxy, smaller ones directly, exactly as the command does. Picklable (the window's worker processes
    build it).
    """

    proxy: str = "auto"

    def build(self, kind: str):
        """The deformer, wrapped in :class:`~facegeom.pipelines.proxy.ProxyDeformer` unless ``proxy`` is off."""
        from facegeom.pipelines.proxy import PROXY_ABOVE, ProxyDeformer, proxy_policy

        deformer = super().build(kind)
        size = proxy_policy(self.proxy)
        if size is None:
            return deformer
        above = PROXY_ABOVE if self.proxy.strip().lower() == "auto" else size
        return ProxyDeformer(deformer, vertices=size, above=above)


def _default_param(name: str, param: str, fallback):
    """The registered deformer ``name``'s default for constructor parameter ``param`` (``fallback`` if none)."""
    try:
        p = inspect.signature(registry.get("deformers", name)).parameters.get(param)
    except (FacegeomError, TypeError, ValueError):
        return fallback
    return fallback if p is None or p.default is inspect.Parameter.empty else p.default


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


class DriveView(MarkerDragging, BaseView):
    """Source | methods... | target, live under marker drags, arrow keys and slider nudges.

    Parameters
    ----------
    model : FaceModel or None
        The face model of the built-in cases; ``None`` with ``case`` (the user's files need no face data).
    methods : str or list of MethodSpec
        ``;``-separated specs as for ``facegeom bench drive`` (``[label=]name[:k=v,...]``).
    seed, expression, intensity, layout_name, layout_seed, bench_case
        The case (see :func:`make_drive_case`).
    case : DriveCase, optional
        Show this case instead, e.g. the user's files (:func:`read_drive_files`): the case panel is left out,
        every method is built as ``facegeom drive`` builds it (:class:`DriveSpec` with ``proxy``) and starts
        from the deformer's own default parameters (tangent's ``beta="auto"``), so a method's face is what
        ``facegeom drive MESH MARKERS -m METHOD`` writes. Without a target the faces are coloured by how far
        each vertex moved.
    proxy : str
        With ``case``: ``facegeom drive --proxy`` (``auto``, ``off`` or a vertex count).
    background : bool
        Fit and deform every method in its own worker process
        (:mod:`facegeom.viewer.workers`): the window never waits for a fit and a
        method still fitting shows "fitting..." while the others keep updating.
        ``False`` (scripts, tests, screenshots) fits and deforms in this process, in order.
    """

    title = "facegeom view drive"
    colorbar_title = "distance to the true target (mm)"

    def __init__(self, model, methods=DEFAULT_METHODS, seed: int = 0, expression: str = "happiness",
                 intensity: float = 0.9, layout_name: str = "ict80", layout_seed: int = 0,
                 bench_case: int | None = None, background: bool = False, case: DriveCase | None = None,
                 proxy: str = "auto"):
        super().__init__()
        self.model = model
        if case is None and model is None:
            raise InputError("no case: give the face model (built-in cases) or a case (the user's files)")
        self.given_case = case
        self.proxy = str(proxy)
        if case is not None:
            from facegeom.pipelines.proxy import proxy_policy

            proxy_policy(self.proxy)  # a bad setting: one line now, not one per method later
            self.colorbar_title = "displacement from the mesh (mm)"
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
        # panel parameters (applied to every tangent / rbf spec); start from the first spec's values, else (the
        # user's files) the deformer's own defaults, as `facegeom drive` builds it, or (built-in cases) tangent
        # with hard constraints
        tan = next((s.params for s in specs if s.name == "tangent"), {})
        own = case is not None
        self.tangent_d = int(tan.get("d", _default_param("tangent", "d", 2) if own else 2))
        self.tangent_beta = tan.get("beta", _default_param("tangent", "beta", "auto") if own else None)
        self.rbf_kernel = str(next((s.params.get("kernel") for s in specs if s.name == "rbf"
                                    and "kernel" in s.params),
                                   _default_param("rbf", "kernel", "thin_plate_spline") if own
                                   else "thin_plate_spline"))
        self.kernels = list(_rbf_kernels())
        self.background = bool(background)
        self.deformers: dict[str, object] = {}  # in-process mode only
        self.status: dict[str, str] = {}  # label -> "fitting" | "ready" | "failed"
        self.fit_started: dict[str, float] = {}
        self.fit_log: list[dict] = []  # every finished fit: label, start, end (s since the view was made), status
        self.fit_s: dict[str, float] = {}
        self.deform_ms: dict[str, float] = {}
        self.results: dict[str, np.ndarray] = {}
        self.failed: dict[str, str] = {}
        self.workers: dict = {}  # label -> MethodWorker (background mode)
        self._jobs: dict[str, dict[int, tuple]] = {}  # label -> job id -> ("fit", None) | ("deform", version)
        self._shown_version: dict[str, int] = {}
        self.version = 0  # bumped by every marker change
        self.marker = 0
        self.hover: int | None = None
        self._drag = None
        self.drags = 0  # drags completed (state file)
        self._auto_vmax = True
        self._near: dict = {}
        self._built = False
        self.load_case()

    # ------------------------------------------------------------------ model side (no polyscope)
    def load_case(self, **changes) -> None:
        """(Re)build the case, fit every selected method, deform with the labels; offsets reset.

        In background mode the fits only start here; :meth:`poll` installs them.
        """
        self.case_args.update(changes)
        self.case = self.given_case if self.given_case is not None else make_drive_case(self.model, **self.case_args)
        self.offsets = np.zeros_like(self.case.labels)
        self.version += 1
        self.marker = min(self.marker, self.case.handles.size - 1)
        self.deformers.clear()
        self.failed.clear()
        self.results.clear()
        self._near = {}
        for label in self.selected:
            self.fit_method(label)
        self.update_deform(refresh=False)
        self._auto_vmax = True
        self._set_auto_vmax()
        self.rebuild()

    @property
    def triangles(self) -> np.ndarray:
        """The ``(m, 3)`` triangles of the case's mesh."""
        return self.case.triangles if self.case.triangles is not None else self.model.triangles

    def colour_values(self, Y: np.ndarray) -> np.ndarray:
        """What a face ``Y (n, 3)`` is coloured by (mm): its distance to the true target, or without one (the
        user's files) how far each vertex moved from the mesh."""
        c = self.case
        return np.linalg.norm(Y - (c.source if c.target is None else c.target), axis=1) * c.unit_mm

    def _set_auto_vmax(self) -> None:
        """The colour scale from a typical method's 99th percentile, once every method has a face."""
        if not self._auto_vmax or any(self.status.get(x) == "fitting" for x in self.selected):
            return
        area = slice(None) if self.case.target is None else slice(FACE_AREA)  # the face model's face area
        errs = [np.percentile(self.colour_values(Y)[area], 99) for x, Y in self.results.items()
                if x in self.selected]
        self.vmax = nice_ceiling(float(np.median(errs)) if errs else 5.0)
        self._auto_vmax = False

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
        if self.given_case is not None:  # built as `facegeom drive` builds it (its --proxy policy)
            return DriveSpec(s.label, s.name, params, proxy=self.proxy)
        return MethodSpec(s.label, s.name, params)

    def fit_method(self, label: str) -> None:
        """Build method ``label`` and fit it on the case's source face and handles (timed, in ``fit_s``).

        A :class:`~facegeom.errors.FacegeomError` is not raised: the message goes
        to ``failed[label]`` and the method's last face is dropped. In background
        mode the fit is sent to the method's worker and ``status[label]`` is
        ``"fitting"`` until :meth:`poll` sees the answer (the last face stays shown).
        """
        self.failed.pop(label, None)
        self.deformers.pop(label, None)
        self.fit_started[label] = time.monotonic() - self.clock0
        if self.background:
            from facegeom.viewer.workers import MethodWorker

            if label not in self.workers:
                self.workers[label] = MethodWorker()
            job = self.workers[label].submit("fit_deformer", (self.spec_for(label), self.case.source,
                                                              self.triangles, self.case.handles))
            self._jobs.setdefault(label, {})[job] = ("fit", None)
            self.status[label] = "fitting"
            return
        try:
            d = self.spec_for(label).build("deformers")
            t = time.perf_counter()
            d.fit(self.case.source, self.triangles, self.case.handles)
            self.fit_s[label] = time.perf_counter() - t
            self.deformers[label] = d
            self.status[label] = "ready"
        except FacegeomError as exc:
            self.failed[label] = str(exc)
            self.status[label] = "failed"
            self.results.pop(label, None)
        self._log_fit(label)

    def _log_fit(self, label: str) -> None:
        self.fit_log.append({"label": label, "start": self.fit_started.get(label, 0.0),
                             "end": time.monotonic() - self.clock0, "status": self.status.get(label)})

    def positions(self) -> np.ndarray:
        """The handle positions the methods are driven with: labels + user offsets, ``(k, 3)`` cm."""
        return self.case.labels + self.offsets

    def update_deform(self, refresh: bool = True) -> None:
        """One factorized ``deform`` per fitted method (timed), then refresh the faces.

        In background mode the new positions go to every ready worker and the faces
        change when :meth:`poll` collects the answers.
        """
        if self.background:
            self.poll()
            return
        P = self.positions()
        for label, d in self.deformers.items():
            try:
                t = time.perf_counter()
                Y = d.deform(P)
                self.deform_ms[label] = (time.perf_counter() - t) * 1e3
                self.results[label] = Y
            except FacegeomError as exc:
                self.failed[label] = str(exc)
                self.status[label] = "failed"
        if refresh:
            self.refresh()

    def poll(self) -> bool:
        """Background mode: collect finished fits and deforms, send the newest marker positions to every
        ready worker that is idle. Never blocks. Returns whether a face changed."""
        changed = False
        for label, w in list(self.workers.items()):
            jobs = self._jobs.setdefault(label, {})
            for job, status, payload, secs in w.poll():
                kind, version = jobs.pop(job, (None, None))
                if kind == "fit" and not any(k == "fit" for k, _ in jobs.values()):  # the newest fit
                    if status == "ok":
                        self.status[label] = "ready"
                        self.fit_s[label] = secs
                        self._shown_version.pop(label, None)
                    else:
                        self.status[label] = "failed"
                        self.failed[label] = payload
                        self.results.pop(label, None)
                        changed = True
                    self._log_fit(label)
                elif kind == "deform":
                    if status == "ok":
                        self.results[label] = payload
                        self.deform_ms[label] = secs * 1e3
                        self._shown_version[label] = version
                        changed = True
                    elif not any(k == "fit" for k, _ in jobs.values()):
                        self.status[label] = "failed"
                        self.failed[label] = payload
            if (label in self.selected and self.status.get(label) == "ready" and not jobs
                    and self._shown_version.get(label) != self.version):
                job = w.submit("deform", self.positions())
                jobs[job] = ("deform", self.version)
        if changed:
            self._set_auto_vmax()
            self.refresh()
        return changed

    def pending(self) -> list[str]:
        """Selected methods whose fit or newest deform has not come back yet (background mode)."""
        return [x for x in self.selected if self.status.get(x) == "fitting"
                or (self.status.get(x) == "ready" and self._shown_version.get(x, -1) != self.version)
                ] if self.background else []

    def busy(self) -> bool:
        """Whether a selected method is fitting (deforms in flight do not count)."""
        return any(self.status.get(x) == "fitting" for x in self.selected)

    def wait(self, timeout: float | None = 120.0) -> None:
        """Background mode: poll until every selected method has fitted and shows the newest markers."""
        t = time.monotonic()
        while self.pending() and (timeout is None or time.monotonic() - t < timeout):
            self.poll()
            time.sleep(0.01)
        self.poll()

    def close(self) -> None:
        """Stop the worker processes."""
        for w in self.workers.values():
            w.close()
        self.workers.clear()
        self._jobs.clear()

    def set_offset(self, marker: int, offset_cm) -> None:
        """Move marker ``marker`` to its label + ``offset_cm`` (in the case's units: cm for the face model, the
        mesh's own for the user's files); every method re-deforms. Sliders, keys and drags land here."""
        k = self.case.handles.size
        if not 0 <= int(marker) < k:
            raise InputError(f"marker index {marker} is out of range [0, {k})")
        self.marker = int(marker)
        self.offsets[self.marker] = np.asarray(offset_cm, dtype=np.float64)
        self.version += 1
        self.update_deform()

    def nudge(self, marker: int, delta_mm) -> None:
        """Add ``delta_mm`` (3,) millimetres to marker ``marker``'s offset."""
        self.set_offset(marker, self.offsets[int(marker)] + np.asarray(delta_mm, float) / self.case.unit_mm)

    def set_methods(self, labels: list[str]) -> None:
        """Select the methods shown (fitting the new ones)."""
        unknown = [x for x in labels if x not in self.specs]
        if unknown:
            raise InputError(f"no deformer {unknown[0]!r}; available: {', '.join(self.specs)}")
        new = [x for x in labels if self.status.get(x) not in ("ready", "fitting")]  # new ones, failed ones again
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
        """``facegeom bench drive``'s error summary for one method's current face.

        Without a target (the user's files): ``moved_max_mm`` / ``moved_mean_mm``, how far the vertices moved,
        and ``at_markers_max_mm``, the largest distance from a marker vertex to its marker (0 for a method that
        interpolates its markers; a soft fit such as tangent's ``beta="auto"`` leaves some).
        """
        c = self.case
        Y = self.results[label]
        if c.target is not None:
            return face_errors_mm(Y, c.target)
        moved = self.colour_values(Y)
        at = np.linalg.norm(Y[c.handles] - self.positions(), axis=1) * c.unit_mm
        return {"moved_max_mm": float(moved.max()), "moved_mean_mm": float(moved.mean()),
                "at_markers_max_mm": float(at.max())}

    # ------------------------------------------------------------------ scene
    def copies(self) -> list[str]:
        """Names of the faces in the row, left to right: ``source``, the selected methods, ``target`` (when the
        case has one)."""
        return ["source", *[x for x in self.selected], *(["target"] if self.case.target is not None else [])]

    def draggable(self) -> list[str]:
        """The copies whose markers the mouse can grab: every method's face and the target (if any)."""
        return [*self.selected, *(["target"] if self.case.target is not None else [])]

    def face(self, name: str) -> np.ndarray:
        """The ``(n, 3)`` face drawn as copy ``name`` (without its row shift): a method's last result, or the
        source while it has none."""
        c = self.case
        if name == "source":
            return c.source
        if name == "target":
            return c.target
        return self.results.get(name, c.source)

    def shown_faces(self) -> dict:
        """Copy name -> its face as drawn, row shift included."""
        return {n: self.face(n) + self.shifts[n] for n in self.copies()} if self._built else {}

    def build(self) -> None:
        """Register the row: source and target with their markers, one face per selected method with the
        handle positions it is driven with (a failed method's face is red, a fitting one grey), then
        :meth:`refresh`. On the target, the markers show where the methods are driven to."""
        self._built = True
        c, F = self.case, self.triangles
        names = self.copies()
        self.shifts = dict(zip(names, row_offsets(c.source, len(names))))
        self.radius = 0.011 * float(np.ptp(c.source[:, 0]))
        self.mesh("source", c.source, F, self.shifts["source"])
        self.points("source markers", c.source[c.handles], self.shifts["source"], radius=self.radius)
        if c.target is not None:
            self.mesh("target", c.target, F, self.shifts["target"])
            self.points("target markers", self.positions(), self.shifts["target"], radius=self.radius)
        for label in self.selected:
            m = self.mesh(label, self.face(label), F, self.shifts[label])
            if label in self.failed:
                m.set_color(FAILED_COLOR)
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

        self._capture_rest_faces()
        if not ps.is_initialized() or not self._built:
            return
        c = self.case
        if c.target is not None:  # without one the mesh itself stays grey: nothing moved
            self.error_colors(ps.get_surface_mesh("source"), error_mm(c.source, c.target), self.vmax)
            self.error_colors(ps.get_surface_mesh("target"), np.zeros(c.target.shape[0]), self.vmax)
        colors = np.tile(MARKER_COLOR, (c.handles.size, 1))
        colors[self.marker] = SELECTED_COLOR
        P = self.positions()
        for name in self.draggable():
            if not ps.has_point_cloud(f"{name} markers"):
                continue
            pc = ps.get_point_cloud(f"{name} markers")
            pc.update_point_positions(P + self.shifts[name])
            pc.add_color_quantity("selected", colors, enabled=True)
        for label in self.selected:
            if not ps.has_surface_mesh(label):
                continue
            m = ps.get_surface_mesh(label)
            if label in self.failed:
                m.remove_all_quantities()
                m.set_color(FAILED_COLOR)
            elif label in self.results:
                m.update_vertex_positions(self.results[label] + self.shifts[label])
                self.error_colors(m, self.colour_values(self.results[label]), self.vmax)
            else:  # still fitting: the source shape, grey
                m.remove_all_quantities()
                m.set_color(TRUTH_COLOR)

    # ------------------------------------------------------------------ mouse and keys
    def marker_screen(self) -> dict:
        """Copy name -> ``(k, 2)`` window pixels of its markers, for every draggable copy."""
        P = self.positions()
        names = self.draggable()
        xy = self.world_to_screen(np.concatenate([P + self.shifts[n] for n in names]))
        return {n: xy[i * len(P):(i + 1) * len(P)] for i, n in enumerate(names)}

    def marker_world(self, name: str, m: int) -> np.ndarray:
        """Marker ``m`` as drawn on copy ``name``: its label + offset, shifted into the copy's place, ``(3,)``."""
        return self.positions()[m] + self.shifts[name]

    def drag_value(self, m: int) -> np.ndarray:
        """What a drag of marker ``m`` changes: its offset (cm), copied at the press."""
        return self.offsets[m].copy()

    def drag_set(self, m: int, start, delta) -> None:
        """A drag moved marker ``m`` by ``delta`` (cm) since the press: its offset becomes ``start + delta``."""
        new = start + delta
        if not np.array_equal(new, self.offsets[m]):
            self.set_offset(m, new)

    def handle_keys(self) -> None:
        """Arrow keys nudge the selected marker in the screen plane (left/right, up/down), page up/down towards or
        away from the camera; :data:`KEY_STEP_MM` per press, four times that with shift. Not while a widget
        has the keyboard."""
        import polyscope as ps
        import polyscope.imgui as psim

        io = psim.GetIO()
        if io.WantCaptureKeyboard or self._drag is not None:
            return
        cam = ps.get_view_camera_parameters()
        right, up = np.asarray(cam.get_right_dir(), float), np.asarray(cam.get_up_dir(), float)
        look = np.asarray(cam.get_look_dir(), float)
        step = KEY_STEP_MM * (4.0 if io.KeyShift else 1.0)
        delta = np.zeros(3)
        for key, v in ((psim.ImGuiKey_LeftArrow, -right), (psim.ImGuiKey_RightArrow, right),
                       (psim.ImGuiKey_UpArrow, up), (psim.ImGuiKey_DownArrow, -up),
                       (psim.ImGuiKey_PageUp, -look), (psim.ImGuiKey_PageDown, look)):
            if psim.IsKeyPressed(key):
                delta += v * step
        if delta.any():
            self.nudge(self.marker, delta)

    def _capture_rest_faces(self) -> None:
        if not self.offsets.any():
            for n in self.copies():
                if n in ("source", "target") or (n in self.results and n not in self.pending()):
                    self._near.setdefault(n, self.face(n).copy())

    def near_marker_mm(self) -> dict:
        """Copy name -> largest displacement (mm) of the drawn face, against the face it showed with every
        offset at zero, over the rest-shape vertices within :data:`NEAR_CM` of the selected marker's vertex.
        Copies without such a face yet (still fitting) are left out."""
        c = self.case
        self._capture_rest_faces()
        v = int(c.handles[self.marker])
        ids = np.flatnonzero(np.linalg.norm(c.source - c.source[v], axis=1) <= NEAR_CM * CM_TO_MM / c.unit_mm)
        return {n: float(np.linalg.norm(self.face(n)[ids] - self._near[n][ids], axis=1).max() * c.unit_mm)
                for n in self.copies() if n in self._near}

    def at_marker_mm(self) -> dict:
        """Copy name -> distance (mm) from its face's vertex under the selected marker to where that marker is
        driven (label + offset): ~0 for a method that interpolates its markers, the offset for the target."""
        v, P = int(self.case.handles[self.marker]), self.positions()[self.marker]
        return {n: float(np.linalg.norm(self.face(n)[v] - P) * self.case.unit_mm) for n in self.copies()
                if n in ("source", "target") or n in self.results}

    def state(self) -> dict:
        """:meth:`BaseView.state` plus the drive view's: ``copies_order``, ``selected``, ``marker``, ``hover``,
        ``dragging``, ``drags``, ``offsets_mm`` (k, 3), ``status`` / ``fit_s`` / ``deform_ms`` per method,
        ``fit_log``, ``pending``, ``near_marker_mm`` and ``at_marker_mm`` (see those methods)."""
        out = super().state()
        out.update(copies_order=self.copies(), selected=list(self.selected), marker=int(self.marker),
                   hover=self.hover, dragging=self._drag is not None, drags=self.drags,
                   offsets_mm=(self.offsets * self.case.unit_mm).tolist(), status=dict(self.status),
                   fit_s=dict(self.fit_s), deform_ms=dict(self.deform_ms), fit_log=list(self.fit_log),
                   pending=self.pending(), near_marker_mm=self.near_marker_mm(), failed=dict(self.failed),
                   at_marker_mm=self.at_marker_mm())
        return out

    def rebuild(self) -> None:
        """:meth:`BaseView.rebuild`, forgetting the faces :meth:`near_marker_mm` compares with."""
        self._near = {}
        super().rebuild()

    # ------------------------------------------------------------------ panel
    def callback(self) -> None:
        """Background results, :meth:`BaseView.callback`, then the mouse, the keys and the marker rings (input
        only when no screenshot is being taken)."""
        if self.background:
            self.poll()
        super().callback()
        if not self.frozen:
            self.handle_mouse()
            self.handle_keys()
        self.draw_marker_rings()

    def panel(self) -> None:
        """Per-method timings and errors (mm), then the Case, Methods and Marker sections.

        Every change goes through the matching method (:meth:`load_case`,
        :meth:`set_methods`, :meth:`set_params`, :meth:`set_offset`).
        """
        import polyscope.imgui as psim

        ui, c = self.ui, self.case
        own = c.target is None  # the user's files: no truth to measure against
        psim.TextWrapped(c.description)
        psim.TextWrapped("left to right: " + " | ".join(self.copies()))
        psim.TextUnformatted("colour: displacement from the mesh (mm)" if own
                             else "colour: distance to the true target (mm)")
        if self.color_max_slider():
            self._auto_vmax = False
            self.refresh()
        psim.TextUnformatted("per method: last deform (ms), fit (s); how far the mesh moved, how far a marker "
                             "vertex is from its marker (mm)" if own
                             else "per method: last deform (ms), fit (s); error over the face area (mm)")
        now = time.monotonic() - self.clock0
        for label in self.selected:
            if label in self.failed:
                psim.TextColored((1.0, 0.3, 0.3, 1.0), f"{label}: failed: {self.failed[label]}")
                continue
            if self.status.get(label) == "fitting":
                what = "refitting" if label in self.results else "fitting"
                psim.TextColored((0.95, 0.6, 0.1, 1.0),
                                 f"{label}: {what}... {now - self.fit_started.get(label, now):.1f} s")
            if label not in self.results:
                continue
            e = self.errors(label)
            psim.TextUnformatted(f"{label}: deform {self.deform_ms.get(label, float('nan')):.2f} ms, "
                                 f"fit {self.fit_s.get(label, float('nan')):.2f} s")
            if own:
                psim.TextUnformatted(f"    moved mean {e['moved_mean_mm']:.2f} mm, max {e['moved_max_mm']:.1f} mm; "
                                     f"at the markers max {e['at_markers_max_mm']:.3f} mm")
            else:
                psim.TextUnformatted(f"    mean {e['mean_mm']:.2f} mm, RMS {e['rms_mm']:.2f} mm, "
                                     f"max {e['max_mm']:.1f} mm")
        psim.Separator()

        if own:
            psim.TextWrapped(f"your files: {c.files[0]} driven by {c.files[1]}, each method built as `facegeom "
                             f"drive` builds it (--proxy {self.proxy}), from its own defaults until changed below")
        elif psim.CollapsingHeader("Case", psim.ImGuiTreeNodeFlags_DefaultOpen):
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
            auto = isinstance(self.tangent_beta, str)  # "auto": chosen from the markers, `facegeom drive`'s default
            ch, on = ui.checkbox("tangent: beta auto (facegeom drive's default)", auto)
            if ch:
                self.set_params(tangent_beta="auto" if on else None)
            if not auto:
                ch, hard = ui.checkbox("tangent: hard constraints (beta = None)", self.tangent_beta is None)
                if ch:
                    self.set_params(tangent_beta=None if hard else 100.0)
            if not auto and self.tangent_beta is not None:
                ch, v = ui.slider_float("tangent log10 beta", math.log10(self.tangent_beta), -2.0, 4.0, "%.2f")
                if ch:
                    self.set_params(tangent_beta=float(10.0 ** v))
            ch, v = ui.combo("rbf kernel", self.rbf_kernel, self.kernels)
            if ch:
                self.set_params(rbf_kernel=v)

        if psim.CollapsingHeader("Marker", psim.ImGuiTreeNodeFlags_DefaultOpen):
            where = "any method's face" if own else "any method's face or on the target"
            psim.TextWrapped(f"Drag a marker on {where} with the left mouse button "
                             "(a ring shows what a press grabs), nudge the selected one with the arrow keys "
                             "(page up/down: depth; shift: x4) or with the sliders:")
            k = c.handles.size
            ch, v = ui.slider_int("marker", self.marker, 0, k - 1)
            if ch:
                self.marker = int(v)
                self.refresh()
            off = self.offsets[self.marker] * c.unit_mm
            new = off.copy()
            for i, axis in enumerate("xyz"):
                ch, v = ui.slider_float(f"d{axis} (mm)", off[i], -NUDGE_RANGE_MM, NUDGE_RANGE_MM, "%.2f")
                if ch:
                    new[i] = v
            if not np.array_equal(new, off):
                self.set_offset(self.marker, new / c.unit_mm)
            if ui.button("reset marker"):
                self.set_offset(self.marker, np.zeros(3))
            psim.SameLine()
            if ui.button("reset all"):
                self.offsets[:] = 0.0
                self.update_deform()
            psim.TextUnformatted(f"vertex {int(c.handles[self.marker])}, offset "
                                 f"{np.linalg.norm(self.offsets[self.marker]) * c.unit_mm:.2f} mm")

