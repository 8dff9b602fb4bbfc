"""The five operations of a batch job and their per-worker shared state.

``fit``, ``drive``, ``retarget``, ``animate`` and ``clean`` (:data:`OPS`), each
an :class:`Operation`: client-side checks of the job, the output files of an
input, the state a worker builds once per job, and per item compute, write
and error metrics against ground truth.
"""
from __future__ import annotations

import hashlib
import os
import time
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.pipelines.batch.cache import load_model, stamp
from facegeom.pipelines.batch.job import Job, job_error, resolve_template

__all__ = ["Operation", "OPS"]


def _timed(fn, items):
    """Per-item compute: yield ``(item, result or exception, seconds)``."""
    for it in items:
        t0 = time.perf_counter()
        try:
            res = fn(it)
        except Exception as exc:  # noqa: BLE001 - one bad input fails its own row
            res = exc
        yield it, res, time.perf_counter() - t0


def _need_data(job: Job, what: str) -> str:
    from facegeom.model import locate_data

    try:
        return str(locate_data(job.data))
    except InputError as exc:
        raise job_error(job.source, f"{what} needs the face data: {exc}") from None


def _shared_path(job: Job, key: str, must_exist: bool = True, dir_ok: bool = False) -> str | None:
    v = job.shared.get(key)
    if v is None:
        return None
    p = Path(os.path.expanduser(v))
    p = p if p.is_absolute() else job.base / p
    if must_exist and not p.exists():
        raise job_error(job.source, f"shared.{key} {p}: file not found")
    if must_exist and p.is_dir() and not dir_ok:
        raise job_error(job.source, f"shared.{key} {p}: is a folder, not a file")
    return str(p)


def _check_method(job: Job, kind: str):
    from facegeom import registry

    try:
        return registry.create(kind, job.method, **job.params)
    except InputError as exc:
        raise job_error(job.source, f"method {job.method!r}: {exc}") from None


def _vertex_errors(A: np.ndarray, B: np.ndarray, what: str, path) -> dict:
    A, B = np.asarray(A, dtype=np.float64), np.asarray(B, dtype=np.float64)
    if A.shape != B.shape:
        raise InputError(f"{what} has shape {B.shape}, the result {A.shape}", path)
    d = np.linalg.norm(A - B, axis=-1)
    return {"err_mean": float(np.nanmean(d)), "err_max": float(np.nanmax(d))}


class Operation:
    """One batch operation; the engine calls these methods.

    Client side, once per job: :meth:`prepare`, :meth:`outputs` per input,
    :meth:`default_chunk`. Worker side: :meth:`state` once per process and job,
    then per chunk :meth:`compute` (by default :meth:`one` per item),
    :meth:`write` per result and :meth:`evaluate_many` for the items with
    ground truth. ``spec`` is the task spec, ``item`` an item of the plan
    (:mod:`facegeom.pipelines.batch.plan`).
    """

    name = ""

    def prepare(self, job: Job, spec: dict, files: list[Path]) -> None:
        """Client side: check the method and the shared inputs; resolve them into ``spec['shared']``."""

    def outputs(self, job: Job, spec: dict, src: Path, stem: Path) -> tuple[list[Path], dict]:
        """The output files of input ``src`` (``stem``: output folder / relative name without suffix)."""
        raise NotImplementedError

    def default_chunk(self, job: Job, spec: dict, items: list[dict]) -> int:
        """Items per task when the job sets none."""
        return 1

    def state(self, spec: dict):
        """The shared state of the job on a worker (built once per process, :func:`~.tasks.worker_state`)."""
        return {}

    def compute(self, state, spec: dict, items: list[dict]):
        """Yield ``(item, result or exception, seconds)`` for every item."""
        return _timed(lambda it: self.one(state, spec, it), items)

    def one(self, state, spec: dict, item: dict):
        """The result of one item (raises for a bad input)."""
        raise NotImplementedError

    def write(self, state, spec: dict, item: dict, result) -> dict:
        """Write the item's output files; returns the summary columns of the item."""
        raise NotImplementedError

    def evaluate(self, state, spec: dict, item: dict, result, truth: str) -> dict:
        """Error metrics of one result against its ground truth file ``truth``."""
        return {}

    def evaluate_many(self, state, spec: dict, pairs: list) -> list:
        """Metrics of ``[(item, result)]``: a dict or the exception, per pair (batched where it pays)."""
        out = []
        for it, res in pairs:
            try:
                out.append(self.evaluate(state, spec, it, res, it["truth"]))
            except Exception as exc:  # noqa: BLE001
                out.append(exc)
        return out


