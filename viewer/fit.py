"""``facegeom view fit``: a target beside every fitter's fitted face, with each method's coefficients.

The target is one of ``facegeom bench fit``'s random expressions
(:func:`facegeom.model.scenarios.fitting_cases`: a random identity, 2-6 active shapes)
given to the fitters as 23 noisy 2-D landmarks seen by an unposed camera (the
``landmarks`` experiment) or as the whole mesh in correspondence (``mesh``), or
a mesh file in correspondence with the generic ICT rig. Row: the true face (with
the landmark vertices) | one fitted face per method, coloured by the distance to
the true face (mm). The panel shows every method's coefficients as a histogram
over the blendshapes and its largest coefficients by name, against the truth.

A mesh file (``target=``, ``facegeom view fit --target FILE``) is read and fitted
exactly as ``facegeom fit FILE`` reads and fits it
(:func:`facegeom.model.read_fit_target` with ``scale="auto"``, then
:func:`facegeom.methods.fitting.fit_aligned`, which also brings a mesh that is off
the rig's frame back into it), so a fitter's weights are the ones that command
writes with ``-m`` that fitter. Weights outside ``[0, 1]`` (fitters without that
box, e.g. ``sem`` without ``clamp``, the PCA baselines) are flagged in the panel.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from facegeom import registry
from facegeom.constants import FACE_AREA
from facegeom.errors import FacegeomError, InputError
from facegeom.model import FIT_LANDMARKS_23, BlendshapeRig, LandmarkTarget, MeshTarget, PinholeCamera, look_at_camera
from facegeom.model.scenarios import fitting_cases
from facegeom.registry import LINEUPS, MethodSpec, parse_methods
from facegeom.viewer.app import MARKER_COLOR, BaseView, error_mm, nice_ceiling, row_offsets

__all__ = ["FitCase", "make_fit_case", "FitView", "AlignedSpec", "AlignedFitter", "DEFAULT_METHODS", "KINDS",
           "out_of_box"]

DEFAULT_METHODS = "sem;l1reg;pcadel"
KINDS = ["landmarks", "mesh"]
TOP = 5  # largest coefficients listed by name per method


@dataclass
class FitCase:
    """One case of ``facegeom view fit``: the rig, the true face and the target the fitters get.

    Attributes
    ----------
    description : str
        One line for the panel.
    rig : BlendshapeRig
        The rig fitted: the case's identity, or the generic ICT face for a mesh file.
    truth : (n, 3) float64
        The true face (cm).
    weights : (B,) float64 or None
        The true coefficients; ``None`` for a mesh given by the user.
    target : LandmarkTarget or MeshTarget
        What the fitters are given.
    landmark_ids : (L,) int64 or None
        Vertex ids of a landmark target (drawn on every face); ``None`` for a mesh target.
    aligned : bool
        Fit as ``facegeom fit`` fits a mesh: through :func:`~facegeom.methods.fitting.fit_aligned`
        (:class:`AlignedSpec`); the fitted faces are shown in the target's frame.
    notes : list of str
        What reading the target did (a unit factor), as ``facegeom fit`` prints it.
    """

    description: str
    rig: BlendshapeRig
    truth: np.ndarray  # (n, 3) the true face
    weights: np.ndarray | None  # (B,) the true coefficients, if known
    target: object  # LandmarkTarget | MeshTarget
    landmark_ids: np.ndarray | None
    aligned: bool = False
    notes: list = field(default_factory=list)


class AlignedFitter:
    """A fitter run as ``facegeom fit`` runs it on a mesh or a point cloud: :func:`fit_aligned` (the fit itself
    when the target is in the rig's frame, else pose and expression alternately).

    :meth:`fit` returns the inner fitter's :class:`~facegeom.interfaces.FitResult` with ``info["alignment"]``:
    the rigid alignment (rig -> target) or ``None``.
    """

    def __init__(self, inner):
        self.inner = inner

    def fit(self, rig, target):
        """The inner fitter's result on ``target`` after ``facegeom fit``'s alignment (the pose in ``info``)."""
        from facegeom.methods.fitting import fit_aligned

        r, pose = fit_aligned(rig, target, self.inner)
        r.info = {**(r.info if isinstance(r.info, dict) else {}), "alignment": pose}
        return r


@dataclass(frozen=True)
class AlignedSpec(MethodSpec):
    """A fitter spec that builds an :class:`AlignedFitter` (picklable: the window's workers build it)."""

    def build(self, kind: str):
        """The spec's fitter wrapped in an :class:`AlignedFitter`."""
        return AlignedFitter(super().build(kind))


def out_of_box(weights, tol: float = 1e-9) -> bool:
    """Whether any weight lies outside ``[0, 1]`` (beyond ``tol``): a fitter without that box."""
    w = np.asarray(weights, dtype=np.float64)
    return bool(w.size and (w.min() < -tol or w.max() > 1.0 + tol))


def make_fit_case(model, case: int = 0, seed: int = 0, kind: str = "landmarks", noise_px: float = 1.0,
                  mesh=None, target=None) -> FitCase:
    """Case ``case`` of ``facegeom bench fit --seed seed`` as a landmark or mesh target; or ``mesh`` (n, 3), in
    the rig's units; or ``target``, a mesh file read as ``facegeom fit TARGET`` reads it (on the generic ICT
    rig, ``scale="auto"``). Meshes are fitted as ``facegeom fit`` fits them (``aligned``).

    Raises
    ------
    InputError
        A file that cannot be read, or one ``facegeom fit`` would not fit as a mesh in correspondence (another
        vertex count, no triangles): one line naming it.
    """
    if target is not None:
        from facegeom.io import MESH_FORMATS
        from facegeom.model import read_fit_target

        rig = BlendshapeRig.from_face_model(model)  # `facegeom fit`'s rig without --rig
        if Path(target).suffix.lower() not in MESH_FORMATS:
            raise InputError(f"not a mesh file ({', '.join(MESH_FORMATS)}): this view fits meshes in vertex "
                             f"correspondence with the ICT face; `facegeom fit` takes landmarks and photos", target)
        notes: list[str] = []
        got, tgt = read_fit_target(target, rig, "auto", scale="auto", notes=notes)  # as `facegeom fit TARGET`
        if got != "mesh":  # a point cloud to `facegeom fit`: another vertex count, or no triangles
            n = tgt.points.shape[0]
            why = (f"{n} vertices, not the ICT face's {rig.n_vertices}" if n != rig.n_vertices
                   else "no triangles")
            raise InputError(f"{why}: `facegeom fit` fits it as a point cloud, which this view does not show; give "
                             f"a mesh in vertex correspondence with the ICT face", target)
        return FitCase(f"{Path(target).name} on the generic ICT rig, fitted as `facegeom fit {Path(target).name}` "
                       f"fits it", rig, tgt.vertices, None, tgt, None, aligned=True, notes=notes)
    if mesh is not None:
        rig = BlendshapeRig.from_face_model(model)
        V = np.asarray(mesh, dtype=np.float64)
        if V.shape != (rig.n_vertices, 3):
            raise InputError(f"the target mesh has {V.shape[0]} vertices but the rig {rig.n_vertices}: it must be "
                             f"in correspondence with the ICT face")
        return FitCase("a mesh target on the generic ICT rig", rig, V, None, MeshTarget(V), None, aligned=True)
    if kind not in KINDS:
        raise InputError(f"unknown target kind {kind!r}; choose one of {', '.join(KINDS)}")
    if case < 0:
        raise InputError(f"--case must be >= 0, got {case}")
    if not np.isfinite(noise_px) or noise_px < 0:
        raise InputError(f"--noise-px must be a non-negative number, got {noise_px}")
    c = fitting_cases(model, case + 1, seed)[case]
    rig = BlendshapeRig.from_face_model(model, c.identity)
    V = rig.evaluate(c.weights)
    active = ", ".join(f"{rig.names[i]} {c.weights[i]:.2f}" for i in np.flatnonzero(c.weights))
    desc = f"bench fit case {case} (seed {seed}): {active}"
    if kind == "mesh":
        return FitCase(desc + "; the mesh in correspondence", rig, V, c.weights, MeshTarget(V), None)
    ids = model.landmarks[list(FIT_LANDMARKS_23)]
    cam = look_at_camera(V, yaw=c.yaw, pitch=c.pitch)
    rng = np.random.default_rng([int(seed), 99, int(case)])
    uv = cam.project(V[ids]) + rng.normal(size=(ids.size, 2)) * noise_px
    target = LandmarkTarget(uv, ids, PinholeCamera(cam.focal, cam.cx, cam.cy))
    desc += f"; {ids.size} landmarks, yaw {c.yaw:.0f} pitch {c.pitch:.0f} deg, noise {noise_px:g} px, pose unknown"
    return FitCase(desc, rig, V, c.weights, target, ids)


class FitView(BaseView):
    """True face | one fitted face per fitter, with coefficient charts.

    Parameters
    ----------
    model : FaceModel
    methods : str or list of MethodSpec
        Fitter specs (``;``-separated, as for ``facegeom bench fit``).
    case, seed, kind, noise_px, mesh, target
        The target (see :func:`make_fit_case`); ``target``: a mesh file, fitted as ``facegeom fit TARGET`` fits
        it (the weights shown are the ones it writes with ``-m`` the same fitter).
    background : bool
        Fit in worker processes (:mod:`facegeom.viewer.workers`): the window opens at
        once and never freezes; a fitter still running shows "fitting..." and its face
        appears when it is done. ``False`` fits in this process, in order.
    """

    title = "facegeom view fit"
    panel_width = 460
    colorbar_title = "distance to the true face (mm)"

    def __init__(self, model, methods=DEFAULT_METHODS, case: int = 0, seed: int = 0, kind: str = "landmarks",
                 noise_px: float = 1.0, mesh=None, background: bool = False, target=None):
        super().__init__()
        self.background = bool(background)
        self.workers: dict = {}
        self._jobs: dict[str, int] = {}  # label -> the newest fit job
        self.fit_started: dict[str, float] = {}
        self.model = model
        specs = (parse_methods(methods, "fitters", LINEUPS["fit"]) if isinstance(methods, str)
                 else list(methods))
        if not specs:
            raise InputError("no fitter given, e.g. --methods sem")
        self.specs: dict[str, MethodSpec] = {s.label: s for s in specs}
        for name in registry.available("fitters"):
            self.specs.setdefault(name, MethodSpec(name, name, {}))
        self.selected = [s.label for s in specs]
        self.case_args = dict(case=int(case), seed=int(seed), kind=kind, noise_px=float(noise_px), mesh=mesh,
                              target=target)
        if mesh is not None or target is not None:  # the user's mesh: no truth behind it, only the target
            self.colorbar_title = "distance to the target (mm)"
        self.results: dict[str, object] = {}
        self.time_ms: dict[str, float] = {}
        self.failed: dict[str, str] = {}
        self._built = False
        self.load_case()

    # ------------------------------------------------------------------ model side
    def load_case(self, **changes) -> None:
        """(Re)build the case with ``changes`` (arguments of :func:`make_fit_case`), fit every selected
        fitter, set the colour scale from their errors and register the scene again."""
        self.case_args.update(changes)
        self.case = make_fit_case(self.model, **self.case_args)
        self.results.clear()
        self.failed.clear()
        self._jobs.clear()
        for label in self.selected:
            self.fit_method(label)
        self._auto_vmax = True
        self._set_auto_vmax()
        self.rebuild()

    def _set_auto_vmax(self) -> None:
        if not self._auto_vmax or self.pending():
            return
        errs = [np.percentile(error_mm(self.face(x), self.case.truth)[:FACE_AREA], 99) for x in self.results]
        self.vmax = nice_ceiling(float(np.median(errs)) if errs else 5.0)  # a typical method's 99th pct.
        self._auto_vmax = False

    def pending(self) -> list[str]:
        """Selected fitters still fitting in a worker (background mode)."""
        return [x for x in self.selected if x in self._jobs]

    def poll(self) -> bool:
        """Background mode: install every finished fit (never blocks); returns whether one arrived."""
        got = False
        for label, w in list(self.workers.items()):
            for job, status, payload, secs in w.poll():
                if self._jobs.get(label) != job:
                    continue  # an older fit of this label
                del self._jobs[label]
                got = True
                if status == "ok":
                    self.results[label] = payload
                    self.time_ms[label] = secs * 1e3
                else:
                    self.failed[label] = payload
        if got:
            self._set_auto_vmax()
            self.rebuild()
        return got

    def wait(self, timeout: float | None = 300.0) -> None:
        """Background mode: poll until no fitter is running."""
        t = time.monotonic()
        while self.pending() and (timeout is None or time.monotonic() - t < timeout):
            self.poll()
            time.sleep(0.01)

    def close(self) -> None:
        """Stop the worker processes."""
        for w in self.workers.values():
            w.close()
        self.workers.clear()

    def callback(self) -> None:
        """Install finished background fits, then :meth:`BaseView.callback`."""
        if self.background:
            self.poll()
        super().callback()

    def spec(self, label: str) -> MethodSpec:
        """Fitter ``label``'s spec as it is run on the case: an :class:`AlignedSpec` for a mesh fitted as
        ``facegeom fit`` fits one."""
        s = self.specs[label]
        return AlignedSpec(s.label, s.name, dict(s.params)) if self.case.aligned else s

    def face(self, label: str) -> np.ndarray:
        """Fitter ``label``'s face ``(n, 3)`` where the truth is: the fitted face, moved by the alignment
        (rig -> target) when the target was off the rig's frame."""
        r = self.results[label]
        pose = r.info.get("alignment") if isinstance(r.info, dict) else None
        return r.vertices if pose is None else r.vertices @ np.asarray(pose.R).T + np.asarray(pose.t)

    def fit_method(self, label: str) -> None:
        """Build fitter ``label`` and fit it to the case (timed, in ``time_ms``).

        A :class:`~facegeom.errors.FacegeomError` is not raised: the message goes
        to ``failed[label]`` and the fitter's last result is dropped.
        """
        self.failed.pop(label, None)
        self.fit_started[label] = time.monotonic() - self.clock0
        if self.background:
            from facegeom.viewer.workers import MethodWorker

            if label not in self.workers:
                self.workers[label] = MethodWorker()
            self.results.pop(label, None)
            self._jobs[label] = self.workers[label].submit("fit_fitter", (self.spec(label), self.case.rig,
                                                                          self.case.target))
            return
        try:
            f = self.spec(label).build("fitters")
            t = time.perf_counter()
            self.results[label] = f.fit(self.case.rig, self.case.target)
            self.time_ms[label] = (time.perf_counter() - t) * 1e3
        except FacegeomError as exc:
            self.failed[label] = str(exc)
            self.results.pop(label, None)

    def set_methods(self, labels: list[str]) -> None:
        """Select the fitters shown, fitting those without a result (new or failed).

        Raises
        ------
        InputError
            A label is not a known fitter.
        """
        unknown = [x for x in labels if x not in self.specs]
        if unknown:
            raise InputError(f"no fitter {unknown[0]!r}; available: {', '.join(self.specs)}")
        self.selected = list(labels)
        for label in labels:
            if label not in self.results and label not in self._jobs:  # new ones, and failed ones again
                self.fit_method(label)
        self.rebuild()

    def shown_faces(self) -> dict:
        """Copy name -> its face as drawn (row shift included)."""
        if not self._built:
            return {}
        return {n: (self.case.truth if n == "truth" else self.face(n)) + self.shifts[n]
                for n in self.copies() if n in self.shifts}

    def state(self) -> dict:
        """:meth:`BaseView.state` plus ``copies_order``, ``pending`` fitters, ``time_ms``, ``failed`` and
        ``out_of_box`` (the shown fitters with a weight outside ``[0, 1]``)."""
        out = super().state()
        out.update(copies_order=self.copies(), pending=self.pending(), time_ms=dict(self.time_ms),
                   failed=dict(self.failed), out_of_box=self.out_of_box())
        return out

    def out_of_box(self) -> list[str]:
        """The shown fitters with a weight outside ``[0, 1]`` (fitters without that box), flagged in the panel."""
        return [x for x in self.shown() if out_of_box(self.results[x].weights)]

    def shown(self) -> list[str]:
        """The selected fitters that have a result (failed ones left out), in selection order."""
        return [x for x in self.selected if x in self.results]

    # ------------------------------------------------------------------ scene
    def copies(self) -> list[str]:
        """Names of the faces in the row, left to right: ``truth``, then every shown fitter."""
        return ["truth", *self.shown()]

    def build(self) -> None:
        """Register the row: the true face and each fitted face coloured by its error (mm), and, for a
        landmark target, the landmark vertices on every face."""
        self._built = True
        c, F = self.case, self.model.triangles
        names = self.copies()
        self.shifts = dict(zip(names, row_offsets(c.truth, len(names))))
        r = 0.011 * float(np.ptp(c.truth[:, 0]))
        m = self.mesh("truth", c.truth, F, self.shifts["truth"])
        self.error_colors(m, np.zeros(c.truth.shape[0]), self.vmax)
        for label in self.shown():
            V = self.face(label)
            m = self.mesh(label, V, F, self.shifts[label])
            self.error_colors(m, error_mm(V, c.truth), self.vmax)
        if c.landmark_ids is not None:
            for name in names:
                V = c.truth if name == "truth" else self.face(name)
                pc = self.points(f"{name} landmarks", V[c.landmark_ids], self.shifts[name], color=MARKER_COLOR)
                pc.set_radius(r, relative=False)

    def refresh_colors(self) -> None:
        """Colour every fitted face again by its distance to the truth, on the current scale ``vmax`` (mm)."""
        import polyscope as ps

        if not ps.is_initialized() or not self._built:
            return
        for label in self.shown():
            self.error_colors(ps.get_surface_mesh(label), error_mm(self.face(label), self.case.truth), self.vmax)

    # ------------------------------------------------------------------ panel
    def histogram(self, label: str, weights: np.ndarray) -> None:
        """Every coefficient, one bar per blendshape (in rig order)."""
        import polyscope.imgui as psim

        w = np.asarray(weights, dtype=np.float64)
        lo, hi = min(0.0, float(w.min())), max(1.0, float(w.max()))
        box = f", outside [0, 1]: {w.min():.2f} to {w.max():.2f}" if out_of_box(w) else ""
        psim.PlotHistogram(f"##{label} coefficients", w.astype(np.float32),
                           overlay_text=f"{label}: {int((np.abs(w) > 1e-3).sum())} active of {w.size}{box}",
                           scale_min=lo, scale_max=hi, graph_size=(self.panel_width - 30.0, 42.0))

    def named_rows(self) -> list[int]:
        """Shapes listed by name: the true ones, then each method's largest ``TOP`` coefficients."""
        rows = [] if self.case.weights is None else [int(i) for i in np.flatnonzero(self.case.weights)]
        for label in self.shown():
            w = self.results[label].weights
            rows += [int(i) for i in np.argsort(-np.abs(w))[:TOP] if abs(w[i]) > 1e-3 and i not in rows]
        return rows

    def coefficient_table(self) -> None:
        """Named coefficients as progress bars: one row per shape, one column per method (truth first)."""
        import polyscope.imgui as psim

        names, cols = self.case.rig.names, []
        if self.case.weights is not None:
            cols.append(("truth", self.case.weights))
        cols += [(label, self.results[label].weights) for label in self.shown()]
        if not cols or not psim.BeginTable("coefficients", len(cols) + 1, psim.ImGuiTableFlags_RowBg):
            return
        psim.TableSetupColumn("shape")
        flagged = set(self.out_of_box())
        for label, _ in cols:
            psim.TableSetupColumn(label + (" *" if label in flagged else ""))
        psim.TableHeadersRow()
        for i in self.named_rows():
            psim.TableNextRow()
            psim.TableNextColumn()
            psim.TextUnformatted(names[i])
            for _, w in cols:
                psim.TableNextColumn()
                psim.ProgressBar(float(np.clip(abs(w[i]), 0.0, 1.0)), (-1.0, 0.0), f"{w[i]:+.2f}" if w[i] else "0")
        psim.EndTable()
        if flagged:
            psim.TextWrapped("* unconstrained: weights outside [0, 1] (this fitter has no such box; `facegeom "
                             "fit`'s default fitter keeps every weight in it)")

    def panel(self) -> None:
        """Timings and mean face-area errors (mm), coefficient histograms and table, then the Target and
        Methods sections (changes go through :meth:`load_case` and :meth:`set_methods`)."""
        import polyscope.imgui as psim

        ui, c = self.ui, self.case
        psim.TextWrapped(c.description)
        for line in c.notes:
            psim.TextWrapped(line)
        psim.TextWrapped("left to right: " + " | ".join(self.copies()))
        psim.TextUnformatted(f"colour: {self.colorbar_title}")
        if self.color_max_slider():
            self._auto_vmax = False
            self.refresh_colors()
        psim.Separator()
        now = time.monotonic() - self.clock0
        for label in self.selected:
            if label in self.failed:
                psim.TextColored((1.0, 0.3, 0.3, 1.0), f"{label}: failed: {self.failed[label]}")
                continue
            if label in self._jobs:
                psim.TextColored((0.95, 0.6, 0.1, 1.0),
                                 f"{label}: fitting... {now - self.fit_started.get(label, now):.1f} s")
                continue
            if label not in self.results:
                continue
            r = self.results[label]
            e = error_mm(self.face(label), c.truth)[:FACE_AREA].mean()
            psim.TextUnformatted(f"{label}: {self.time_ms[label]:.0f} ms, mean vertex error {e:.2f} mm")
            if out_of_box(r.weights):
                psim.TextColored((0.95, 0.6, 0.1, 1.0), f"    unconstrained: weights {r.weights.min():.2f} to "
                                                        f"{r.weights.max():.2f}, outside [0, 1]")
        psim.TextUnformatted("coefficients by blendshape (rig order)")
        if c.weights is not None:
            self.histogram("truth", c.weights)
        for label in self.shown():
            self.histogram(label, self.results[label].weights)
        self.coefficient_table()
        psim.Separator()
        if (self.case_args["mesh"] is None and self.case_args["target"] is None
                and psim.CollapsingHeader("Target", psim.ImGuiTreeNodeFlags_DefaultOpen)):
            a, changes = self.case_args, {}
            ch, v = ui.input_int("case", a["case"])
            if ch:
                changes["case"] = max(0, int(v))
            ch, v = ui.input_int("seed", a["seed"])
            if ch:
                changes["seed"] = int(v)
            ch, v = ui.combo("target kind", a["kind"], KINDS)
            if ch:
                changes["kind"] = v
            if a["kind"] == "landmarks":
                ch, v = ui.slider_float("noise (px)", a["noise_px"], 0.0, 5.0, "%.1f")
                if ch:
                    changes["noise_px"] = float(v)
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
