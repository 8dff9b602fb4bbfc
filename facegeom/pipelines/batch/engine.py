"""Where the chunks run: Dask (a local cluster or a scheduler, retries, worker deaths) or inline; progress."""
from __future__ import annotations

import contextlib
import hashlib
import os
import signal
import time

from facegeom.errors import InputError
from facegeom.pipelines.batch.tasks import describe, make_row, run_chunk

__all__ = ["default_workers", "LOCAL_CLUSTER_CONFIG", "local_cluster", "connect", "run_inline", "run_on_dask",
           "progress_bar"]


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
def connect(client=None, scheduler: str | None = None, workers: int | None = None):
    """A Dask client: the given one, one connected to ``scheduler``, or a new local cluster (closed on exit).

    Parameters
    ----------
    client : distributed.Client, optional
        Used as it is and left open.
    scheduler : str, optional
        Address of a running scheduler.
    workers : int, optional
        Worker processes of a new local cluster (default: one per core).

    Yields
    ------
    client : distributed.Client
    description : str
        Where the tasks run, for the log.

    Raises
    ------
    InputError
        The scheduler cannot be reached.
    """
    if client is not None:
        yield client, f"Dask scheduler {client.scheduler.address}"
        return
    from distributed import Client

    if scheduler:
        try:
            c = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise InputError(f"cannot reach the Dask scheduler at {scheduler}: {describe(exc)}") from None
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


def run_inline(spec: dict, chunks: list[list[dict]], rows: dict, progress: bool, isolate: bool = False) -> None:
    """Run the chunks in this process, one after the other; their rows go into ``rows`` (by item index).

    Parameters
    ----------
    spec : dict
        The task spec (:func:`facegeom.pipelines.batch.plan.plan`).
    chunks : list of list of dict
        The items of each task.
    rows : dict
        Summary rows by item index, filled in place.
    progress : bool
        Show a progress bar.
    isolate : bool
        Run each chunk in a forked child process (the shared state is built
        once here first and inherited): a native crash costs its chunk's child,
        whose items are then run one child each, so only the crashing input
        fails. Without it a crash ends this process.
    """
    if isolate:
        _prebuild_state(spec)
    with progress_bar(sum(len(c) for c in chunks), spec["operation"], progress) as bar:
        for c in chunks:
            if isolate:
                _run_isolated(spec, c, rows)
            else:
                try:
                    for r in run_chunk(spec, c):
                        rows[r["index"]] = r
                except Exception as exc:  # noqa: BLE001 - as a failed task on Dask
                    for it in c:
                        rows[it["index"]] = make_row(it, "failed", f"task failed: {describe(exc)}", None, "")
            bar.update(len(c))


def _prebuild_state(spec: dict) -> None:
    """Build the job's shared state in this process, so forked children inherit it (a failure: each chunk says)."""
    from facegeom.pipelines.batch.tasks import worker_state

    with contextlib.suppress(Exception):
        worker_state(spec)


def _child(spec: dict, items: list[dict], conn) -> None:
    try:
        conn.send(("rows", run_chunk(spec, items)))
    except Exception as exc:  # noqa: BLE001 - sent to the parent as the task's failure
        conn.send(("error", f"task failed: {describe(exc)}"))
    finally:
        conn.close()


def _in_child(spec: dict, items: list[dict]) -> tuple[str, object]:
    """``run_chunk(spec, items)`` in a forked child: ``("rows", rows)``, ``("error", message)`` or ``("died", how)``."""
    import multiprocessing

    try:
        ctx = multiprocessing.get_context("fork")
    except ValueError:  # pragma: no cover - no fork (Windows)
        raise InputError("isolated inline runs need fork (POSIX); run on a local Dask cluster instead") from None
    recv, send = ctx.Pipe(duplex=False)
    p = ctx.Process(target=_child, args=(spec, items, send), daemon=True)
    p.start()
    send.close()
    try:
        msg = recv.recv()
    except EOFError:
        msg = None
    finally:
        recv.close()
        p.join()
    if msg is not None:
        return msg
    code = p.exitcode
    if code is not None and code < 0:
        with contextlib.suppress(ValueError):
            return "died", signal.Signals(-code).name
        return "died", f"signal {-code}"
    return "died", f"exit status {code}"