class _Fit(Operation):
    name = "fit"

    def prepare(self, job, spec, files):
        from facegeom.io import TARGET_KINDS
        from facegeom.model import load_rig

        kind = job.shared.get("kind", "auto")
        if kind not in TARGET_KINDS:
            raise job_error(job.source, f"shared.kind {kind!r}: choose one of {', '.join(TARGET_KINDS)}")
        rig = job.shared.get("rig")
        if rig in (None, "ict"):
            spec["data"] = _need_data(job, "the default rig (the ICT face)")
            rig = None
        else:
            rig = _shared_path(job, "rig", dir_ok=True)
            try:
                load_rig(rig)  # a broken rig is the job's error, found before any task runs
            except InputError as exc:
                raise job_error(job.source, f"shared.rig: {exc}") from None
        cam = [job.shared.get(k) for k in ("focal", "cx", "cy")]
        landmarks = kind == "landmarks" or (kind == "auto" and any(f.suffix.lower() == ".csv" for f in files))
        if landmarks and any(c is None for c in cam):
            raise job_error(job.source, "landmark targets need the camera: set shared.focal, shared.cx and shared.cy "
                                        "(pixels)")
        fitter = _check_method(job, "fitters")
        spec["shared"] = {"rig": rig, "kind": kind, "camera": cam,
                          "vectorised": hasattr(fitter, "fit_landmarks")}
        spec["stamp"] = stamp([rig] if rig else [spec.get("data")])

    def outputs(self, job, spec, src, stem):
        return [stem.with_name(stem.name + "." + spec["format"])], {}

    def _is_landmarks(self, spec, path: str) -> bool:
        kind = spec["shared"]["kind"]
        return kind == "landmarks" or (kind == "auto" and path.lower().endswith(".csv"))

    def default_chunk(self, job, spec, items):
        lm = spec["shared"]["vectorised"] and all(self._is_landmarks(spec, it["input"]) for it in items)
        return 64 if lm else 1

    def state(self, spec):
        from facegeom import registry
        from facegeom.model import load_rig

        rig = load_rig(spec["shared"]["rig"], lambda: load_model(spec))
        rig.gram()  # the Gram matrix, once per worker
        rig.delta_matrix()
        return {"rig": rig, "fitter": registry.create("fitters", spec["method"], **spec["params"])}

    def compute(self, state, spec, items):
        from facegeom.model import read_fit_target
        from facegeom.pipelines.single import FitOutcome, fit_file

        rig, fitter = state["rig"], state["fitter"]
        cam = spec["shared"]["camera"]
        batch = [it for it in items if spec["shared"]["vectorised"] and self._is_landmarks(spec, it["input"])]
        in_batch = {it["index"] for it in batch}
        single = [it for it in items if it["index"] not in in_batch]
        if batch:
            good, targets = [], []
            for it, res, dt in _timed(lambda it: read_fit_target(it["input"], rig, "landmarks", *cam), batch):
                if isinstance(res, BaseException):
                    yield it, res, dt
                else:
                    good.append((it, dt))
                    targets.append(res[1])
            if targets:
                t0 = time.perf_counter()
                try:
                    E, cams = fitter.fit_landmarks(rig, targets)
                except Exception:  # noqa: BLE001 - one target broke the batch: fit them one by one to find it
                    single = [it for it, _ in good] + single
                else:
                    share = (time.perf_counter() - t0) / len(targets)
                    for k, (it, dt) in enumerate(good):
                        yield it, FitOutcome("landmarks", E[k], cams[k]), dt + share

        yield from _timed(lambda it: fit_file(rig, it["input"], lambda: fitter, spec["shared"]["kind"], *cam), single)

    def write(self, state, spec, item, result):
        from facegeom.pipelines.single import write_fit

        write_fit(item["outputs"][0], state["rig"].names, result, spec["method"], item["input"])
        return {"active": int(result.active.size)}

    def evaluate(self, state, spec, item, result, truth):
        return self.evaluate_many(state, spec, [(item, result)])[0]

    def evaluate_many(self, state, spec, pairs):
        """Coefficient and vertex errors; the faces of all pairs from one product ``D (W - W_true)``."""
        from facegeom.io import read_weights

        rig = state["rig"]
        out, dW, slots = [], [], []
        for it, res in pairs:
            try:
                wt = read_weights(it["truth"], rig.names)
            except Exception as exc:  # noqa: BLE001
                out.append(exc)
                continue
            dW.append(np.asarray(res.weights, dtype=np.float64) - wt)
            slots.append(len(out))
            out.append(None)
        if dW:
            dW = np.stack(dW)  # (K, B)
            E = rig.delta_matrix() @ dW.T  # (3n, K): the face difference of each pair, one GEMM
            d = np.sqrt((E.reshape(rig.n_vertices, 3, -1) ** 2).sum(axis=1))  # (n, K) per-vertex distances
            for j, slot in enumerate(slots):
                out[slot] = {"coef_mae": float(np.abs(dW[j]).mean()), "coef_max": float(np.abs(dW[j]).max()),
                             "err_mean": float(d[:, j].mean()), "err_max": float(d[:, j].max())}
        return out


