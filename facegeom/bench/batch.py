"""Throughput of ``facegeom batch`` on Dask against a plain loop in one process.

Three measurements on the real ICT face (inputs generated in a temporary folder,
deleted afterwards; nothing derived from the face data is kept):

1. **SEM landmark fits**: ``--fits`` (10,000) landmark CSVs ``vertex_id,u,v``
   of the 23 fit landmarks of random expressions on the generic face, seen by a
   pinhole camera (focal 1000 px, 640 x 480) turned by a random yaw / pitch, with
   1 px noise; the pose is estimated (the fitter gets the intrinsics only). The
   job fits them with ``sem`` in chunks of 64 (``SEMFitter.fit_many``).
2. **Driving**: ``--frames`` (2,000) frames of the 80-marker ``ict80`` layout
   (marker positions of random sparse expressions), in marker sequences of
   ``--per-file`` (100) frames, driving the tangent deformer fitted once per
   worker on the ICT neutral; one ``.npz`` of driven vertices per sequence.
3. **Scheduler overhead**: ``--noop`` (1,000) tasks that do nothing, submitted
   and gathered; the time per task.

Each job runs twice into fresh folders: ``run_job(inline=True)`` (the same
chunks, one after the other in this process -- the plain loop) and on a local
Dask cluster of ``--workers`` processes x 1 thread. Those times are end to end:
planning, the shared state built by each worker (rig and Gram matrix; the face
model and the fitted deformer), the writes and the summary. The drive job then
runs ``--repeats`` (5) more times each way, alternating, into other folders:
the shared state is cached (per process, by job), so those runs measure the
steady state of a session that drives many takes with one rig (medians). The plain loop runs with one
BLAS thread as the workers do (``--blas-threads 1``, the default: set in this process
through threadpoolctl, and as ``OPENBLAS_NUM_THREADS`` & co. for the cluster's worker
processes, which start after it; ``--blas-threads default`` leaves BLAS alone): a single process that
leaves BLAS multi-threaded is *slower* on this face's small products (the
tangent deformer's ``deform`` takes ~9 ms with 2 BLAS threads against ~1.4 ms
with one), which would flatter Dask. Cluster start-up is timed separately.

Usage::

    facegeom bench batch                  # 10,000 fits, 2,000 frames, 2 workers
    facegeom bench batch --fits 2000 --frames 500 --out bench-out/batch.json
    facegeom bench batch --example data/jobs/out  # inputs for data/jobs/fit-landmarks.toml
"""
from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from facegeom.bench.report import write_json

BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
FOCAL, CX, CY = 1000.0, 320.0, 240.0


# --------------------------------------------------------------------------- inputs


def make_landmark_inputs(model, folder, count: int, seed: int = 0, noise_px: float = 1.0) -> tuple[Path, Path]:
    """``count`` landmark CSVs in ``folder/landmarks`` and their true weights in ``folder/truth`` (JSON).

    Random sparse expressions (2-6 shapes, U(0.2, 1)) of the generic ICT face, the
    23 fit landmarks projected by a camera (focal 1000, 640 x 480) turned by yaw
    U(-25, 25) and pitch U(-15, 15) degrees, plus Gaussian noise of ``noise_px``.
    """
    from facegeom.io import write_weights
    from facegeom.model import FIT_LANDMARKS_23, BlendshapeRig, look_at_camera

    folder = Path(folder)
    lm_dir, truth_dir = folder / "landmarks", folder / "truth"
    lm_dir.mkdir(parents=True, exist_ok=True)
    truth_dir.mkdir(parents=True, exist_ok=True)
    rig = BlendshapeRig.from_face_model(model)
    ids = model.landmarks[list(FIT_LANDMARKS_23)]
    rng = np.random.default_rng([int(seed), 8])
    B = rig.n_shapes
    for k in range(count):
        w = np.zeros(B)
        a = int(rng.integers(2, 7))
        w[rng.choice(B, a, replace=False)] = rng.uniform(0.2, 1.0, a)
        V = rig.evaluate(w)
        cam = look_at_camera(V, focal=FOCAL, image_size=(2 * CX, 2 * CY), yaw=float(rng.uniform(-25, 25)),
                             pitch=float(rng.uniform(-15, 15)))
        uv = cam.project(V[ids]) + rng.normal(size=(ids.size, 2)) * noise_px
        name = f"t{k:05d}"
        (lm_dir / f"{name}.csv").write_text(
            "vertex_id,u,v\n" + "".join(f"{i},{a!r},{b!r}\n" for i, (a, b) in zip(ids.tolist(), uv.tolist())))
        write_weights(truth_dir / f"{name}.json", rig.names, w)
    return lm_dir, truth_dir


