"""Running a job: plan it, check the output folder, skip what is complete, run the rest, write the summary."""
from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

from facegeom.pipelines.batch.engine import connect, run_inline, run_on_dask
from facegeom.pipelines.batch.job import Job
from facegeom.pipelines.batch.ledger import (
    SUMMARY_NAME,
    finish_rows,
    make_output_folders,
    read_summary,
    remove_outputs,
    remove_stale_temporaries,
    write_manifest,
    write_summary,
)
from facegeom.pipelines.batch.lock import output_lock
from facegeom.pipelines.batch.plan import plan
from facegeom.pipelines.batch.tasks import is_complete, make_row

__all__ = ["BatchResult", "run_job"]


@dataclass
class BatchResult:
    """What :func:`run_job` did.

    Attributes
    ----------
    rows : list of dict
        One summary row per input, in input order.
    summary : Path
        The summary CSV.
    seconds : float
        Wall time of the run.
    engine : str
        Where the tasks ran.
    chunk : int
        Items per task.
    tasks : int
        Tasks run.
    """

    rows: list[dict]
    summary: Path
    seconds: float
    engine: str
    chunk: int
    tasks: int

    @property
    def counts(self) -> dict:
        """Inputs per status: ``ok``, ``failed``, ``skipped``, ``not run``."""
        c = {"ok": 0, "failed": 0, "skipped": 0, "not run": 0}
        for r in self.rows:
            c[r["status"]] = c.get(r["status"], 0) + 1
        return c

    @property
    def failed(self) -> list[dict]:
        """The rows of the inputs that failed."""
        return [r for r in self.rows if r["status"] == "failed"]


def run_job(job: Job, *, client=None, scheduler: str | None = None, workers: int | None = None,
            inline: bool = False, isolate: bool = False, overwrite: bool = False, progress: bool = True,
            echo=None) -> BatchResult:
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
    isolate : bool
        With ``inline``: run each chunk in a forked child process, so a native
        crash (segfault) fails only the input that caused it (see
        :mod:`facegeom.pipelines.batch`). Off by default: no process per chunk.
    overwrite : bool
        Delete the outputs of every input first and recompute them all.
    echo : callable, optional
        Where to say what is being done (e.g. ``print``); silent by default.

    Raises
    ------
    InputError
        A bad job (no input matched, a missing shared file, an unknown method,
        an output folder made by another job, or one another run is writing to). Bad *inputs* never raise: their
        rows in :attr:`BatchResult.rows` and the summary say ``failed``.
    """
    say = echo or (lambda *_: None)
    t_start = time.perf_counter()
    spec, items, chunk = plan(job)
    make_output_folders(job, items)
    with output_lock(job.output):
        out_rows, engine, n_tasks, summary = _run_locked(job, spec, items, chunk, client, scheduler, workers, inline,
                                                         isolate, overwrite, progress, say)
    return BatchResult(out_rows, summary, time.perf_counter() - t_start, engine or "nothing to do", chunk, n_tasks)


def _run_locked(job, spec, items, chunk, client, scheduler, workers, inline, isolate, overwrite, progress, say):
    """The run in an output folder this process has locked: ``(rows, engine, tasks, summary path)``."""
    write_manifest(job, spec, overwrite)
    summary = job.output / SUMMARY_NAME
    if overwrite:
        remove_outputs(items, summary)
    stale = remove_stale_temporaries(items)
    if stale:
        say(f"removed {stale} temporary file{'s' if stale > 1 else ''} left by an interrupted earlier run")
    previous = read_summary(summary)
    chunks, rows = _schedule(items, chunk)
    n_todo = sum(len(c) for c in chunks)
    engine = ("inline (this process, a child process per task)" if isolate else "inline (this process)") \
        if inline else None
    say(f"{job.operation} ({spec['method']}): {len(items)} inputs, {n_todo} to do in {len(chunks)} tasks of up to "
        f"{chunk}, {len(items) - n_todo} already complete -> {job.output}")
    try:
        if chunks and inline:
            say(f"engine: {engine}")
            run_inline(spec, chunks, rows, progress, isolate)
        elif chunks:
            with connect(client, scheduler or os.environ.get("DASK_SCHEDULER_ADDRESS"), workers) as (cl, engine):
                say(f"engine: {engine}")
                run_on_dask(cl, spec, chunks, rows, job.retries, progress)
    finally:
        out_rows = finish_rows(job, items, rows, previous)
        write_summary(summary, out_rows)
    return out_rows, engine, len(chunks), summary


def _schedule(items: list[dict], chunk: int) -> tuple[list[list[dict]], dict[int, dict]]:
    """The tasks: fixed chunks of ``chunk`` items less the complete ones; a ``skipped`` row per complete item."""
    chunks = []
    for c0 in range(0, len(items), chunk):
        todo = [it for it in items[c0:c0 + chunk] if not is_complete(it)]
        if todo:
            chunks.append(todo)
    rows = {it["index"]: make_row(it, "skipped", "output already complete (an earlier run wrote it)", None, "")
            for it in items if is_complete(it)}
    return chunks, rows
