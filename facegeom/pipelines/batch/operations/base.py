"""The base of the batch operations and the checks they share."""
from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.pipelines.batch.job import Job, job_error

__all__ = ["Operation", "timed", "need_data", "shared_path", "check_method", "vertex_errors"]


def timed(fn, items):
    """Per-item compute: yield ``(item, fn(item) or the exception it raised, seconds)``.

    Parameters
    ----------
    fn : callable
        The computation of one item.
    items : iterable of dict

    Yields
    ------
    tuple of (dict, object, float)
    """
    for it in items:
        t0 = time.perf_counter()
        try:
            res = fn(it)
        except Exception as exc:  # noqa: BLE001 - one bad input fails its own row
            res = exc
        yield it, res, time.perf_counter() - t0


def need_data(job: Job, what: str) -> str:
    """The face data bundle that ``what`` of the job needs (the job's ``data``, else the default location).

    Parameters
    ----------
    job : Job
    what : str
        What needs it (for the message).

    Returns
    -------
    str
        Its path.

    Raises
    ------
    InputError
        No face data found, naming the job.
    """
    from facegeom.model import locate_data

    try:
        return str(locate_data(job.data))
    except InputError as exc:
        raise job_error(job.source, f"{what} needs the face data: {exc}") from None


def shared_path(job: Job, key: str, must_exist: bool = True, dir_ok: bool = False) -> str | None:
    """The absolute path of the shared input ``key`` (None when the job has none).

    Parameters
    ----------
    job : Job
    key : str
        The key in ``[shared]``.
    must_exist : bool
        Refuse a missing file.
    dir_ok : bool
        Accept a folder.

    Returns
    -------
    str or None

    Raises
    ------
    InputError
        Missing, or a folder where a file is needed, naming the job.
    """
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


def check_method(job: Job, kind: str):
    """Build the job's method of ``kind`` once on the client, so a bad name or parameter fails the job early.

    Parameters
    ----------
    job : Job
    kind : str
        ``fitters``, ``deformers`` or ``retargeters``.

    Returns
    -------
    object
        The method.

    Raises
    ------
    InputError
        Unknown method or bad parameters, naming the job.
    """
    from facegeom import registry

    try:
        return registry.create(kind, job.method, **job.params)
    except InputError as exc:
        raise job_error(job.source, f"method {job.method!r}: {exc}") from None


def vertex_errors(A: np.ndarray, B: np.ndarray, what: str, path) -> dict:
    """Mean and largest point distance between a result and its ground truth.

    Parameters
    ----------
    A : ndarray, shape (..., 3)
        The result (e.g. ``(n, 3)`` vertices or ``(T, p, 3)`` markers).
    B : ndarray, same shape as ``A``
        The truth.
    what, path
        The truth's description and file, for the error.

    Returns
    -------
    dict
        ``err_mean`` and ``err_max`` (NaN distances ignored).

    Raises
    ------
    InputError
        The shapes differ.
    """
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
        return timed(lambda it: self.one(state, spec, it), items)

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