def _peek_header(path: Path) -> str:
    try:
        with open(path, encoding="utf-8-sig", errors="replace") as fh:
            return fh.readline().strip().lower()
    except OSError:
        return ""


def _as_int_names(names) -> np.ndarray | None:
    try:
        return np.array([int(n) for n in names], dtype=np.int64)
    except (TypeError, ValueError):
        return None


class _Drive(Operation):
    name = "drive"

    def _type(self, job, src: Path) -> str:
        forced = job.shared.get("input", "auto")
        if forced in ("frames", "sequences"):
            return forced[:-1]
        if src.suffix.lower() == ".npz":
            return "sequence"
        return "sequence" if _peek_header(src).startswith("frame") else "frame"

    def prepare(self, job, spec, files):
        from facegeom.io import read_mesh

        if job.shared.get("input", "auto") not in ("auto", "frames", "sequences"):
            raise job_error(job.source, f"shared.input {job.shared['input']!r}: choose auto, frames or sequences")
        mesh = _shared_path(job, "mesh")
        model = None
        if mesh is None:
            spec["data"] = _need_data(job, "the default rest mesh (the ICT neutral)")
            model = load_model(spec)
            n = model.n_vertices
        else:
            try:
                n = read_mesh(mesh)[0].shape[0]
            except InputError as exc:
                raise job_error(job.source, f"shared.mesh: {exc}") from None
        ids = self._layout(job, model, n, files)
        _check_method(job, "deformers")
        spec["shared"] = {"mesh": mesh, "ids": ids.tolist(), "fill_gaps": bool(job.shared.get("fill_gaps", False))}
        spec["stamp"] = stamp([mesh or spec.get("data")])

    def _layout(self, job, model, n, files) -> np.ndarray:
        from facegeom.io import read_marker_sequence, read_markers, read_vertex_csv
        from facegeom.model import layout

        name = job.shared.get("markers")
        if name is not None:
            p = Path(os.path.expanduser(name))
            p = p if p.is_absolute() else job.base / p
            if not p.exists() and (name in ("ict80", "landmarks68") or name.startswith("random")):
                if model is None:
                    raise job_error(job.source, f"shared.markers {name!r} is a layout of the ICT face; with "
                                                f"shared.mesh give a marker file (a CSV with a vertex_id column)")
                try:
                    return layout(model, name)
                except InputError as exc:
                    raise job_error(job.source, f"shared.markers: {exc}") from None
            if not p.exists():
                raise job_error(job.source, f"shared.markers {p}: file not found (a CSV with a vertex_id column, "
                                            f"or a layout name: ict80, landmarks68, random<k>)")
            try:
                return read_vertex_csv(p, n).ids.astype(np.int64)
            except InputError as exc:
                raise job_error(job.source, f"shared.markers: {exc}") from None
        # no layout given: the markers of the first input that can be read
        for f in files:
            try:
                if self._type(job, f) == "frame":
                    return read_markers(f, n_vertices=n)[0]
                ids = _as_int_names(read_marker_sequence(f).names)
                if ids is not None and ids.min() >= 0 and ids.max() < n and np.unique(ids).size == ids.size:
                    return ids
            except InputError:
                continue
            break
        raise job_error(job.source, "shared.markers is needed: a marker file (CSV with a vertex_id column) or a layout "
                                    "name (ict80, landmarks68, random<k>) giving the marker vertices")

    def outputs(self, job, spec, src, stem):
        t = self._type(job, src)
        suffix = "npz" if t == "sequence" else spec["format"]
        return [stem.with_name(stem.name + "." + suffix)], {"type": t}

    def default_chunk(self, job, spec, items):
        return 16 if all(it["extra"]["type"] == "frame" for it in items) else 1

    def state(self, spec):
        from facegeom import registry
        from facegeom.io import read_mesh

        if spec["shared"]["mesh"] is None:
            model = load_model(spec)
            V, F = model.neutral.copy(), model.triangles.copy()
        else:
            V, F = read_mesh(spec["shared"]["mesh"])
        ids = np.asarray(spec["shared"]["ids"], dtype=np.int64)
        d = registry.create("deformers", spec["method"], **spec["params"])
        d.fit(V, F, ids)  # the factorization, once per worker
        return {"V": V, "F": F, "ids": ids, "deformer": d}

    def one(self, state, spec, item):
        from facegeom.io import fill_gaps, read_marker_sequence, read_markers
        from facegeom.pipelines.animate import drive_frames

        ids, path = state["ids"], item["input"]
        if item["extra"]["type"] == "frame":
            got, pos = read_markers(path, n_vertices=state["V"].shape[0])
            where = {int(v): k for k, v in enumerate(got.tolist())}
            missing = [int(v) for v in ids.tolist() if v not in where]
            if missing or got.size != ids.size:
                extra = sorted(set(where) - set(ids.tolist()))
                what = f"vertex_id {missing[0]} of the layout is missing" if missing else \
                    f"vertex_id {extra[0]} is not in the layout"
                raise InputError(f"the markers differ from the layout of {ids.size} markers: {what}", path)
            return "frame", state["deformer"].deform(pos[[where[v] for v in ids.tolist()]])
        seq = read_marker_sequence(path)
        P = seq.positions
        miss = seq.missing()
        if miss.any():
            f, j = (int(x) for x in np.argwhere(miss)[0])
            if not spec["shared"]["fill_gaps"]:
                raise InputError(f"frame {int(seq.frames[f])}: marker {seq.names[j]!r} is lost (empty or NaN); set "
                                 f"shared.fill_gaps = true to interpolate lost markers over time", path)
            try:
                P, _ = fill_gaps(P)
            except InputError as exc:
                raise InputError(exc.reason, path) from None
        named = _as_int_names(seq.names)
        if named is not None and set(named.tolist()) == set(ids.tolist()) and named.size == ids.size:
            where = {int(v): k for k, v in enumerate(named.tolist())}
            P = P[:, [where[v] for v in ids.tolist()]]
        elif seq.n_markers != ids.size:
            raise InputError(f"{seq.n_markers} markers per frame, but the layout has {ids.size}", path)
        Y, _ = drive_frames(state["deformer"], P, dtype=np.float32)  # written as float32, like animate
        return "sequence", Y, seq.frames

    def write(self, state, spec, item, result):
        from facegeom.io import atomic_path, write_mesh

        out = item["outputs"][0]
        if result[0] == "frame":
            write_mesh(out, result[1], state["F"])
            return {}
        _, Y, frames = result
        with atomic_path(out) as tmp:
            with open(tmp, "wb") as fh:
                # float32 like `facegeom animate` (and mesh caches): ~1e-6 cm on a face, half the bytes to write
                np.savez(fh, vertices=Y, faces=state["F"], frames=frames, marker_ids=state["ids"])
        return {"frames": int(Y.shape[0])}

    def evaluate(self, state, spec, item, result, truth):
        from facegeom.io import read_mesh

        if result[0] == "frame":
            return _vertex_errors(result[1], read_mesh(truth)[0], "the truth mesh", truth)
        try:
            with np.load(truth, allow_pickle=False) as z:
                Vt = z["vertices"]
        except Exception as exc:  # noqa: BLE001
            raise InputError(f"cannot read 'vertices' from the truth npz ({exc.__class__.__name__})", truth) from None
        return _vertex_errors(result[1], Vt, "'vertices'", truth)


