"""Batch processing on Dask: one operation over many scans, landmark files, frames or takes.

A *job* (a TOML file read with :func:`load_job`, or a :class:`Job` built in
Python) names an operation, its method and parameters, the inputs shared by
every item (rig, rest mesh, marker layout, camera) and the inputs to process
(folders or globs). :func:`run_job` writes one result file per input into the
output folder and a summary CSV (``batch-summary.csv``: per input its status,
error message, error metrics when ground truth is given, and time).

Operations (each reuses the single-item code of the matching command):

``fit``       blendshape coefficients of targets (landmark CSVs, meshes, point
              clouds; :func:`facegeom.model.inputs.read_fit_target`) -> ``.json``/``.csv``
              weights. Landmark files are fitted a chunk at a time through the
              fitter's batched ``fit_many`` when it solves landmarks together (SEM).
``drive``     a deformer fitted once on the rest mesh and marker layout, driven
              by marker frames (``vertex_id,x,y,z`` CSV -> one mesh) or marker
              sequences (``.npz``/long CSV -> ``.npz`` with float32 ``vertices (T, n, 3)``).
``retarget``  marker sequences with their labelled character frames (a path
              template per source) -> retargeted sequences.
``animate``   Live Link Face takes -> character animation ``.npz`` (as
              ``facegeom animate``).
``clean``     meshes through ``clean`` / ``decimate`` / ``crop`` (pymeshlab) ->
              mesh + JSON report (+ index map, carried marker files).

Engine: Dask ``distributed``. By default a :class:`distributed.LocalCluster`
sized to the machine (one process per core, one thread each, loopback only);
``scheduler=ADDRESS`` (or ``$DASK_SCHEDULER_ADDRESS``) runs the same job on an
existing cluster whose workers have facegeom installed and see the same paths.
A task carries the job spec (small) and the paths of a chunk of inputs; the
heavy shared state (rig and Gram matrix, fitted deformer, face model) is built
once per worker process and kept in a module-level cache keyed by the job's
hash (:func:`worker_state`). ``inline=True`` runs the very same chunks in this
process, one after the other (debugging, baselines, the reference in tests).

Safety: every file is written atomically (temporary file, then rename), so an
output that exists is complete. Before computing an item a task checks its
outputs: a rerun, or Dask's retry of a task whose worker died, skips what is
already written, so nothing is lost and nothing is written twice. An input
that fails (unreadable, malformed, a solver error) fails its own row, never the
job. A manifest (``batch-job.json``) records what the folder was made with; a
rerun with other settings is refused unless ``overwrite=True``.

Chunks: inputs are sorted and cut into fixed chunks of ``chunk`` items
(``[batch] chunk``, default per operation: 64 landmark files, 16 marker frames,
else 1), independent of the number of workers, so a job gives the same result
files on any cluster and inline. (The vectorised landmark fit estimates the
poses of a chunk together; its coefficients depend on the chunk's other
targets at the 1e-8 level, so a resumed chunk may differ in the last digits
from an uninterrupted run.)
"""
from __future__ import annotations

import contextlib
import csv
import glob
import hashlib
import json
import math
import os
import socket
import threading
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from facegeom.errors import FacegeomError, InputError

__all__ = ["OPERATIONS", "SUMMARY_NAME", "MANIFEST_NAME", "Job", "BatchResult", "SharedStateError", "load_job",
           "job_from_dict", "run_job", "run_chunk", "worker_state", "default_workers", "local_cluster"]

OPERATIONS = ("fit", "drive", "retarget", "animate", "clean")
SUMMARY_NAME = "batch-summary.csv"
MANIFEST_NAME = "batch-job.json"
SUMMARY_COLUMNS = ("input", "output", "status", "message", "time_s", "worker")
JOB_KEYS = ("operation", "method", "params", "inputs", "output", "shared", "truth", "batch", "data")
BATCH_KEYS = ("chunk", "retries", "format")


# --------------------------------------------------------------------------- the job


@dataclass
class Job:
    """What to run; paths are absolute (see :func:`job_from_dict` for the meaning of each field)."""

    operation: str
    inputs: list[str]
    output: Path
    method: str | None = None
    params: dict = field(default_factory=dict)
    shared: dict = field(default_factory=dict)
    truth: str | None = None
    chunk: int | None = None
    retries: int = 2
    format: str | None = None
    data: str | None = None
    source: str = "job"  # the job file (named in error messages)
    base: Path = field(default_factory=Path.cwd)  # relative paths are relative to this folder


def _fail(job_source: str, message: str) -> InputError:
    return InputError(message, job_source)


def load_job(path: str | os.PathLike, output: str | os.PathLike | None = None, data: str | None = None) -> Job:
    """Read a job file (TOML). Relative paths in it are relative to the file's folder.

    ``output`` (e.g. the CLI's ``-o``) replaces the file's ``output``; ``data``
    (the CLI's ``--data``) is the face data bundle when the file names none.
    """
    p = Path(path)
    if not p.exists():
        raise InputError("file not found", p)
    if p.is_dir():
        raise InputError("is a folder, not a job file", p)
    try:
        with open(p, "rb") as fh:
            d = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"not valid TOML: {exc}", p) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read the job file ({exc.__class__.__name__})", p) from None
    if output is not None:
        d["output"] = str(Path(output).resolve())
    if data is not None and "data" not in d:
        d["data"] = str(Path(data).resolve())
    return job_from_dict(d, base=p.resolve().parent, source=str(p))


