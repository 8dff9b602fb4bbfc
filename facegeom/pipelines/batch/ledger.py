"""The output folder's records: manifest, summary, resume, stale temporary files.

The manifest (``batch-job.json``) records what the folder was made with; a
rerun with other settings is refused unless ``overwrite``. The summary
(``batch-summary.csv``) has a row per input; a rerun keeps the metrics and
times of the outputs it skips.
"""
from __future__ import annotations

import contextlib
import csv
import json
import math
import os
from pathlib import Path

from facegeom.errors import InputError
from facegeom.pipelines.batch.job import Job, job_error
from facegeom.pipelines.batch.tasks import make_row

__all__ = ["SUMMARY_NAME", "MANIFEST_NAME", "SUMMARY_COLUMNS", "read_summary", "write_summary", "write_manifest",
           "remove_outputs", "remove_stale_temporaries", "finish_rows", "make_output_folders"]

SUMMARY_NAME = "batch-summary.csv"
MANIFEST_NAME = "batch-job.json"
SUMMARY_COLUMNS = ("input", "output", "status", "message", "time_s", "worker")


def read_summary(path: Path) -> dict:
    """The rows of an earlier summary by their ``input`` column; empty when there is none or it is unreadable.

    Parameters
    ----------
    path : Path

    Returns
    -------
    dict of str to dict
    """
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


def write_summary(path: Path, rows: list[dict]) -> None:
    """Write the summary CSV atomically: :data:`SUMMARY_COLUMNS`, then every metric column in order of appearance.

    Parameters
    ----------
    path : Path
    rows : list of dict
        One row per input (keys starting with ``_`` and ``index`` are not written).
    """
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


def write_manifest(job: Job, spec: dict, overwrite: bool) -> None:
    """Record the job's settings in the output folder; refuse a folder made by another job.

    Parameters
    ----------
    job : Job
    spec : dict
        The task spec (its ``config`` hash and settings).
    overwrite : bool
        Replace another job's manifest instead of refusing.

    Raises
    ------
    InputError
        The folder holds the results of a job with other settings.
    """
    from facegeom.io import atomic_path
    from facegeom.version import __version__

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


def make_output_folders(job: Job, items: list[dict]) -> None:
    """Create the output folder and every subfolder the items write into (before any task runs).

    Outputs mirror their inputs' paths relative to the inputs' common folder
    (inputs ``a/x.csv`` and ``b/y.csv`` write ``OUT/a/x.json`` and
    ``OUT/b/y.json``), so same-named inputs of different folders never collide.

    Parameters
    ----------
    job : Job
    items : list of dict
        The planned items (their ``outputs``).

    Raises
    ------
    InputError
        A folder cannot be created (a file is in the way, no permission), naming the job.
    """
    folders = {job.output} | {Path(o).parent for it in items for o in it["outputs"]}
    for folder in sorted(folders, key=lambda f: len(f.parts)):
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except FileExistsError:
            raise job_error(job.source, f"output folder {folder}: a file of that name is in the way") from None
        except OSError as exc:
            raise job_error(job.source, f"output folder {folder}: cannot create it ({exc.strerror or exc})") from None


def remove_outputs(items: list[dict], summary: Path) -> None:
    """Delete the outputs of every item and the summary (a run with ``overwrite``).

    Parameters
    ----------
    items : list of dict
        The planned items (their ``outputs``).
    summary : Path
        The summary CSV.
    """
    for it in items:
        for o in it["outputs"]:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(o)
    with contextlib.suppress(FileNotFoundError):
        os.unlink(summary)


def remove_stale_temporaries(items: list[dict]) -> int:
    """Delete the temporary files of this job's outputs (``.STEM.*.tmp.EXT``, see :func:`facegeom.io.atomic_path`).

    A process killed while writing leaves its temporary file behind (the output
    itself is never half-written). Run before any task starts, so none is in use
    by this job.

    Parameters
    ----------
    items : list of dict
        The planned items (their ``outputs``).

    Returns
    -------
    int
        The number of files deleted.
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


def finish_rows(job: Job, items: list[dict], rows: dict, previous: dict) -> list[dict]:
    """The summary rows in input order, with relative paths; a skipped output keeps its earlier metrics.

    Parameters
    ----------
    job : Job
    items : list of dict
        The planned items.
    rows : dict
        Rows by item index (an item without one was ``not run``).
    previous : dict
        The earlier summary (:func:`read_summary`).

    Returns
    -------
    list of dict
    """
    out = []
    for it in items:
        r = dict(rows.get(it["index"]) or make_row(it, "not run", "interrupted before this input ran", None, ""))
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