class _Retarget(Operation):
    name = "retarget"

    def prepare(self, job, spec, files):
        if "labels" not in job.shared:
            raise job_error(job.source, "retarget needs shared.labels, the labelled character frames of each source "
                                        "as a path template, e.g. \"labels/{stem}.csv\"")
        _check_method(job, "retargeters")
        spec["shared"] = {"fill_gaps": bool(job.shared.get("fill_gaps", False))}

    def outputs(self, job, spec, src, stem):
        return [stem.with_name(stem.name + "." + spec["format"])], \
            {"labels": str(resolve_template(job.base, job.shared["labels"], src))}

    def one(self, state, spec, item):
        from facegeom import registry
        from facegeom.pipelines.single import retarget_files

        return retarget_files(item["input"], item["extra"]["labels"],
                              lambda: registry.create("retargeters", spec["method"], **spec["params"]),
                              spec["shared"]["fill_gaps"])

    def write(self, state, spec, item, result):
        from facegeom.pipelines.single import write_retargeted

        write_retargeted(item["outputs"][0], result)
        return {"frames": int(result.markers.shape[0]), "filled": int(result.filled),
                "label_dev": result.label_deviation}

    def evaluate(self, state, spec, item, result, truth):
        from facegeom.io import read_marker_sequence

        Y, names = result.markers, result.source.names
        tr = read_marker_sequence(truth).reorder(names, "truth")
        if tr.n_frames != Y.shape[0] or not np.array_equal(tr.frames, np.arange(Y.shape[0])):
            raise InputError(f"the truth must hold the frames 0..{Y.shape[0] - 1} of the source", truth)
        return _vertex_errors(Y, tr.positions, "the truth", truth)