def job_from_dict(d: dict, base: str | os.PathLike | None = None, source: str = "job") -> Job:
    """Build and check a :class:`Job` from the TOML's table.

    Keys: ``operation`` (one of :data:`OPERATIONS`); ``method`` (a registered
    fitter / deformer / retargeter, or ``clean``/``decimate``/``crop``; default
    per operation); ``params`` (the method's parameters); ``inputs`` (a folder,
    a glob or a file, or a list of them); ``output`` (the output folder);
    ``shared`` (the operation's shared inputs); ``truth`` (a path template of
    each input's ground truth, with ``{stem}``, ``{name}``, ``{parent}``);
    ``[batch]`` ``chunk``, ``retries``, ``format``; ``data`` (face data bundle).
    """
    base = Path(base).resolve() if base is not None else Path.cwd()
    if not isinstance(d, dict):
        raise _fail(source, "a job is a table of keys")
    d = {k: (os.fspath(v) if isinstance(v, os.PathLike) else v) for k, v in d.items()}
    if isinstance(d.get("inputs"), (list, tuple)):
        d["inputs"] = [os.fspath(x) if isinstance(x, os.PathLike) else x for x in d["inputs"]]
    unknown = [k for k in d if k not in JOB_KEYS]
    if unknown:
        raise _fail(source, f"unknown key {unknown[0]!r}; a job has {', '.join(JOB_KEYS)}")
    op_name = d.get("operation")
    if op_name is None:
        raise _fail(source, f"no operation; set operation = one of {', '.join(OPERATIONS)}")
    if op_name not in OPERATIONS:
        raise _fail(source, f"unknown operation {op_name!r}; choose one of {', '.join(OPERATIONS)}")
    op = _OPS[op_name]
    method = d.get("method", op.default_method)
    if not isinstance(method, str) or not method:
        raise _fail(source, f"method must be a name, got {method!r}")
    params = d.get("params", {})
    if not isinstance(params, dict):
        raise _fail(source, "params must be a table, e.g. [params] clamp = true")
    shared = d.get("shared", {})
    if not isinstance(shared, dict):
        raise _fail(source, "shared must be a table, e.g. [shared] rig = \"rig.npz\"")
    for k, v in shared.items():
        if k not in op.shared_keys:
            keys = ", ".join(op.shared_keys) or "none"
            raise _fail(source, f"unknown shared input {k!r} for {op_name}; it takes {keys}")
        kind = op.shared_keys[k]
        ok = {"str": isinstance(v, str), "path": isinstance(v, str), "template": isinstance(v, str),
              "bool": isinstance(v, bool), "int": isinstance(v, int) and not isinstance(v, bool),
              "number": isinstance(v, (int, float)) and not isinstance(v, bool)}[kind]
        if not ok:
            what = {"str": "a string", "path": "a path (string)", "template": "a path template (string)",
                    "bool": "true or false", "int": "an integer", "number": "a number"}[kind]
            raise _fail(source, f"shared.{k} must be {what}, got {v!r}")
    inputs = d.get("inputs")
    if inputs is None:
        raise _fail(source, "no inputs; set inputs = a folder, a glob or a list of them")
    if isinstance(inputs, str):
        inputs = [inputs]
    if not isinstance(inputs, list) or not inputs or not all(isinstance(x, str) and x for x in inputs):
        raise _fail(source, "inputs must be a folder, a glob, or a list of them (strings)")
    output = d.get("output")
    if not isinstance(output, str) or not output:
        raise _fail(source, "no output folder; set output = \"folder\" (or pass -o)")
    truth = d.get("truth")
    if truth is not None:
        if not op.uses_truth:
            raise _fail(source, f"{op_name} takes no ground truth (truth is for fit, drive and retarget)")
        if not isinstance(truth, str):
            raise _fail(source, "truth must be a path template such as \"truth/{stem}.json\"")
        _check_template(truth, "truth", source)
    for k, kind in op.shared_keys.items():
        if kind == "template" and k in shared:
            _check_template(shared[k], f"shared.{k}", source)
    b = d.get("batch", {})
    if not isinstance(b, dict):
        raise _fail(source, "batch must be a table: [batch] chunk = 64")
    unknown = [k for k in b if k not in BATCH_KEYS]
    if unknown:
        raise _fail(source, f"unknown key batch.{unknown[0]}; [batch] has {', '.join(BATCH_KEYS)}")
    chunk = b.get("chunk")
    if chunk is not None and (not isinstance(chunk, int) or isinstance(chunk, bool) or chunk < 1):
        raise _fail(source, f"batch.chunk must be a positive integer, got {chunk!r}")
    retries = b.get("retries", 2)
    if not isinstance(retries, int) or isinstance(retries, bool) or retries < 0:
        raise _fail(source, f"batch.retries must be a non-negative integer, got {retries!r}")
    fmt = b.get("format")
    if fmt is not None:
        fmt = str(fmt).lower().lstrip(".")
        if fmt not in op.formats:
            raise _fail(source, f"batch.format {fmt!r} is not one of {', '.join(op.formats)} for {op_name}")
    data = d.get("data")
    if data is not None and not isinstance(data, str):
        raise _fail(source, "data must be a path (string)")

    def absolute(x: str) -> str:
        return str(Path(os.path.expanduser(x)) if os.path.isabs(os.path.expanduser(x)) else base / x)

    return Job(operation=op_name, inputs=[absolute(x) for x in inputs], output=Path(absolute(output)),
               method=method, params=dict(params), shared=dict(shared), truth=truth, chunk=chunk, retries=retries,
               format=fmt, data=absolute(data) if data else None, source=source, base=base)


def _check_template(t: str, what: str, source: str) -> None:
    try:
        t.format(stem="x", name="x.y", parent="p")
    except (KeyError, IndexError, ValueError) as exc:
        raise _fail(source, f"{what} {t!r}: bad template ({exc.__class__.__name__}: {exc}); use {{stem}}, "
                            f"{{name}} or {{parent}}") from None


def _template(job_base: Path, t: str, src: Path) -> Path:
    p = Path(os.path.expanduser(t.format(stem=src.stem, name=src.name, parent=str(src.parent))))
    return p if p.is_absolute() else job_base / p


# --------------------------------------------------------------------------- per-worker state


_STATE: dict = {}
_STATE_LOCK = threading.Lock()
_BUILDS: dict = {}  # job key -> how many times this process built the state (1 unless evicted)
_KEEP = 2  # job states kept per worker process


def worker_state(spec: dict):
    """The operation's shared state for ``spec``, built once per process and cached by the job key."""
    key = spec["key"]
    with _STATE_LOCK:
        st = _STATE.get(key)
        if st is None:
            st = _OPS[spec["operation"]].state(spec)
            while len(_STATE) >= _KEEP:
                _STATE.pop(next(iter(_STATE)))
            _STATE[key] = st
            _BUILDS[key] = _BUILDS.get(key, 0) + 1
    return st


class SharedStateError(FacegeomError, RuntimeError):
    """A worker could not build the job's shared state (rig, fitted deformer, face model)."""


