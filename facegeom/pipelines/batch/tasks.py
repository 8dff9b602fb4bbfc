"""A task on a worker: a chunk of items run with the job's state cached per process, one summary row per item.

The heavy shared state of a job (rig and Gram matrix, fitted deformer, face
model) is built once per worker process and kept in a module-level cache keyed
by the job's hash (:func:`worker_state`); ``_BUILDS`` counts the builds (tests
read it on the workers).
"""
from __future__ import annotations

import contextlib
import os
import socket
import threading
import time

from facegeom.errors import FacegeomError
from facegeom.pipelines.batch.operations import OPS, Operation

__all__ = ["worker_state", "SharedStateError", "run_chunk", "make_row", "describe", "is_complete", "worker_name"]

_STATE: dict = {}
_STATE_LOCK = threading.Lock()
_BUILDS: dict = {}  # job key -> how many times this process built the state (1 unless evicted)
_KEEP = 2  # job states kept per worker process


def worker_state(spec: dict):
    """The operation's shared state for a task, built once per process and cached by the job key.

    Parameters
    ----------
    spec : dict
        The task spec; ``spec["key"]`` identifies the job and its shared files' versions.

    Returns
    -------
    object
        What the operation's ``state(spec)`` built (e.g. ``{"rig": ..., "fitter": ...}``).
    """
    key = spec["key"]
    with _STATE_LOCK:
        st = _STATE.get(key)
        if st is None:
            st = OPS[spec["operation"]].state(spec)
            while len(_STATE) >= _KEEP:
                _STATE.pop(next(iter(_STATE)))
            _STATE[key] = st
            _BUILDS[key] = _BUILDS.get(key, 0) + 1
    return st


class SharedStateError(FacegeomError, RuntimeError):
    """A worker could not build the job's shared state (rig, fitted deformer, face model)."""


def worker_name() -> str:
    """``host:pid`` of this process (the summary's ``worker`` column)."""
    return f"{socket.gethostname()}:{os.getpid()}"


def describe(exc: BaseException) -> str:
    """An exception as one line: a facegeom error's own message, else ``Type: message``.

    Parameters
    ----------
    exc : BaseException

    Returns
    -------
    str
    """
    if isinstance(exc, FacegeomError):
        return " ".join(str(exc).split())
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def is_complete(item: dict) -> bool:
    """Whether every output file of ``item`` exists (outputs are written atomically, so they are whole)."""
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
        found = Operation.evaluate_many(op, state, spec, pairs)
    share = (time.perf_counter() - t0) / len(with_truth)
    for (it, _, metrics, seconds), m in zip(with_truth, found):
        if isinstance(m, BaseException):
            metrics["_note"] = f"ground truth: {describe(m)}"
        else:
            metrics.update(m)
        seconds[0] += share


def run_chunk(spec: dict, items: list[dict]) -> list[dict]:
    """Process a chunk of items (a task): skip complete ones, compute and write the others; one row each.

    Never raises for a bad item: its row says ``failed`` with the message. Error
    metrics against ground truth are computed after the chunk's outputs are
    written, for the whole chunk at once.

    Parameters
    ----------
    spec : dict
        The task spec (:func:`facegeom.pipelines.batch.plan.plan`).
    items : list of dict
        The chunk's items: ``index``, ``input``, ``outputs``, ``truth``, ``extra``.

    Returns
    -------
    list of dict
        One summary row per item (:func:`make_row`), in chunk order.

    Raises
    ------
    SharedStateError
        The job's shared state cannot be built (Dask then retries the task).
    """
    op = OPS[spec["operation"]]
    where = worker_name()
    rows = {}
    todo = []
    for it in items:
        if is_complete(it):
            rows[it["index"]] = make_row(it, "skipped", "output already complete (an earlier attempt or run wrote it)",
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
        raise SharedStateError(f"shared state: {describe(exc)}") from exc
    done = []
    for it, res, seconds in op.compute(state, spec, todo):
        if isinstance(res, BaseException):
            rows[it["index"]] = make_row(it, "failed", describe(res), seconds, where)
            continue
        t0 = time.perf_counter()
        try:
            metrics = op.write(state, spec, it, res) or {}
        except Exception as exc:  # noqa: BLE001
            rows[it["index"]] = make_row(it, "failed", describe(exc), seconds + time.perf_counter() - t0, where)
            continue
        done.append((it, res, metrics, [seconds + time.perf_counter() - t0]))
    _measure(op, state, spec, done)
    for it, _, metrics, seconds in done:
        note = metrics.pop("_note", "")
        rows[it["index"]] = make_row(it, "ok", note, seconds[0], where, metrics)
    return [rows[it["index"]] for it in items if it["index"] in rows]


def make_row(item: dict, status: str, message: str, seconds, where: str, metrics: dict | None = None) -> dict:
    """A summary row of ``item``.

    Parameters
    ----------
    item : dict
        The item (its ``index``).
    status : str
        ``ok``, ``failed``, ``skipped`` or ``not run``.
    message : str
        Why it failed or was skipped, or a note.
    seconds : float or None
        Time spent on the item.
    where : str
        The worker (``host:pid``), or empty.
    metrics : dict, optional
        Extra columns (output sizes, errors against the truth).

    Returns
    -------
    dict
    """
    r = {"index": item["index"], "status": status, "message": message,
         "time_s": None if seconds is None else float(seconds), "worker": where}
    r.update(metrics or {})
    return r
