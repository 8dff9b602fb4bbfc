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

Output names: an output mirrors its input's path relative to the inputs'
common folder (inputs ``a/x.csv`` and ``b/y.csv`` write ``OUT/a/x.json`` and
``OUT/b/y.json``), so same-named inputs of different folders never collide;
the subfolders are created before any task runs. Files in the output folder
are never inputs: a pattern that matches only files there (the output folder
is an input folder) is refused, naming the folder.

One run per output folder: :func:`run_job` holds an exclusive ``flock`` on
``OUT/.facegeom-batch.lock`` (holding its pid and host) from the manifest check
to the summary, and a second run into the folder is refused at once:
``another batch job (pid N) is writing to OUT``. The kernel releases the lock
when its process ends however it ends, so a lock file left by a killed run is
stale by construction and taken over by the next run
(:mod:`facegeom.pipelines.batch.lock`).

Crash isolation: a native crash (segfault, out-of-memory kill) in one input
kills the process running its chunk. On Dask the scheduler retries the task on
another worker; when the chunk still kills its worker every time (Dask's
``KilledWorker``), its items are resubmitted one task each (at most ``chunk``
extra tasks per such chunk; the items written before the crash are skipped), so
only the crashing input fails. A single input whose worker died is run once more
alone, after every other task: Dask counts a worker's death against every task
queued on it, so an innocent input next to a crashing one can be killed too. The normal path pays nothing for this. Inline,
chunks run in this process and a crash ends the run (outputs written so far are
kept; a rerun resumes) unless ``isolate=True``: then each chunk runs in a
forked child (the shared state is built once in the parent and inherited), and
a chunk whose child dies is rerun one child per item, with the same effect as
on Dask. Use a local cluster (the default engine) or ``isolate`` for inputs
that may crash native code.

Chunks: inputs are sorted and cut into fixed chunks of ``chunk`` items
(``[batch] chunk``, default per operation: 64 landmark files, 16 marker frames,
else 1), independent of the number of workers, so a job gives the same result
files on any cluster and inline. (The vectorised landmark fit estimates the
poses of a chunk together; its coefficients depend on the chunk's other
targets at the 1e-8 level, so a resumed chunk may differ in the last digits
from an uninterrupted run.)
"""
from __future__ import annotations

from facegeom.pipelines.batch.engine import LOCAL_CLUSTER_CONFIG, default_workers, local_cluster
from facegeom.pipelines.batch.job import OPERATIONS, Job, job_from_dict, load_job
from facegeom.pipelines.batch.ledger import MANIFEST_NAME, SUMMARY_NAME
from facegeom.pipelines.batch.operations import OPS as _OPS
from facegeom.pipelines.batch.plan import plan as _plan
from facegeom.pipelines.batch.runner import BatchResult, run_job
from facegeom.pipelines.batch.tasks import _BUILDS, SharedStateError, run_chunk, worker_state

__all__ = ["OPERATIONS", "SUMMARY_NAME", "MANIFEST_NAME", "Job", "BatchResult", "SharedStateError", "load_job",
           "job_from_dict", "run_job", "run_chunk", "worker_state", "default_workers", "local_cluster",
           "LOCAL_CLUSTER_CONFIG", "_OPS", "_BUILDS", "_plan"]