def _where() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def _describe(exc: BaseException) -> str:
    if isinstance(exc, FacegeomError):
        return " ".join(str(exc).split())
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _complete(item: dict) -> bool:
    return all(os.path.exists(o) for o in item["outputs"])


def _measure(op, state, spec: dict, done: list) -> None:
    """Metrics against the ground truth of the written items ``done`` (``[(item, result, metrics, seconds)]``).

    A bad truth file costs that item its metrics (a note in its row), not its result.
    """
    with_truth = [d for d in done if d[0].get("truth")]
    if not with_truth:
        return
    t0 = time.perf_counter()
    pairs = [(it, res) for it, res, _, _ in with_truth]
    try:
        found = op.evaluate_many(state, spec, pairs)
    except Exception:  # noqa: BLE001 - the batched form broke: item by item, to find the bad truth file
        found = _Op.evaluate_many(op, state, spec, pairs)
    share = (time.perf_counter() - t0) / len(with_truth)
    for (it, _, metrics, seconds), m in zip(with_truth, found):
        if isinstance(m, BaseException):
            metrics["_note"] = f"ground truth: {_describe(m)}"
        else:
            metrics.update(m)
        seconds[0] += share


def run_chunk(spec: dict, items: list[dict]) -> list[dict]:
    """Process a chunk of items (a task): skip complete ones, compute and write the others; one row each.

    Never raises for a bad item: its row says ``failed`` with the message. Raises
    :class:`SharedStateError` when the job's shared state cannot be built (Dask
    then retries the task). Error metrics against ground truth are computed
    after the chunk's outputs are written, for the whole chunk at once.
    """
    op = _OPS[spec["operation"]]
    where = _where()
    rows = {}
    todo = []
    for it in items:
        if _complete(it):
            rows[it["index"]] = _row(it, "skipped", "output already complete (an earlier attempt or run wrote it)",
                                     None, where)
        else:
            todo.append(it)
    if not todo:
        return [rows[it["index"]] for it in items]
    with _one_blas_thread():
        return _run_todo(op, spec, items, todo, rows, where)