class _FitOnce:
    """A deformer whose ``fit`` is skipped when called again on the same rest mesh and markers."""

    def __init__(self, deformer):
        self.deformer = deformer
        self._key = None

    def fit(self, vertices, faces, handles):
        h = hashlib.sha1()
        for a in (vertices, faces, handles):
            a = np.ascontiguousarray(a)
            h.update(str((a.dtype, a.shape)).encode())
            h.update(a.tobytes())
        key = h.hexdigest()
        if key != self._key:
            self._key = None
            self.deformer.fit(vertices, faces, handles)
            self._key = key
        return self

    def deform(self, handle_positions):
        return self.deformer.deform(handle_positions)

    def __getattr__(self, name):  # deform_many and the rest of the deformer
        if name == "deformer":
            raise AttributeError(name)
        return getattr(self.deformer, name)


class _Animate(Operation):
    name = "animate"

    def prepare(self, job, spec, files):
        from facegeom.registry import parse_method

        s = {"start": 0, "frames": 100, "labels": 10, "seed": 0, "deformer": "tangent", **job.shared}
        if s["start"] < 0 or s["frames"] < 2 or s["labels"] < 2:
            raise job_error(job.source, "shared.start must be >= 0, shared.frames and shared.labels >= 2")
        if s["labels"] > s["frames"]:
            raise job_error(job.source, f"shared.labels {s['labels']} exceeds shared.frames {s['frames']}")
        spec["data"] = _need_data(job, "animate")
        _check_method(job, "retargeters")
        try:
            parse_method(s["deformer"]).build("deformers")
        except InputError as exc:
            raise job_error(job.source, f"shared.deformer {s['deformer']!r}: {exc}") from None
        spec["shared"] = s
        spec["stamp"] = stamp([spec["data"]])

    def outputs(self, job, spec, src, stem):
        return [stem.with_name(stem.name + ".npz")], {}

    def state(self, spec):
        from facegeom.registry import parse_method

        return {"model": load_model(spec),
                "deformer": _FitOnce(parse_method(spec["shared"]["deformer"]).build("deformers"))}

    def one(self, state, spec, item):
        from facegeom import registry
        from facegeom.pipelines.animate import animate_take

        s = spec["shared"]
        anim, _, ids = animate_take(state["model"], item["input"], s["start"], s["frames"], s["labels"], s["seed"],
                                    lambda: registry.create("retargeters", spec["method"], **spec["params"]),
                                    lambda: state["deformer"])
        return anim, ids

    def write(self, state, spec, item, result):
        from facegeom.pipelines.animate import write_animation_npz

        anim, ids = result
        write_animation_npz(item["outputs"][0], anim, ids)
        return {"face_err_mm_mean": float(anim.frame_error_mm.mean()),
                "face_err_mm_max": float(anim.frame_error_mm.max()),
                "marker_err_mm_mean": float(anim.marker_error_mm.mean())}


_CLEAN_PARAMS = {
    "clean": ("merge_tol", "largest_component", "non_manifold", "orient"),
    "decimate": ("vertices", "preserve_boundary", "preserve_topology"),
    "crop": ("from_vertices", "radius", "id_range", "geodesic"),
}