def make_drive_inputs(model, folder, frames: int, per_file: int = 100, seed: int = 0) -> Path:
    """``frames`` frames of ``ict80`` marker positions of random sparse expressions, as ``.npz`` sequences.

    Each file holds ``markers (T, 80, 3)`` with the marker vertex ids as
    ``marker_names`` (the layout of the drive job).
    """
    from facegeom.io import write_marker_sequence
    from facegeom.model import layout, random_sparse_expression

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    ids = layout(model, "ict80")
    rng = np.random.default_rng([int(seed), 9])
    D = np.asarray(model.expression_deltas, dtype=np.float64)[:, ids]
    base = model.neutral[ids]
    done, k = 0, 0
    while done < frames:
        T = min(per_file, frames - done)
        P = np.empty((T, ids.size, 3))
        for t in range(T):
            w = model.expression_vector(random_sparse_expression(model.expression_names, rng))
            P[t] = base + np.tensordot(w, D, axes=1)
        write_marker_sequence(folder / f"seq{k:04d}.npz", P, names=[str(i) for i in ids.tolist()])
        done += T
        k += 1
    return folder


# --------------------------------------------------------------------------- timing


def _timed_job(job, **kw):
    from facegeom.pipelines.batch import run_job

    t = time.perf_counter()
    res = run_job(job, progress=False, **kw)
    dt = time.perf_counter() - t
    c = res.counts
    if c["failed"]:
        raise SystemExit(f"{c['failed']} inputs failed: {res.failed[0]['message']}")
    return dt, res


def _noop(x):
    return x


