"""Scaling of retargeting with the number of frames: time and peak memory per method and strategy.

Protocol (seeded): a synthetic smooth actor sequence of ``T`` frames of ``p``
markers (four expressions, sinusoids of 0.2-1.5 Hz at 30 fps, with random
per-marker directions), a character that is a smooth non-linear function of
it, ``labels`` known character frames evenly spread. Each case (``T``, method)
is fitted once. With ``isolate`` (the default of the command) every case runs
in a fresh Python process: the wall time of ``fit``, the peak resident memory
of the process during ``fit`` above its resident memory just before it (all
allocations, native ones included) and a cap on the address space (a case
over it is reported as ``failed``, not run into swap). Without ``isolate`` the
case runs in this process and the peak is the one ``tracemalloc`` sees
(NumPy and Python allocations only).
"""
from __future__ import annotations

import json
import subprocess
import sys
import time

import numpy as np

from facegeom.bench.report import Report, format_table, machine_note
from facegeom.registry import MethodSpec

__all__ = ["synthetic_take", "measure", "run", "summarize", "main", "DEFAULT_METHODS"]

DEFAULT_METHODS = (
    "tangent",
    "tangent-exact=tangent:beta=None,ridge=0.0001,source_smoothing=0",
    "tangent-marker=tangent:strategy=marker",
    "tangent-exact-marker=tangent:strategy=marker,beta=None,ridge=0.0001,source_smoothing=0",
    "laplacian",
    "rbf",
    "copy",
)


def synthetic_take(T: int, p: int = 80, labels: int = 10, seed: int = 0):
    """A smooth actor sequence, a character derived from it and evenly spread labelled frames.

    Parameters
    ----------
    T : int
        Frames (at 30 fps).
    p : int
        Markers per frame.
    labels : int
        Labelled frames, evenly spread (``round(linspace(0, T-1, labels))``).
    seed : int
        Seed of the expressions, directions and rest shape.

    Returns
    -------
    source : (T, p, 3) float64
        The actor's markers.
    frames : (L,) int64
        The labelled frames.
    target_labels : (L, p, 3) float64
        The character's markers on those frames.
    """
    from facegeom.methods.tangent_retarget import evenly_spread

    rng = np.random.default_rng(seed)
    t = np.arange(T) / 30.0
    freq, phase = rng.uniform(0.2, 1.5, 4), rng.uniform(0, 1, 4)
    curves = np.sin(2 * np.pi * (freq[None] * t[:, None] + phase[None]))  # (T, 4)
    dirs = rng.normal(size=(4, p, 3)) * 0.3
    rest = rng.normal(size=(p, 3)) * 3
    source = rest[None] + np.einsum("te,epi->tpi", curves, dirs)
    frames = evenly_spread(T, labels)
    X = source[frames]
    target = 1.2 * X + 0.5 + 0.1 * np.sin(X) * X
    return source, frames, target


def _rss_bytes() -> int:
    """Current resident memory of this process (Linux ``/proc/self/statm``; 0 elsewhere)."""
    try:
        import os

        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


def measure(spec_text: str, T: int, p: int = 80, labels: int = 10, seed: int = 0, traced: bool = True) -> dict:
    """Fit one retargeter once on :func:`synthetic_take` in this process; time and peak memory.

    Parameters
    ----------
    spec_text : str
        A retargeter spec (``[label=]name[:k=v,...]``).
    T, p, labels, seed : int
        The take (see :func:`synthetic_take`).
    traced : bool
        Peak memory from ``tracemalloc`` (NumPy and Python allocations; slows
        pure-Python loops); otherwise from the process's peak resident memory
        (``ru_maxrss``) above the resident memory before ``fit``.

    Returns
    -------
    dict
        ``seconds`` (wall time of ``fit``), ``peak_mb`` and ``memory`` (how it was measured).
    """
    import resource
    import tracemalloc

    from facegeom.registry import parse_method

    source, frames, target = synthetic_take(T, p, labels, seed)
    method = parse_method(spec_text).build("retargeters")
    if traced:
        tracemalloc.start()
        tracemalloc.reset_peak()
    before = _rss_bytes()
    t0 = time.perf_counter()
    method.fit(source, frames, target)
    seconds = time.perf_counter() - t0
    if traced:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        how = "tracemalloc"
    else:
        peak = max(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 - before, 0)
        how = "ru_maxrss"
    return {"seconds": seconds, "peak_mb": peak / 2**20, "memory": how}


_CHILD = """
import json, resource, sys
cap = int(sys.argv[6])
if cap > 0:
    resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
from facegeom.bench.retarget_scaling import measure
try:
    out = measure(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5]), traced=False)
    out["status"] = "ok"
except MemoryError:
    out = {"status": "failed: out of memory"}
except Exception as exc:
    out = {"status": "failed: " + type(exc).__name__ + ": " + str(exc)[:200]}
print("RESULT " + json.dumps(out))
"""