class _Clean(Operation):
    name = "clean"

    def prepare(self, job, spec, files):
        from facegeom.pipelines.cleanup import parse_tolerance

        if job.method not in _CLEAN_PARAMS:
            raise job_error(job.source, f"method {job.method!r}: clean runs one of {', '.join(_CLEAN_PARAMS)}")
        allowed = _CLEAN_PARAMS[job.method]
        bad = [k for k in job.params if k not in allowed]
        if bad:
            raise job_error(job.source, f"params.{bad[0]}: {job.method} takes {', '.join(allowed)}")
        p = job.params
        if "merge_tol" in p:
            try:
                parse_tolerance(p["merge_tol"])
            except InputError as exc:
                raise job_error(job.source, f"params.merge_tol: {exc}") from None
        if job.method == "decimate" and not (isinstance(p.get("vertices"), int) and p["vertices"] >= 4):
            raise job_error(job.source, "decimate needs params.vertices, the target vertex count (an integer >= 4)")
        if job.method == "crop":
            if ("from_vertices" in p) == ("id_range" in p):
                raise job_error(job.source, "crop needs either params.from_vertices with params.radius, or "
                                            "params.id_range (one of them)")
            if "from_vertices" in p and "radius" not in p:
                raise job_error(job.source, "params.from_vertices needs params.radius (geodesic distance)")
        m = job.shared.get("map")
        if m is not None and m not in ("csv", "npz"):
            raise job_error(job.source, f"shared.map {m!r}: an index map is csv or npz")
        spec["shared"] = {"markers": "markers" in job.shared, "drop_lost_markers":
                          bool(job.shared.get("drop_lost_markers", False)), "map": m}

    def outputs(self, job, spec, src, stem):
        fmt = spec["format"] or src.suffix.lower().lstrip(".")
        outs = [stem.with_name(stem.name + "." + fmt)]
        extra = {}
        if spec["shared"]["map"]:
            outs.append(stem.with_name(stem.name + ".map." + spec["shared"]["map"]))
        if spec["shared"]["markers"]:
            extra["markers"] = str(resolve_template(job.base, job.shared["markers"], src))
            outs.append(stem.with_name(stem.name + ".markers.csv"))
        outs.append(stem.with_name(stem.name + ".report.json"))
        return outs, extra

    def one(self, state, spec, item):
        from facegeom.io import read_vertex_csv
        from facegeom.pipelines import cleanup
        from facegeom.pipelines.meshinput import read_input_mesh

        method, p = spec["method"], dict(spec["params"])
        V, F = read_input_mesh(item["input"], polygons=method == "clean")
        sources = [read_vertex_csv(item["extra"]["markers"], V.shape[0])] if "markers" in item["extra"] \
            else []
        if method == "clean":
            V2, F2, imap, report = cleanup.clean(V, F, **p)
        elif method == "decimate":
            keep = np.concatenate([s.ids for s in sources]) if sources else None
            V2, F2, imap, report = cleanup.decimate(V, F, p.pop("vertices"), keep=keep, **p)
        else:
            src = p.pop("from_vertices", None)
            rng = p.pop("id_range", None)
            if src is not None:
                src = np.asarray(src, dtype=np.int64)
                bad = src[(src < 0) | (src >= V.shape[0])]
                if bad.size:
                    raise InputError(f"params.from_vertices: vertex {int(bad[0])} is out of range: the mesh has "
                                     f"{V.shape[0]} vertices", item["input"])
            if rng is not None:
                rng = cleanup.parse_id_range(rng, V.shape[0])
            V2, F2, imap, report = cleanup.crop(V, F, sources=src, id_range=rng, **p)
        carried = [cleanup.carry_vertex_csv(s, imap, drop_lost=spec["shared"]["drop_lost_markers"],
                                            operation=method) for s in sources]
        return V, F, V2, F2, imap, report, carried

    def write(self, state, spec, item, result):
        from facegeom.io import all_or_nothing, write_mesh
        from facegeom.pipelines.cleanup import write_vertex_csv

        V, F, V2, F2, imap, report, carried = result
        outs = item["outputs"]  # mesh, [map], [markers], report
        for c in carried:
            report.markers.append(c.summary(outs[-2]))
        with all_or_nothing(outs) as tmps:  # renamed last to first: the mesh exists only once all others do
            write_mesh(tmps[0], V2, F2)
            if spec["shared"]["map"]:
                imap.save(tmps[1])
            for c in carried:
                write_vertex_csv(tmps[-2], c)
            report.write_json(tmps[-1])
        return {"vertices_in": int(V.shape[0]), "vertices_out": int(V2.shape[0]),
                "faces_in": int(len(F)), "faces_out": int(F2.shape[0]),
                "markers_dropped": int(sum(c.dropped_rows.size for c in carried))}


OPS = {op.name: op for op in (_Fit(), _Drive(), _Retarget(), _Animate(), _Clean())}
