"""Planning a job on the client: find the inputs, resolve the shared inputs, name every output, pick the chunk.

The plan is a *task spec* (a small dict sent with every task: ``operation``,
``method``, ``params``, ``shared`` (resolved by the operation), ``data``,
``format``, ``truth``, ``stamp``, ``config`` (hash of the settings) and ``key``
(hash of the settings and the shared files' versions, the worker-cache key))
and one *item* per input (``index``, ``input``, ``outputs``, ``truth``, ``extra``).
"""
from __future__ import annotations

import glob
import hashlib
import json
import os
from pathlib import Path

from facegeom.pipelines.batch.job import Job, job_error, resolve_template
from facegeom.pipelines.batch.ledger import MANIFEST_NAME, SUMMARY_NAME
from facegeom.pipelines.batch.operations import OPS, Operation

__all__ = ["config_hash", "find_inputs", "plan"]


def config_hash(obj) -> str:
    """SHA-256 (hex) of ``obj`` as canonical JSON (sorted keys; other objects as ``str``)."""
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()


def find_inputs(job: Job) -> list[Path]:
    """The job's input files, resolved and sorted; hidden files and files in the output folder left out.

    Files in the output folder (or below it) are outputs of an earlier run,
    never inputs. A pattern all of whose files lie there (the output folder is
    an input folder, or holds it) is refused rather than silently matching nothing.

    Parameters
    ----------
    job : Job
        Its ``inputs``: folders (files with the operation's suffixes), globs or files.

    Returns
    -------
    list of Path

    Raises
    ------
    InputError
        A named file is missing, a pattern matches only files in the output folder, or nothing matched.
    """
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
                files = [e.path for e in it if os.path.splitext(e.name)[1].lower() in job.schema.suffixes]
        elif glob.has_magic(pattern):
            files = glob.glob(pattern, recursive=True)
        elif os.path.exists(pattern):
            files = [pattern]
        else:
            raise job_error(job.source, f"inputs: {pattern}: file not found")
        kept = in_output = 0
        for f in files:
            f = real(f)
            if os.path.basename(f).startswith(".") or not os.path.isfile(f):
                continue
            if f.startswith(out):
                in_output += 1
                continue
            found.add(f)
            kept += 1
        if in_output and not kept:
            raise job_error(job.source, f"inputs: {pattern}: every file it matches is in the output folder "
                                        f"{job.output}, whose files are taken for outputs, never inputs; choose "
                                        f"an output folder outside the inputs")
    if not found:
        raise job_error(job.source, f"no input matched {', '.join(repr(x) for x in job.inputs)}"
                                    f" (for {job.operation}: {', '.join(job.schema.suffixes)} files)")
    return [Path(f) for f in sorted(found)]


def plan(job: Job) -> tuple[dict, list[dict], int]:
    """Check the job; resolve shared inputs; list the items with their output files; the chunk size.

    Parameters
    ----------
    job : Job

    Returns
    -------
    spec : dict
        The task spec (see the module's docstring).
    items : list of dict
        One per input, in sorted input order.
    chunk : int
        Items per task.

    Raises
    ------
    InputError
        A bad job: no inputs, bad shared inputs or method, clashing outputs.
    """
    op = OPS[job.operation]
    files = find_inputs(job)
    spec = {"operation": job.operation, "method": job.method, "params": job.params, "shared": {},
            "data": None, "format": job.format or job.schema.default_format, "truth": job.truth}
    op.prepare(job, spec, files)
    spec["config"] = config_hash({k: spec[k] for k in ("operation", "method", "params", "shared", "data", "format",
                                                       "truth")})
    spec["key"] = config_hash([spec["config"], spec.get("stamp")])[:16]
    items = _items(job, op, spec, files)
    chunk = job.chunk or op.default_chunk(job, spec, items)
    return spec, items, chunk


def _items(job: Job, op: Operation, spec: dict, files: list[Path]) -> list[dict]:
    """An item per input: its outputs (under the output folder as the input is under the inputs' common folder)."""
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
                raise job_error(job.source, f"inputs {owner[o]} and {f} would both write {o}; rename one")
            if o in inputs:
                raise job_error(job.source, f"the output {o} would overwrite an input; choose another output folder")
            if o in own:
                raise job_error(job.source, f"input {f} would write over the batch's own {SUMMARY_NAME} / "
                                            f"{MANIFEST_NAME}")
            owner[o] = fs
        truth = str(resolve_template(job.base, job.truth, f)) if job.truth else None
        items.append({"index": k, "input": fs, "outputs": outs, "truth": truth, "extra": extra})
    return items