@contextlib.contextmanager
def _one_blas_thread():
    """One BLAS thread, as in a Dask worker: the same products give the same bits inline and on any worker."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - a dependency; without it results may differ in the last bits
        yield
        return
    with threadpool_limits(limits=1, user_api="blas"):
        yield


def _run_todo(op, spec: dict, items: list[dict], todo: list[dict], rows: dict, where: str) -> list[dict]:
    try:
        state = worker_state(spec)
    except Exception as exc:  # noqa: BLE001 - the task fails: Dask retries it, then every item says why
        raise SharedStateError(f"shared state: {_describe(exc)}") from exc
    done = []
    for it, res, seconds in op.compute(state, spec, todo):
        if isinstance(res, BaseException):
            rows[it["index"]] = _row(it, "failed", _describe(res), seconds, where)
            continue
        t0 = time.perf_counter()
        try:
            metrics = op.write(state, spec, it, res) or {}
        except Exception as exc:  # noqa: BLE001
            rows[it["index"]] = _row(it, "failed", _describe(exc), seconds + time.perf_counter() - t0, where)
            continue
        done.append((it, res, metrics, [seconds + time.perf_counter() - t0]))
    _measure(op, state, spec, done)
    for it, _, metrics, seconds in done:
        note = metrics.pop("_note", "")
        rows[it["index"]] = _row(it, "ok", note, seconds[0], where, metrics)
    return [rows[it["index"]] for it in items if it["index"] in rows]


def _row(item: dict, status: str, message: str, seconds, where: str, metrics: dict | None = None) -> dict:
    r = {"index": item["index"], "status": status, "message": message,
         "time_s": None if seconds is None else float(seconds), "worker": where}
    r.update(metrics or {})
    return r


def _timed(fn, items):
    """Per-item compute: yield ``(item, result or exception, seconds)``."""
    for it in items:
        t0 = time.perf_counter()
        try:
            res = fn(it)
        except Exception as exc:  # noqa: BLE001 - one bad input fails its own row
            res = exc
        yield it, res, time.perf_counter() - t0


# --------------------------------------------------------------------------- operations


_MODELS: dict = {}  # face data path -> (files' sizes and times, FaceModel): one load per process and version
_MODELS_LOCK = threading.Lock()


def _load_model(spec: dict):
    """The face model of ``spec['data']``, loaded once per process (reloaded when its files change)."""
    from facegeom.model import load_face_model

    key = spec["data"]
    stamp = _stamp([key])
    with _MODELS_LOCK:
        hit = _MODELS.get(key)
        if hit is None or hit[0] != stamp:
            _MODELS.clear()
            _MODELS[key] = hit = (stamp, load_face_model(key))
    return hit[1]


def _need_data(job: Job, what: str) -> str:
    from facegeom.model import locate_data

    try:
        return str(locate_data(job.data))
    except InputError as exc:
        raise _fail(job.source, f"{what} needs the face data: {exc}") from None


def _shared_path(job: Job, key: str, must_exist: bool = True, dir_ok: bool = False) -> str | None:
    v = job.shared.get(key)
    if v is None:
        return None
    p = Path(os.path.expanduser(v))
    p = p if p.is_absolute() else job.base / p
    if must_exist and not p.exists():
        raise _fail(job.source, f"shared.{key} {p}: file not found")
    if must_exist and p.is_dir() and not dir_ok:
        raise _fail(job.source, f"shared.{key} {p}: is a folder, not a file")
    return str(p)


def _check_method(job: Job, kind: str):
    from facegeom import registry

    try:
        return registry.create(kind, job.method, **job.params)
    except InputError as exc:
        raise _fail(job.source, f"method {job.method!r}: {exc}") from None


def _vertex_errors(A: np.ndarray, B: np.ndarray, what: str, path) -> dict:
    A, B = np.asarray(A, dtype=np.float64), np.asarray(B, dtype=np.float64)
    if A.shape != B.shape:
        raise InputError(f"{what} has shape {B.shape}, the result {A.shape}", path)
    d = np.linalg.norm(A - B, axis=-1)
    return {"err_mean": float(np.nanmean(d)), "err_max": float(np.nanmax(d))}


class _Op:
    name = ""
    default_method = ""
    shared_keys: dict = {}
    formats: tuple = ()
    default_format = ""
    suffixes: tuple = ()
    uses_truth = False

    def prepare(self, job: Job, spec: dict, files: list[Path]) -> None:
        """Client side: check the method and the shared inputs; resolve them into ``spec['shared']``."""

    def outputs(self, job: Job, spec: dict, src: Path, stem: Path) -> tuple[list[Path], dict]:
        """The output files of input ``src`` (``stem``: output folder / relative name without suffix)."""
        raise NotImplementedError

    def default_chunk(self, job: Job, spec: dict, items: list[dict]) -> int:
        return 1

    def state(self, spec: dict):
        return {}

    def compute(self, state, spec: dict, items: list[dict]):
        return _timed(lambda it: self.one(state, spec, it), items)

    def one(self, state, spec: dict, item: dict):
        raise NotImplementedError

    def write(self, state, spec: dict, item: dict, result) -> dict:
        raise NotImplementedError

    def evaluate(self, state, spec: dict, item: dict, result, truth: str) -> dict:
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


# ----------------------------------------------------------------- fit


class _Fit(_Op):
    name = "fit"
    default_method = "sem"
    shared_keys = {"rig": "path", "kind": "str", "focal": "number", "cx": "number", "cy": "number"}
    formats = ("json", "csv")
    default_format = "json"
    suffixes = (".csv", ".obj", ".ply", ".off", ".xyz", ".npy")
    uses_truth = True

    def prepare(self, job, spec, files):
        from facegeom.io import TARGET_KINDS
        from facegeom.model import load_rig

        kind = job.shared.get("kind", "auto")
        if kind not in TARGET_KINDS:
            raise _fail(job.source, f"shared.kind {kind!r}: choose one of {', '.join(TARGET_KINDS)}")
        rig = job.shared.get("rig")
        if rig in (None, "ict"):
            spec["data"] = _need_data(job, "the default rig (the ICT face)")
            rig = None
        else:
            rig = _shared_path(job, "rig", dir_ok=True)
            try:
                load_rig(rig)  # a broken rig is the job's error, found before any task runs
            except InputError as exc:
                raise _fail(job.source, f"shared.rig: {exc}") from None
        cam = [job.shared.get(k) for k in ("focal", "cx", "cy")]
        landmarks = kind == "landmarks" or (kind == "auto" and any(f.suffix.lower() == ".csv" for f in files))
        if landmarks and any(c is None for c in cam):
            raise _fail(job.source, "landmark targets need the camera: set shared.focal, shared.cx and shared.cy "
                                    "(pixels)")
        fitter = _check_method(job, "fitters")
        from facegeom.interfaces import batched_targets

        spec["shared"] = {"rig": rig, "kind": kind, "camera": cam,
                          "vectorised": "landmarks" in batched_targets(fitter)}
        spec["stamp"] = _stamp([rig] if rig else [spec.get("data")])

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

        rig = load_rig(spec["shared"]["rig"], lambda: _load_model(spec))
        rig.gram()  # the Gram matrix, once per worker
        rig.delta_matrix()
        return {"rig": rig, "fitter": registry.create("fitters", spec["method"], **spec["params"])}

    def compute(self, state, spec, items):
        from facegeom.interfaces import fit_many
        from facegeom.model import read_fit_target

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
                    res = fit_many(fitter, rig, targets)
                except Exception:  # noqa: BLE001 - one target broke the batch: fit them one by one to find it
                    single = [it for it, _ in good] + single
                else:
                    share = (time.perf_counter() - t0) / len(targets)
                    for k, (it, dt) in enumerate(good):
                        yield it, ("landmarks", res[k].weights, res[k].info["camera"]), dt + share

        def one(it):
            kind, tgt = read_fit_target(it["input"], rig, spec["shared"]["kind"], *cam)
            r = fitter.fit(rig, tgt)
            info = r.info if isinstance(r.info, dict) else {}
            return kind, r.weights, info.get("camera")

        yield from _timed(one, single)

    def write(self, state, spec, item, result):
        from facegeom.io import write_weights

        kind, w, cam = result
        rig = state["rig"]
        info = {"method": spec["method"], "target": item["input"], "kind": kind}
        if cam is not None:
            info["pose"] = {"R": np.asarray(cam.R).tolist(), "t": np.asarray(cam.t).tolist()}
        write_weights(item["outputs"][0], rig.names, w, info)
        return {"active": int((np.abs(w) > 1e-6).sum())}

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
            dW.append(np.asarray(res[1], dtype=np.float64) - wt)
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


# ----------------------------------------------------------------- drive


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


class _Drive(_Op):
    name = "drive"
    default_method = "tangent"
    shared_keys = {"mesh": "path", "markers": "str", "input": "str", "fill_gaps": "bool"}
    formats = ("ply", "obj", "off")
    default_format = "ply"
    suffixes = (".csv", ".npz")
    uses_truth = True

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
            raise _fail(job.source, f"shared.input {job.shared['input']!r}: choose auto, frames or sequences")
        mesh = _shared_path(job, "mesh")
        model = None
        if mesh is None:
            spec["data"] = _need_data(job, "the default rest mesh (the ICT neutral)")
            model = _load_model(spec)
            n = model.n_vertices
        else:
            try:
                n = read_mesh(mesh)[0].shape[0]
            except InputError as exc:
                raise _fail(job.source, f"shared.mesh: {exc}") from None
        ids = self._layout(job, model, n, files)
        _check_method(job, "deformers")
        spec["shared"] = {"mesh": mesh, "ids": ids.tolist(), "fill_gaps": bool(job.shared.get("fill_gaps", False))}
        spec["stamp"] = _stamp([mesh or spec.get("data")])

    def _layout(self, job, model, n, files) -> np.ndarray:
        from facegeom.io import read_marker_sequence, read_markers, read_vertex_csv
        from facegeom.model import layout

        name = job.shared.get("markers")
        if name is not None:
            p = Path(os.path.expanduser(name))
            p = p if p.is_absolute() else job.base / p
            if not p.exists() and (name in ("ict80", "landmarks68") or name.startswith("random")):
                if model is None:
                    raise _fail(job.source, f"shared.markers {name!r} is a layout of the ICT face; with "
                                            f"shared.mesh give a marker file (a CSV with a vertex_id column)")
                try:
                    return layout(model, name)
                except InputError as exc:
                    raise _fail(job.source, f"shared.markers: {exc}") from None
            if not p.exists():
                raise _fail(job.source, f"shared.markers {p}: file not found (a CSV with a vertex_id column, "
                                        f"or a layout name: ict80, landmarks68, random<k>)")
            try:
                return read_vertex_csv(p, n).ids.astype(np.int64)
            except InputError as exc:
                raise _fail(job.source, f"shared.markers: {exc}") from None
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
        raise _fail(job.source, "shared.markers is needed: a marker file (CSV with a vertex_id column) or a layout "
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
            model = _load_model(spec)
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


# ----------------------------------------------------------------- retarget


class _Retarget(_Op):
    name = "retarget"
    default_method = "tangent"
    shared_keys = {"labels": "template", "fill_gaps": "bool"}
    formats = ("npz", "csv")
    default_format = "npz"
    suffixes = (".csv", ".npz")
    uses_truth = True

    def prepare(self, job, spec, files):
        if "labels" not in job.shared:
            raise _fail(job.source, "retarget needs shared.labels, the labelled character frames of each source "
                                    "as a path template, e.g. \"labels/{stem}.csv\"")
        _check_method(job, "retargeters")
        spec["shared"] = {"fill_gaps": bool(job.shared.get("fill_gaps", False))}

    def outputs(self, job, spec, src, stem):
        return [stem.with_name(stem.name + "." + spec["format"])], \
            {"labels": str(_template(job.base, job.shared["labels"], src))}

    def one(self, state, spec, item):
        from facegeom import registry
        from facegeom.io import read_retarget_inputs

        src, P, lab, n = read_retarget_inputs(item["input"], item["extra"]["labels"], spec["shared"]["fill_gaps"])
        r = registry.create("retargeters", spec["method"], **spec["params"])
        Y = r.fit(P, lab.frames, lab.positions).transform()
        return Y, src.names, lab, n

    def write(self, state, spec, item, result):
        from facegeom.io import write_marker_sequence

        Y, names, lab, n = result
        write_marker_sequence(item["outputs"][0], Y, names=names, extra={"labelled_frames": lab.frames})
        return {"frames": int(Y.shape[0]), "filled": int(n),
                "label_dev": float(np.abs(Y[lab.frames] - lab.positions).max())}

    def evaluate(self, state, spec, item, result, truth):
        from facegeom.io import read_marker_sequence

        Y, names = result[0], result[1]
        tr = read_marker_sequence(truth).reorder(names, "truth")
        if tr.n_frames != Y.shape[0] or not np.array_equal(tr.frames, np.arange(Y.shape[0])):
            raise InputError(f"the truth must hold the frames 0..{Y.shape[0] - 1} of the source", truth)
        return _vertex_errors(Y, tr.positions, "the truth", truth)


# ----------------------------------------------------------------- animate


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


class _Animate(_Op):
    name = "animate"
    default_method = "tangent"
    shared_keys = {"start": "int", "frames": "int", "labels": "int", "seed": "int", "deformer": "str"}
    formats = ("npz",)
    default_format = "npz"
    suffixes = (".csv",)

    def prepare(self, job, spec, files):
        from facegeom.bench.common import parse_method

        s = {"start": 0, "frames": 100, "labels": 10, "seed": 0, "deformer": "tangent", **job.shared}
        if s["start"] < 0 or s["frames"] < 2 or s["labels"] < 2:
            raise _fail(job.source, "shared.start must be >= 0, shared.frames and shared.labels >= 2")
        if s["labels"] > s["frames"]:
            raise _fail(job.source, f"shared.labels {s['labels']} exceeds shared.frames {s['frames']}")
        spec["data"] = _need_data(job, "animate")
        _check_method(job, "retargeters")
        try:
            parse_method(s["deformer"]).build("deformers")
        except InputError as exc:
            raise _fail(job.source, f"shared.deformer {s['deformer']!r}: {exc}") from None
        spec["shared"] = s
        spec["stamp"] = _stamp([spec["data"]])

    def outputs(self, job, spec, src, stem):
        return [stem.with_name(stem.name + ".npz")], {}

    def state(self, spec):
        from facegeom.bench.common import parse_method

        return {"model": _load_model(spec),
                "deformer": _FitOnce(parse_method(spec["shared"]["deformer"]).build("deformers"))}

    def one(self, state, spec, item):
        from facegeom import registry
        from facegeom.cli.main import animate_take

        s = spec["shared"]
        anim, _, ids = animate_take(state["model"], item["input"], s["start"], s["frames"], s["labels"], s["seed"],
                                    lambda: registry.create("retargeters", spec["method"], **spec["params"]),
                                    lambda: state["deformer"])
        return anim, ids

    def write(self, state, spec, item, result):
        from facegeom.cli.main import write_animation_npz

        anim, ids = result
        write_animation_npz(item["outputs"][0], anim, ids)
        return {"face_err_mm_mean": float(anim.frame_error_mm.mean()),
                "face_err_mm_max": float(anim.frame_error_mm.max()),
                "marker_err_mm_mean": float(anim.marker_error_mm.mean())}


# ----------------------------------------------------------------- clean


_CLEAN_PARAMS = {
    "clean": ("merge_tol", "largest_component", "non_manifold", "orient"),
    "decimate": ("vertices", "preserve_boundary", "preserve_topology"),
    "crop": ("from_vertices", "radius", "id_range", "geodesic"),
}


class _Clean(_Op):
    name = "clean"
    default_method = "clean"
    shared_keys = {"markers": "template", "drop_lost_markers": "bool", "map": "str"}
    formats = ("obj", "ply", "off")
    default_format = ""  # the input's
    suffixes = (".obj", ".ply", ".off")

    def prepare(self, job, spec, files):
        from facegeom.pipelines.cleanup import parse_tolerance

        if job.method not in _CLEAN_PARAMS:
            raise _fail(job.source, f"method {job.method!r}: clean runs one of {', '.join(_CLEAN_PARAMS)}")
        allowed = _CLEAN_PARAMS[job.method]
        bad = [k for k in job.params if k not in allowed]
        if bad:
            raise _fail(job.source, f"params.{bad[0]}: {job.method} takes {', '.join(allowed)}")
        p = job.params
        if "merge_tol" in p:
            try:
                parse_tolerance(p["merge_tol"])
            except InputError as exc:
                raise _fail(job.source, f"params.merge_tol: {exc}") from None
        if job.method == "decimate" and not (isinstance(p.get("vertices"), int) and p["vertices"] >= 4):
            raise _fail(job.source, "decimate needs params.vertices, the target vertex count (an integer >= 4)")
        if job.method == "crop":
            if ("from_vertices" in p) == ("id_range" in p):
                raise _fail(job.source, "crop needs either params.from_vertices with params.radius, or "
                                        "params.id_range (one of them)")
            if "from_vertices" in p and "radius" not in p:
                raise _fail(job.source, "params.from_vertices needs params.radius (geodesic distance)")
        m = job.shared.get("map")
        if m is not None and m not in ("csv", "npz"):
            raise _fail(job.source, f"shared.map {m!r}: an index map is csv or npz")
        spec["shared"] = {"markers": "markers" in job.shared, "drop_lost_markers":
                          bool(job.shared.get("drop_lost_markers", False)), "map": m}

    def outputs(self, job, spec, src, stem):
        fmt = spec["format"] or src.suffix.lower().lstrip(".")
        outs = [stem.with_name(stem.name + "." + fmt)]
        extra = {}
        if spec["shared"]["map"]:
            outs.append(stem.with_name(stem.name + ".map." + spec["shared"]["map"]))
        if spec["shared"]["markers"]:
            extra["markers"] = str(_template(job.base, job.shared["markers"], src))
            outs.append(stem.with_name(stem.name + ".markers.csv"))
        outs.append(stem.with_name(stem.name + ".report.json"))
        return outs, extra

    def one(self, state, spec, item):
        from facegeom.cli.cleanup import _read_input
        from facegeom.io import read_vertex_csv
        from facegeom.pipelines import cleanup

        method, p = spec["method"], dict(spec["params"])
        V, F = _read_input(item["input"], polygons=method == "clean")
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


_OPS = {op.name: op for op in (_Fit(), _Drive(), _Retarget(), _Animate(), _Clean())}


# --------------------------------------------------------------------------- planning


def _stamp(paths) -> list:
    """Sizes and modification times of shared files: a changed file makes a new worker-cache key."""
    out = []
    for p in paths:
        if p is None:
            continue
        q = Path(p)
        files = sorted(q.iterdir()) if q.is_dir() else [q]
        for f in files:
            with contextlib.suppress(OSError):
                st = f.stat()
                out.append([str(f), st.st_size, st.st_mtime_ns])
    return out


def _hash(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()


def _find_inputs(job: Job, op: _Op) -> list[Path]:
    out = os.path.realpath(job.output) + os.sep
    found: set[str] = set()
    real_dirs: dict[str, str] = {}

    def real(f: str) -> str:  # resolve the folder once, not every file (10,000 inputs: 1.3 s -> 0.1 s)
        d, name = os.path.split(f)
        if os.path.islink(f):
            return os.path.realpath(f)
        if d not in real_dirs:
            real_dirs[d] = os.path.realpath(d or ".")
        return os.path.join(real_dirs[d], name)

    for pattern in job.inputs:
        if os.path.isdir(pattern):
            with os.scandir(pattern) as it:
                files = [e.path for e in it if os.path.splitext(e.name)[1].lower() in op.suffixes]
        elif glob.has_magic(pattern):
            files = glob.glob(pattern, recursive=True)
        elif os.path.exists(pattern):
            files = [pattern]
        else:
            raise _fail(job.source, f"inputs: {pattern}: file not found")
        for f in files:
            f = real(f)
            if os.path.basename(f).startswith(".") or f.startswith(out) or not os.path.isfile(f):
                continue
            found.add(f)
    if not found:
        raise _fail(job.source, f"no input matched {', '.join(repr(x) for x in job.inputs)}"
                                f" (for {job.operation}: {', '.join(op.suffixes)} files)")
    return [Path(f) for f in sorted(found)]


def _plan(job: Job) -> tuple[dict, list[dict], int]:
    """Check the job; resolve shared inputs; list the items with their output files; the chunk size."""
    op = _OPS[job.operation]
    files = _find_inputs(job, op)
    spec = {"operation": job.operation, "method": job.method, "params": job.params, "shared": {},
            "data": None, "format": job.format or op.default_format, "truth": job.truth}
    op.prepare(job, spec, files)
    spec["config"] = _hash({k: spec[k] for k in ("operation", "method", "params", "shared", "data", "format",
                                                 "truth")})
    spec["key"] = _hash([spec["config"], spec.get("stamp")])[:16]
    root = Path(os.path.commonpath([str(f.parent) for f in files]))
    out = job.output.resolve()
    items, owner = [], {}
    inputs = {str(f) for f in files}
    own = {str(out / SUMMARY_NAME), str(out / MANIFEST_NAME)}
    root_s = str(root)
    for k, f in enumerate(files):
        fs = str(f)
        rel_parent, name = os.path.split(os.path.relpath(fs, root_s))
        stem = out / rel_parent / os.path.splitext(name)[0] if rel_parent else out / os.path.splitext(name)[0]
        outs, extra = op.outputs(job, spec, f, stem)
        outs = [str(o) for o in outs]
        for o in outs:
            if o in owner:
                raise _fail(job.source, f"inputs {owner[o]} and {f} would both write {o}; rename one")
            if o in inputs:
                raise _fail(job.source, f"the output {o} would overwrite an input; choose another output folder")
            if o in own:
                raise _fail(job.source, f"input {f} would write over the batch's own {SUMMARY_NAME} / "
                                        f"{MANIFEST_NAME}")
            owner[o] = fs
        truth = str(_template(job.base, job.truth, f)) if job.truth else None
        items.append({"index": k, "input": fs, "outputs": outs, "truth": truth, "extra": extra})
    chunk = job.chunk or op.default_chunk(job, spec, items)
    return spec, items, chunk


# --------------------------------------------------------------------------- running


@dataclass
class BatchResult:
    """What :func:`run_job` did: one row per input (in input order), the summary file, counts."""

    rows: list[dict]
    summary: Path
    seconds: float
    engine: str
    chunk: int
    tasks: int

    @property
    def counts(self) -> dict:
        c = {"ok": 0, "failed": 0, "skipped": 0, "not run": 0}
        for r in self.rows:
            c[r["status"]] = c.get(r["status"], 0) + 1
        return c

    @property
    def failed(self) -> list[dict]:
        return [r for r in self.rows if r["status"] == "failed"]


def default_workers() -> int:
    """One worker process per core available to this process."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