def _run_isolated(spec: dict, chunk: list[dict], rows: dict) -> None:
    """One chunk in a child; if the child dies, each of its items in a child of its own."""
    kind, value = _in_child(spec, chunk)
    if kind == "died" and len(chunk) > 1:
        for it in chunk:
            _run_isolated(spec, [it], rows)
        return
    if kind == "rows":
        for r in value:
            rows[r["index"]] = r
        return
    msg = value if kind == "error" else (f"task failed: its process died while processing this input ({value}; a "
                                         f"crash in native code or out of memory?)")
    for it in chunk:
        rows[it["index"]] = make_row(it, "failed", msg, None, "")


def run_on_dask(client, spec: dict, chunks: list[list[dict]], rows: dict, retries: int, progress: bool) -> None:
    """Submit a task per chunk; gather their rows into ``rows`` as they finish (a failed task fails its items).

    Parameters
    ----------
    client : distributed.Client
    spec : dict
        The task spec.
    chunks : list of list of dict
        The items of each task.
    rows : dict
        Summary rows by item index, filled in place.
    retries : int
        Retries of a task that raised.
    progress : bool
        Show a progress bar.
    """
    from distributed import as_completed

    token = hashlib.sha1(f"{spec['key']}{time.time_ns()}{os.getpid()}".encode()).hexdigest()[:8]
    futures = {}
    suspects: list[tuple[list[dict], str]] = []  # single inputs killed with their worker, to rerun alone
    alone: set[str] = set()  # names of tasks that ran with no other task in flight

    def rerun_alone(done) -> None:
        """When nothing else is in flight, submit the next suspect: no other task can share its worker."""
        if futures or not suspects:
            return
        c, name = suspects.pop(0)
        alone.add(f"{name}-alone")
        f = client.submit(run_chunk, spec, c, retries=retries, key=f"facegeom-{spec['operation']}-{token}-{name}-alone")
        futures[f] = (c, f"{name}-alone")
        done.add(f)

    for k, c in enumerate(chunks):
        f = client.submit(run_chunk, spec, c, key=f"facegeom-{spec['operation']}-{token}-{k}", retries=retries)
        futures[f] = (c, str(k))
    try:
        with progress_bar(sum(len(c) for c in chunks), spec["operation"], progress) as bar:
            done = as_completed(list(futures), with_results=True, raise_errors=False)
            for fut, res in done:
                c, name = futures.pop(fut)
                if fut.status == "error":  # the task itself failed (e.g. its worker died too often)
                    exc = _task_exception(fut)
                    if type(exc).__name__ == "KilledWorker" and len(c) > 1:
                        fut.release()
                        # a crash in one input: its chunk's items one task each, so only that input fails
                        for j, it in enumerate(c):
                            f = client.submit(run_chunk, spec, [it], retries=retries,
                                              key=f"facegeom-{spec['operation']}-{token}-{name}-{j}")
                            futures[f] = ([it], f"{name}-{j}")
                            done.add(f)
                        continue
                    if type(exc).__name__ == "KilledWorker" and name not in alone:
                        # one input whose worker died: it may only have been queued on the worker a crashing
                        # input killed; it runs again on its own once everything else is done
                        fut.release()
                        suspects.append((c, name))
                        rerun_alone(done)
                        continue
                    msg = _task_error(exc, len(c))
                    for it in c:
                        rows[it["index"]] = make_row(it, "failed", msg, None, "")
                else:
                    for r in res:
                        rows[r["index"]] = r
                fut.release()  # the rows are here: a later worker death must not recompute the task
                bar.update(len(c))
                rerun_alone(done)
    finally:
        if futures:
            client.cancel(list(futures))


def _task_exception(fut) -> BaseException:
    try:
        return fut.exception()
    except Exception as e:  # noqa: BLE001
        return e


def _task_error(exc: BaseException, n_items: int) -> str:
    name = type(exc).__name__
    if name == "KilledWorker":
        what = "it" if n_items > 1 else "this input"
        return (f"task failed: its worker process died each time it ran {what} (KilledWorker; out of memory or a "
                f"crash in native code?)")
    return f"task failed: {describe(exc)}"


@contextlib.contextmanager
def progress_bar(total: int, desc: str, enabled: bool):
    """A tqdm bar of ``total`` items labelled ``desc`` (silent unless ``enabled``), closed on exit."""
    from tqdm import tqdm

    bar = tqdm(total=total, desc=desc, unit="item", disable=not enabled, dynamic_ncols=True)
    try:
        yield bar
    finally:
        bar.close()