def _isolated(spec_text: str, T: int, p: int, labels: int, seed: int, timeout: float, mem_gb: float) -> dict:
    """:func:`measure` in a fresh Python process (address space capped at ``mem_gb``, killed after ``timeout`` s)."""
    cap = int(mem_gb * 2**30) if mem_gb > 0 else 0
    try:
        proc = subprocess.run([sys.executable, "-c", _CHILD, spec_text, str(T), str(p), str(labels), str(seed),
                               str(cap)], capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"status": f"failed: over {timeout:g} s", "seconds": float("nan"), "peak_mb": float("nan")}
    line = next((x for x in proc.stdout.splitlines()[::-1] if x.startswith("RESULT ")), None)
    if line is None:
        tail = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        return {"status": f"failed: {tail[:200]}", "seconds": float("nan"), "peak_mb": float("nan")}
    out = json.loads(line[len("RESULT "):])
    out.setdefault("seconds", float("nan"))
    out.setdefault("peak_mb", float("nan"))
    return out


def run(specs: list[MethodSpec], frames=(100, 1000, 10000, 100000), p: int = 80, labels: int = 10, seed: int = 0,
        isolate: bool = True, timeout: float = 600.0, mem_gb: float = 16.0, echo=print) -> list[dict]:
    """Measure every method at every sequence length.

    Parameters
    ----------
    specs : list of MethodSpec
        The retargeters.
    frames : sequence of int
        Sequence lengths ``T``.
    p, labels, seed : int
        Markers, labelled frames and seed of :func:`synthetic_take`.
    isolate : bool
        One fresh process per case (peak resident memory, a time and memory cap);
        otherwise in this process with ``tracemalloc``.
    timeout : float
        Seconds before an isolated case is stopped (reported as failed).
    mem_gb : float
        Address-space cap of an isolated case, GiB (0: none).
    echo : callable(str)
        Receives one line per case.

    Returns
    -------
    list of dict
        One row per length and method: ``frames``, ``markers``, ``method``,
        ``spec``, ``seconds``, ``peak_mb``, ``memory`` and ``status``.
    """
    rows = []
    for T in frames:
        for spec in specs:
            text = _spec_text(spec)
            if isolate:
                res = _isolated(text, int(T), p, labels, seed, timeout, mem_gb)
            else:
                res = dict(measure(text, int(T), p, labels, seed, traced=True), status="ok")
            row = {"frames": int(T), "markers": p, "method": spec.label, "spec": text,
                   "seconds": float(res["seconds"]), "peak_mb": float(res["peak_mb"]),
                   "memory": res.get("memory", "ru_maxrss" if isolate else "tracemalloc"), "status": res["status"]}
            rows.append(row)
            echo(f"  T={T:>7} {spec.label:<22} {row['seconds']:9.3f} s  peak {row['peak_mb']:10.1f} MB  {row['status']}")
    return rows


def _spec_text(spec: MethodSpec) -> str:
    """``name:k=v,...`` of a spec (the label dropped)."""
    if not spec.params:
        return spec.name
    return spec.name + ":" + ",".join(f"{k}={v}" for k, v in spec.params.items())


def summarize(rows: list[dict]) -> str:
    """The Markdown table of :func:`run`'s rows (one line per case).

    Parameters
    ----------
    rows : list of dict
        From :func:`run`.

    Returns
    -------
    str
        Columns frames, method, seconds, peak MB, status.
    """
    return format_table(["frames", "method", "seconds", "peak MB", "status"],
                        [[r["frames"], r["method"], r["seconds"], r["peak_mb"], r["status"]] for r in rows])


def main(specs: list[MethodSpec], frames, out, p: int = 80, labels: int = 10, seed: int = 0, isolate: bool = True,
         timeout: float = 600.0, mem_gb: float = 16.0, echo=print) -> list[dict]:
    """Run :func:`run` and write ``retarget-scaling.csv`` and ``retarget-scaling-summary.md`` into ``out``.

    Parameters
    ----------
    specs, frames, p, labels, seed, isolate, timeout, mem_gb
        As in :func:`run`.
    out : path-like or None
        Output folder (``None``: only echo the table).
    echo : callable(str)
        Receives progress lines and the summary.

    Returns
    -------
    list of dict
        The rows of :func:`run`.
    """
    rows = run(specs, frames, p, labels, seed, isolate, timeout, mem_gb, echo)
    report = Report(out, "retarget-scaling", echo)
    report.csv(rows)
    how = "peak resident memory above the pre-fit level, one process per case" if isolate else "tracemalloc peak"
    report.summary(summarize(rows), f"{p} markers, {labels} labelled frames evenly spread, seed {seed}; "
                                    f"one fit per case; memory: {how}; {machine_note()}")
    report.done()
    return rows