def bench(model, fits: int, frames: int, per_file: int, workers: int, noop: int, work: Path, echo=print,
          repeats: int = 5) -> dict:
    """Time the fit and drive jobs as a plain loop and on a local Dask cluster, and the scheduler's overhead.

    Parameters
    ----------
    model : FaceModel
        The ICT face.
    fits : int
        Landmark files for the SEM fit job.
    frames, per_file : int
        Marker frames for the drive job, and frames per sequence file.
    workers : int
        Processes of the local cluster (1 thread each).
    noop : int
        No-op tasks for the overhead measurement.
    work : Path
        Folder for the generated inputs and every job's outputs.
    echo : callable(str)
        Prints one line per measurement.
    repeats : int
        Warm drive runs each way (medians reported).

    Returns
    -------
    dict
        Times (s), speed-ups, task counts, per-task overhead (ms) and whether
        both ways drove identical vertices.
    """
    from distributed import Client

    from facegeom.pipelines.batch import job_from_dict, local_cluster

    data = str(Path(model.path))
    out: dict = {"fits": fits, "frames": frames, "workers": workers, "noop_tasks": noop,
                 "blas_threads_plain_loop": os.environ.get("OPENBLAS_NUM_THREADS", "default")}
    echo(f"generating {fits} landmark files and {frames} marker frames in {work} ...")
    t = time.perf_counter()
    lm_dir, truth_dir = make_landmark_inputs(model, work / "fit", fits)
    seq_dir = make_drive_inputs(model, work / "drive", frames, per_file)
    echo(f"  {time.perf_counter() - t:.1f} s")
    fit_job = {"operation": "fit", "method": "sem", "inputs": str(lm_dir), "truth": str(truth_dir / "{stem}.json"),
               "shared": {"focal": FOCAL, "cx": CX, "cy": CY}, "data": data}
    drive_job = {"operation": "drive", "method": "tangent", "inputs": str(seq_dir), "shared": {"markers": "ict80"},
                 "data": data}

    def job(d, name):
        return job_from_dict({**d, "output": str(work / name)}, base=work, source=f"<{name}>")

    # the plain loop: the same chunks in this process
    dt, res = _timed_job(job(fit_job, "fit-inline"), inline=True)
    out["fit_inline_s"] = dt
    out["fit_item_seconds_inline"] = sum(r["time_s"] for r in res.rows)
    out["fit_err_mean_cm"] = float(np.mean([float(r["err_mean"]) for r in res.rows]))
    echo(f"fit, plain loop (one process): {dt:.1f} s = {fits / dt:.0f} fits/s")
    dt, res = _timed_job(job(drive_job, "drive-inline"), inline=True)
    out["drive_inline_s"] = dt
    out["drive_item_seconds_inline"] = sum(r["time_s"] for r in res.rows)
    echo(f"drive, plain loop (one process): {dt:.1f} s = {frames / dt:.0f} frames/s (incl. the deformer fit)")

    t = time.perf_counter()
    cluster = local_cluster(workers)  # as `facegeom batch` makes it
    client = Client(cluster)
    out["cluster_start_s"] = time.perf_counter() - t
    echo(f"local cluster of {workers} workers started in {out['cluster_start_s']:.1f} s")
    try:
        dt, res = _timed_job(job(fit_job, "fit-dask"), client=client)
        out["fit_dask_s"] = dt
        out["fit_tasks"] = res.tasks
        # the work inside the items, summed over both workers: how much two processes slow each other down
        out["fit_item_seconds_dask"] = sum(r["time_s"] for r in res.rows)
        echo(f"fit, Dask {workers} workers: {dt:.1f} s = {fits / dt:.0f} fits/s ({res.tasks} tasks of {res.chunk}); "
             f"speed-up {out['fit_inline_s'] / dt:.2f}x")
        dt, res = _timed_job(job(drive_job, "drive-dask"), client=client)
        out["drive_dask_s"] = dt
        out["drive_tasks"] = res.tasks
        out["drive_item_seconds_dask"] = sum(r["time_s"] for r in res.rows)
        echo(f"drive, Dask {workers} workers: {dt:.1f} s = {frames / dt:.0f} frames/s ({res.tasks} tasks); "
             f"speed-up {out['drive_inline_s'] / dt:.2f}x")
        # steady state: the deformer is fitted (in this process and on each worker); runs alternate, medians
        warm = {"inline": [], "dask": []}
        for r in range(repeats):
            warm["inline"].append(_timed_job(job(drive_job, f"drive-inline-warm{r}"), inline=True)[0])
            warm["dask"].append(_timed_job(job(drive_job, f"drive-dask-warm{r}"), client=client)[0])
        out["drive_inline_warm_s"] = float(np.median(warm["inline"]))
        out["drive_dask_warm_s"] = float(np.median(warm["dask"]))
        out["drive_warm_runs_s"] = warm
        echo(f"drive again x{repeats}, deformer already fitted (medians): plain loop {out['drive_inline_warm_s']:.2f} s, "
             f"Dask {out['drive_dask_warm_s']:.2f} s = {frames / out['drive_dask_warm_s']:.0f} frames/s; speed-up "
             f"{out['drive_inline_warm_s'] / out['drive_dask_warm_s']:.2f}x")
        same = all(np.array_equal(np.load(work / "drive-inline" / f.name)["vertices"], np.load(f)["vertices"])
                   for f in sorted((work / "drive-dask").glob("*.npz")))
        out["drive_outputs_identical"] = bool(same)
        client.gather(client.map(_noop, range(100), pure=False))  # warm up
        t = time.perf_counter()
        client.gather(client.map(_noop, range(noop), pure=False))
        out["noop_per_task_ms"] = (time.perf_counter() - t) / noop * 1e3
        echo(f"scheduler overhead: {noop} no-op tasks in {out['noop_per_task_ms'] * noop / 1e3:.2f} s = "
             f"{out['noop_per_task_ms']:.2f} ms per task")
    finally:
        client.close()
        cluster.close()
    out["fit_speedup"] = out["fit_inline_s"] / out["fit_dask_s"]
    out["drive_speedup"] = out["drive_inline_s"] / out["drive_dask_s"]
    out["drive_warm_speedup"] = out["drive_inline_warm_s"] / out["drive_dask_warm_s"]
    return out