# Dask settings of the local cluster (see local_cluster): measured on 2,048 SEM landmark fits with 2 workers on
# this 2-core machine, they cut the workers' CPU time by ~11% and the client's by half (wall 13.9 s -> 11.6 s).
LOCAL_CLUSTER_CONFIG = {
    # glibc's default trimming: Dask's MALLOC_TRIM_THRESHOLD_=65536 returns freed memory to the system at once,
    # so every large numpy temporary becomes a fresh mmap (vectorised landmark fits 1.6x slower)
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
    # no dashboard, so no statistical profiler sampling the task thread every 10 ms
    "distributed.worker.profile.enabled": False,
    # the event-loop health tick (20 ms), the nanny's memory poll (100 ms) and the dashboard's system monitor
    # (500 ms) each take the GIL or a core from the tasks; a batch job needs none of them that often
    "distributed.admin.tick.interval": "500ms",
    "distributed.worker.memory.monitor-interval": "2s",
    "distributed.admin.system-monitor.interval": "5s",
}


def local_cluster(n_workers: int | None = None):
    """The default engine: a :class:`distributed.LocalCluster` of ``n_workers`` processes x 1 thread on loopback.

    One process per core by default, no dashboard, with :data:`LOCAL_CLUSTER_CONFIG`
    (glibc's default memory trimming, no worker profiler, slower housekeeping
    ticks). On a cluster of your own, the same settings in its Dask
    configuration give the same speed.
    """
    import dask
    from distributed import LocalCluster

    with dask.config.set(LOCAL_CLUSTER_CONFIG):
        # no dashboard; the scheduler's small HTTP server (health checks) on a free port, not on 8787, which
        # another Dask session may hold (Dask would warn and move)
        return LocalCluster(n_workers=n_workers or default_workers(), threads_per_worker=1, processes=True,
                            host="127.0.0.1", dashboard_address=None,
                            scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"})


@contextlib.contextmanager
def _engine(client=None, scheduler: str | None = None, workers: int | None = None):
    """A Dask client: the given one, one connected to ``scheduler``, or a new local cluster."""
    if client is not None:
        yield client, f"Dask scheduler {client.scheduler.address}"
        return
    from distributed import Client

    if scheduler:
        try:
            c = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise InputError(f"cannot reach the Dask scheduler at {scheduler}: {_describe(exc)}") from None
        try:
            yield c, f"Dask scheduler {scheduler} ({len(c.scheduler_info(n_workers=-1)['workers'])} workers)"
        finally:
            c.close()
        return
    n = workers or default_workers()
    cluster = local_cluster(n)
    c = Client(cluster)
    try:
        yield c, f"local Dask cluster, {n} worker process{'es' if n > 1 else ''} x 1 thread"
    finally:
        c.close()
        cluster.close()


def _read_summary(path: Path) -> dict:
    if not path.is_file():
        return {}
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            return {r["input"]: r for r in csv.DictReader(fh) if r.get("input")}
    except (OSError, UnicodeDecodeError, csv.Error, KeyError):
        return {}


def _fmt(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return "" if math.isnan(v) else f"{v:.6g}"
    return str(v)


def _write_summary(path: Path, rows: list[dict]) -> None:
    from facegeom.io import atomic_path

    cols = list(SUMMARY_COLUMNS)
    for r in rows:
        cols += [k for k in r if k not in cols and not k.startswith("_") and k != "index"]
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(cols)
            for r in rows:
                w.writerow([_fmt(r.get(c)) for c in cols])


def _manifest(job: Job, spec: dict, overwrite: bool) -> None:
    from facegeom import __version__
    from facegeom.io import atomic_path

    path = job.output / MANIFEST_NAME
    want = {"config": spec["config"], "operation": spec["operation"], "method": spec["method"],
            "params": spec["params"], "shared": spec["shared"], "data": spec["data"], "format": spec["format"],
            "truth": spec["truth"]}
    if path.is_file() and not overwrite:
        try:
            have = json.loads(path.read_text())
        except (OSError, ValueError):
            have = {}
        if have.get("config") not in (None, spec["config"]):
            diff = [k for k in ("operation", "method", "params", "shared", "data", "format", "truth")
                    if json.dumps(have.get(k), sort_keys=True, default=str)
                    != json.dumps(want[k], sort_keys=True, default=str)]
            raise InputError(f"holds the results of another job (its {', '.join(diff) or 'settings'} differ); use "
                             f"another output folder, or overwrite to recompute everything", job.output)
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps({**want, "facegeom": __version__, "job": job.source}, indent=2, default=str)
                       + "\n")


def run_job(job: Job, *, client=None, scheduler: str | None = None, workers: int | None = None,
            inline: bool = False, overwrite: bool = False, progress: bool = True, echo=None) -> BatchResult:
    """Run ``job``: skip complete outputs, process the rest on Dask, write the summary CSV.

    Parameters
    ----------
    client : distributed.Client, optional
        Run on this client's cluster (left open).
    scheduler : str, optional
        Address of a running Dask scheduler (default ``$DASK_SCHEDULER_ADDRESS``);
        otherwise a local cluster of ``workers`` processes (default: one per core).
    inline : bool
        No Dask: the same chunks, in this process, one after the other.
    overwrite : bool
        Delete the outputs of every input first and recompute them all.
    echo : callable, optional
        Where to say what is being done (e.g. ``print``); silent by default.

    Raises
    ------
    InputError
        A bad job (no input matched, a missing shared file, an unknown method,
        an output folder made by another job). Bad *inputs* never raise: their
        rows in :attr:`BatchResult.rows` and the summary say ``failed``.
    """
    say = echo or (lambda *_: None)
    t_start = time.perf_counter()
    spec, items, chunk = _plan(job)
    job.output.mkdir(parents=True, exist_ok=True)
    _manifest(job, spec, overwrite)
    summary = job.output / SUMMARY_NAME
    if overwrite:
        for it in items:
            for o in it["outputs"]:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(o)
        with contextlib.suppress(FileNotFoundError):
            os.unlink(summary)
    stale = _remove_stale_temporaries(items)
    if stale:
        say(f"removed {stale} temporary file{'s' if stale > 1 else ''} left by an interrupted earlier run")
    previous = _read_summary(summary)
    rows: dict[int, dict] = {}
    chunks = []
    for c0 in range(0, len(items), chunk):
        todo = [it for it in items[c0:c0 + chunk] if not _complete(it)]
        if todo:
            chunks.append(todo)
    n_todo = sum(len(c) for c in chunks)
    for it in items:
        if _complete(it):
            rows[it["index"]] = _row(it, "skipped", "output already complete (an earlier run wrote it)", None, "")
    engine = "inline (this process)" if inline else None
    say(f"{job.operation} ({spec['method']}): {len(items)} inputs, {n_todo} to do in {len(chunks)} tasks of up to "
        f"{chunk}, {len(items) - n_todo} already complete -> {job.output}")
    try:
        if chunks and inline:
            say(f"engine: {engine}")
            with _progress(n_todo, job.operation, progress) as bar:
                for c in chunks:
                    try:
                        for r in run_chunk(spec, c):
                            rows[r["index"]] = r
                    except Exception as exc:  # noqa: BLE001 - as a failed task on Dask
                        for it in c:
                            rows[it["index"]] = _row(it, "failed", f"task failed: {_describe(exc)}", None, "")
                    bar.update(len(c))
        elif chunks:
            with _engine(client, scheduler or os.environ.get("DASK_SCHEDULER_ADDRESS"), workers) as (cl, engine):
                say(f"engine: {engine}")
                _run_on_dask(cl, spec, chunks, rows, job.retries, progress)
    finally:
        out_rows = _finish_rows(job, items, rows, previous)
        _write_summary(summary, out_rows)
    return BatchResult(out_rows, summary, time.perf_counter() - t_start, engine or "nothing to do", chunk,
                       len(chunks))


def _remove_stale_temporaries(items: list[dict]) -> int:
    """Delete the temporary files of this job's outputs (``.STEM.*.tmp.EXT``, see :func:`facegeom.io.files.atomic_path`).

    A process killed while writing leaves its temporary file behind (the output
    itself is never half-written). Run before any task starts, so none is in use
    by this job.
    """
    wanted: dict[str, dict[str, set]] = {}  # folder -> ".STEM." -> {".tmp.EXT"}
    for it in items:
        for o in it["outputs"]:
            folder, name = os.path.split(o)
            stem, ext = os.path.splitext(name)
            wanted.setdefault(folder, {}).setdefault(f".{stem}.", set()).add(f".tmp{ext}")
    removed = 0
    for folder, prefixes in wanted.items():
        try:
            names = [n for n in os.listdir(folder) if n.startswith(".") and ".tmp" in n]
        except OSError:
            continue
        for n in names:
            # the stem may hold dots ("g1.map"): try every prefix ending at a dot
            hit = any(n[:k + 1] in prefixes and any(n.endswith(x) for x in prefixes[n[:k + 1]])
                      for k in range(1, len(n)) if n[k] == ".")
            if hit:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(os.path.join(folder, n))
                    removed += 1
    return removed


def _run_on_dask(client, spec: dict, chunks: list[list[dict]], rows: dict, retries: int, progress: bool) -> None:
    from distributed import as_completed

    token = hashlib.sha1(f"{spec['key']}{time.time_ns()}{os.getpid()}".encode()).hexdigest()[:8]
    futures = {}
    for k, c in enumerate(chunks):
        f = client.submit(run_chunk, spec, c, key=f"facegeom-{spec['operation']}-{token}-{k}", retries=retries)
        futures[f] = c
    try:
        with _progress(sum(len(c) for c in chunks), spec["operation"], progress) as bar:
            for fut, res in as_completed(list(futures), with_results=True, raise_errors=False):
                c = futures.pop(fut)
                if fut.status == "error":  # the task itself failed (e.g. its worker died too often)
                    msg = _task_error(fut)
                    for it in c:
                        rows[it["index"]] = _row(it, "failed", msg, None, "")
                else:
                    for r in res:
                        rows[r["index"]] = r
                fut.release()  # the rows are here: a later worker death must not recompute the task
                bar.update(len(c))
    finally:
        if futures:
            client.cancel(list(futures))


def _task_error(fut) -> str:
    try:
        exc = fut.exception()
    except Exception as e:  # noqa: BLE001
        exc = e
    name = type(exc).__name__
    if name == "KilledWorker":
        return ("task failed: its worker process died each time it ran it (KilledWorker; out of memory or a crash "
                "in native code?)")
    return f"task failed: {_describe(exc)}"


def _finish_rows(job: Job, items: list[dict], rows: dict, previous: dict) -> list[dict]:
    out = []
    for it in items:
        r = dict(rows.get(it["index"]) or _row(it, "not run", "interrupted before this input ran", None, ""))
        inp = Path(it["input"])
        r["input"] = str(inp.relative_to(job.base)) if job.base in inp.parents else str(inp)
        o = Path(it["outputs"][0])
        r["output"] = str(o.relative_to(job.output.resolve())) if job.output.resolve() in o.parents else str(o)
        if r["status"] == "skipped":
            old = previous.get(r["input"])
            if old and old.get("status") in ("ok", "skipped") and old.get("output") == r["output"]:
                # the metrics and time of the run that wrote it
                for k, v in old.items():
                    if k not in ("input", "output", "status", "message") and v not in (None, ""):
                        r[k] = v
                r["message"] = "output already complete (an earlier run wrote it)"
        out.append(r)
    return out


@contextlib.contextmanager
def _progress(total: int, desc: str, enabled: bool):
    from tqdm import tqdm

    bar = tqdm(total=total, desc=desc, unit="item", disable=not enabled, dynamic_ncols=True)
    try:
        yield bar
    finally:
        bar.close()
