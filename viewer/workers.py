"""Methods fitted and run in worker processes, so the viewer's frame loop never waits for them.

A thread is not enough: a sparse Cholesky factorization (the laplacian baseline's
~2-5 s fit, tangent's) holds Python's GIL for its whole duration, and the window
would freeze. Each method therefore lives in its own process (one
:class:`MethodWorker` per method label): the window sends it a job (fit a
deformer, deform with marker positions, fit a fitter) and collects the answer
on a later frame with :meth:`MethodWorker.poll`, which never blocks.

A fitted deformer stays in its worker (factorizations cannot be pickled); the
worker answers ``deform`` jobs with the new face. A fitter's result comes back
whole. Workers start from a fork server that has already imported numpy, scipy
and facegeom (Linux), so a worker is ready in a fraction of a second; they are
daemons and end with the viewer.
"""
from __future__ import annotations

import multiprocessing as mp
import sys
import time
import traceback

__all__ = ["MethodWorker", "min_fit_seconds", "worker_context"]

MIN_FIT_ENV = "FACEGEOM_VIEWER_MIN_FIT"
"""``name=seconds[,name=seconds...]``: a deformer named here takes at least that long to fit in its worker.

A stand-in for a slow machine (on a fast one the laplacian fit ends before a
person, or a test, can drag a marker during it); it delays only the worker's
answer, never the window.
"""

_CTX = None


def worker_context():
    """The multiprocessing context workers start from: a preloaded fork server on Linux, spawn elsewhere.

    Never plain fork: the viewer's process holds an OpenGL context and threads.
    """
    global _CTX
    if _CTX is None:
        if sys.platform.startswith("linux"):
            _CTX = mp.get_context("forkserver")
            _CTX.set_forkserver_preload(["numpy", "scipy.sparse", "facegeom.registry", "facegeom.viewer.workers"])
        else:  # pragma: no cover - macOS / Windows
            _CTX = mp.get_context("spawn")
    return _CTX


def min_fit_seconds(name: str, text: str | None = None) -> float:
    """Seconds the fit of deformer ``name`` is stretched to, from :data:`MIN_FIT_ENV` (0 when unset or invalid)."""
    import os

    text = os.environ.get(MIN_FIT_ENV, "") if text is None else text
    for item in text.split(","):
        key, _, value = item.partition("=")
        if key.strip() == name:
            try:
                v = float(value)
            except ValueError:
                return 0.0
            return v if 0.0 < v < 600.0 else 0.0
    return 0.0


def _serve(conn) -> None:
    """The worker's loop: one job at a time, one answer per job, until the pipe closes.

    BLAS runs single-threaded here: several workers fit at once beside the window's
    renderer, and OpenBLAS threads spinning on oversubscribed cores made a 1.5 s
    fit take 30 s (measured with four fitters on two cores).
    """
    from threadpoolctl import threadpool_limits

    from facegeom.errors import FacegeomError

    threadpool_limits(1)

    deformer = None
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError, KeyboardInterrupt):
            return
        if msg is None:
            return
        job, op, args = msg
        t = time.perf_counter()
        try:
            if op == "fit_deformer":
                spec, V, F, H = args
                deformer = None
                d = spec.build("deformers")
                t = time.perf_counter()  # the fit only, not the plugin's import
                d.fit(V, F, H)
                time.sleep(max(0.0, min_fit_seconds(spec.name) - (time.perf_counter() - t)))
                deformer = d
                out = None
            elif op == "deform":
                if deformer is None:
                    raise RuntimeError("the deformer is not fitted")
                out = deformer.deform(args)
            elif op == "fit_fitter":
                spec, rig, target = args
                f = spec.build("fitters")
                t = time.perf_counter()
                out = f.fit(rig, target)
            else:
                raise RuntimeError(f"unknown job {op!r}")
            reply = (job, "ok", out, time.perf_counter() - t)
        except FacegeomError as exc:
            reply = (job, "failed", str(exc), time.perf_counter() - t)
        except Exception as exc:  # noqa: BLE001 - a method's bug is reported in the panel, the worker stays up
            last = traceback.extract_tb(exc.__traceback__)[-1:]
            where = f" ({last[0].filename}:{last[0].lineno})" if last else ""
            reply = (job, "failed", f"{type(exc).__name__}: {exc}{where}", time.perf_counter() - t)
        try:
            conn.send(reply)
        except (BrokenPipeError, OSError):
            return


class MethodWorker:
    """One method's worker process: :meth:`submit` jobs, :meth:`poll` for answers without blocking.

    Answers are ``(job_id, status, payload, seconds)`` with ``status`` ``"ok"`` or
    ``"failed"`` (payload: the message). A worker that died answers every
    outstanding job with ``"failed"``.
    """

    def __init__(self):
        ctx = worker_context()
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_serve, args=(child,), daemon=True, name="facegeom-viewer-worker")
        self._proc.start()
        child.close()
        self._next = 0
        self.outstanding: set[int] = set()

    def submit(self, op: str, args) -> int:
        """Queue job ``op`` (``"fit_deformer"``, ``"deform"``, ``"fit_fitter"``) with ``args``; returns its id."""
        self._next += 1
        job = self._next
        self.outstanding.add(job)
        try:
            self._conn.send((job, op, args))
        except (BrokenPipeError, OSError):
            pass  # reported by poll()
        return job

    def poll(self) -> list[tuple]:
        """Every answer that has arrived (possibly none); never blocks."""
        out = []
        try:
            while self._conn.poll():
                reply = self._conn.recv()
                self.outstanding.discard(reply[0])
                out.append(reply)
        except (EOFError, OSError):
            out += [(job, "failed", "the worker process ended", 0.0) for job in sorted(self.outstanding)]
            self.outstanding.clear()
        return out

    def busy(self) -> bool:
        """Whether a job is still outstanding."""
        return bool(self.outstanding)

    def close(self) -> None:
        """Stop the worker (it finishes nothing outstanding)."""
        try:
            self._conn.send(None)
        except (BrokenPipeError, OSError):
            pass
        self._proc.join(timeout=0.5)
        if self._proc.is_alive():
            self._proc.terminate()
        self._conn.close()