@contextlib.contextmanager
def blas_threads(n: str):
    """Run the block with ``n`` BLAS threads in this process and in the processes it starts.

    numpy is loaded before a ``facegeom`` subcommand runs, so the environment
    variables alone would come too late for this process: its BLAS pools are
    limited at run time (threadpoolctl); the variables (``OPENBLAS_NUM_THREADS``,
    ``OMP_NUM_THREADS``, ``MKL_NUM_THREADS``) reach the local cluster's worker
    processes, started inside the block. Both are restored afterwards.

    Parameters
    ----------
    n : str
        A positive number of threads, or ``'default'`` (change nothing).
    """
    if n == "default":
        yield
        return
    from threadpoolctl import threadpool_limits

    saved = {var: os.environ.get(var) for var in BLAS_THREAD_VARIABLES}
    os.environ.update({var: str(n) for var in BLAS_THREAD_VARIABLES})
    try:
        with threadpool_limits(limits=int(n), user_api="blas"):
            yield
    finally:
        for var, value in saved.items():
            if value is None:
                os.environ.pop(var, None)
            else:
                os.environ[var] = value


def main(model, fits: int = 10000, frames: int = 2000, per_file: int = 100, workers: int = 2, noop: int = 1000,
         repeats: int = 5, blas: str = "1", work=None, out=None, echo=print) -> dict:
    """``facegeom bench batch``: the three measurements, printed as JSON (and written to ``out``).

    Parameters
    ----------
    model : FaceModel
        The ICT face.
    fits, frames, per_file, workers, noop, repeats : int
        See :func:`bench`.
    blas : str
        BLAS threads of this process (the plain loop), or ``'default'``; see :func:`blas_threads`.
    work : path-like, optional
        Folder for the generated inputs and outputs (default: a temporary folder, deleted at the end).
    out : path-like, optional
        Also write the numbers as JSON here.
    echo : callable(str)

    Returns
    -------
    dict
        The numbers (times in seconds, speed-ups, counts).
    """
    tmp = None
    if work:
        work = Path(work)
        work.mkdir(parents=True, exist_ok=True)
    else:
        tmp = tempfile.mkdtemp(prefix="facegeom-bench-batch-")
        work = Path(tmp)
    try:
        with blas_threads(blas):
            res = bench(model, fits, frames, per_file, workers, noop, work, echo=echo, repeats=repeats)
    finally:
        if tmp:
            shutil.rmtree(tmp, ignore_errors=True)
    echo(json.dumps(res, indent=2))
    if out:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        write_json(out, res)
    return res


def write_example(model, folder, count: int, echo=print) -> None:
    """Inputs for ``data/jobs/fit-landmarks.toml``: ``folder/landmarks/*.csv`` and ``folder/truth/*.json``.

    Parameters
    ----------
    model : FaceModel
    folder : path-like
    count : int
        Landmark files to write (see :func:`make_landmark_inputs`).
    echo : callable(str)
    """
    lm, truth = make_landmark_inputs(model, folder, count)
    echo(f"wrote {count} landmark files to {lm} and their true weights to {truth}")
