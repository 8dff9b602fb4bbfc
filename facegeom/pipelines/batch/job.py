"""The job schema: what to run, read from a TOML file or a table and checked before anything runs.

A job names an operation (:data:`OPERATIONS`), its method and parameters, the
inputs shared by every item, the inputs to process, the output folder, an
optional ground-truth path template and the ``[batch]`` settings. What each
operation accepts (its shared keys, formats, input suffixes) is its
:class:`OperationSchema` in :data:`SCHEMAS`.
"""
from __future__ import annotations

import math
import os
import string
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from facegeom.errors import InputError

__all__ = ["OPERATIONS", "JOB_KEYS", "BATCH_KEYS", "OperationSchema", "SCHEMAS", "Job", "job_error", "load_job",
           "job_from_dict", "check_template", "resolve_template"]

OPERATIONS = ("fit", "drive", "retarget", "animate", "clean")
JOB_KEYS = ("operation", "method", "params", "inputs", "output", "shared", "truth", "batch", "data")
BATCH_KEYS = ("chunk", "retries", "format")
MAX_CHUNK = 1_000_000  # inputs per task
MAX_RETRIES = 100  # retries of a task

# kind of a shared value -> (its check, how the error names it)
_KINDS = {
    "str": (lambda v: isinstance(v, str), "a string"),
    "path": (lambda v: isinstance(v, str), "a path (string)"),
    "template": (lambda v: isinstance(v, str), "a path template (string)"),
    "bool": (lambda v: isinstance(v, bool), "true or false"),
    "int": (lambda v: isinstance(v, int) and not isinstance(v, bool), "an integer"),
    "number": (lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v), "a number"),
}


@dataclass(frozen=True)
class OperationSchema:
    """What a job of one operation may hold.

    Attributes
    ----------
    default_method : str
        The method when the job names none.
    shared_keys : dict of str to str
        Shared input name -> kind: ``str``, ``path``, ``template``, ``bool``, ``int`` or ``number``.
    formats : tuple of str
        Output formats allowed in ``[batch] format``.
    default_format : str
        The output format when the job names none (empty: the input's).
    suffixes : tuple of str
        Input file suffixes taken from a folder.
    uses_truth : bool
        Whether the job may give ground truth.
    """

    default_method: str
    shared_keys: dict
    formats: tuple
    default_format: str
    suffixes: tuple
    uses_truth: bool = False


SCHEMAS = {
    "fit": OperationSchema("sem-ls", {"rig": "path", "kind": "str", "focal": "number", "cx": "number", "cy": "number",
                                      "image": "template", "identity": "bool"},
                           ("json", "csv"), "json", (".csv", ".pts", ".obj", ".ply", ".off", ".xyz", ".npy"), True),
    "drive": OperationSchema("tangent", {"mesh": "path", "markers": "str", "input": "str", "fill_gaps": "bool"},
                             ("ply", "obj", "off"), "ply", (".csv", ".npz", ".c3d"), True),
    "retarget": OperationSchema("tangent", {"labels": "template", "fill_gaps": "bool"}, ("npz", "csv"), "npz",
                                (".csv", ".npz", ".c3d"), True),
    "animate": OperationSchema("tangent", {"start": "int", "frames": "int", "labels": "int", "seed": "int",
                                           "deformer": "str"}, ("npz",), "npz", (".csv",)),
    "clean": OperationSchema("clean", {"markers": "template", "drop_lost_markers": "bool", "map": "str"},
                             ("obj", "ply", "off"), "", (".obj", ".ply", ".off")),
}


@dataclass
class Job:
    """What to run; paths are absolute (see :func:`job_from_dict` for the meaning of each field).

    Attributes
    ----------
    operation : str
        One of :data:`OPERATIONS`.
    inputs : list of str
        Folders, globs or files to process.
    output : Path
        The output folder.
    method : str
        The registered method (or ``clean``/``decimate``/``crop``).
    params : dict
        The method's parameters.
    shared : dict
        The operation's shared inputs, as written in the job.
    truth : str or None
        Path template of each input's ground truth.
    chunk : int or None
        Inputs per task (None: the operation's default).
    retries : int
        Retries of a task that raised.
    format : str or None
        Output format (None: the operation's default).
    data : str or None
        The face data bundle.
    source : str
        The job file, named in error messages.
    base : Path
        The folder that relative paths are relative to.
    """

    operation: str
    inputs: list[str]
    output: Path
    method: str | None = None
    params: dict = field(default_factory=dict)
    shared: dict = field(default_factory=dict)
    truth: str | None = None
    chunk: int | None = None
    retries: int = 2
    format: str | None = None
    data: str | None = None
    source: str = "job"  # the job file (named in error messages)
    base: Path = field(default_factory=Path.cwd)  # relative paths are relative to this folder

    @property
    def schema(self) -> OperationSchema:
        """The schema of the job's operation."""
        return SCHEMAS[self.operation]


def job_error(job_source: str, message: str) -> InputError:
    """The error for a bad job: ``message``, naming the job file ``job_source``.

    Parameters
    ----------
    job_source : str
        The job file (or a description such as ``<demo batch job>``).
    message : str
        What is wrong.

    Returns
    -------
    InputError
    """
    return InputError(message, job_source)


def load_job(path: str | os.PathLike, output: str | os.PathLike | None = None, data: str | None = None) -> Job:
    """Read a job file (TOML). Relative paths in it are relative to the file's folder.

    Parameters
    ----------
    path : str or PathLike
        The job file.
    output : str or PathLike, optional
        Replaces the file's ``output`` (e.g. the CLI's ``-o``).
    data : str, optional
        The face data bundle when the file names none (the CLI's ``--data``).

    Returns
    -------
    Job

    Raises
    ------
    InputError
        A missing or unreadable file, invalid TOML, a bad job (:func:`job_from_dict`).
    """
    p = Path(path)
    if not p.exists():
        raise InputError("file not found", p)
    if p.is_dir():
        raise InputError("is a folder, not a job file", p)
    try:
        with open(p, "rb") as fh:
            d = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"not valid TOML: {exc}", p) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read the job file ({exc.__class__.__name__})", p) from None
    if output is not None:
        d["output"] = str(Path(output).resolve())
    if data is not None and "data" not in d:
        d["data"] = str(Path(data).resolve())
    return job_from_dict(d, base=p.resolve().parent, source=str(p))


def job_from_dict(d: dict, base: str | os.PathLike | None = None, source: str = "job") -> Job:
    """Build and check a :class:`Job` from the TOML's table.

    Parameters
    ----------
    d : dict
        Keys: ``operation`` (one of :data:`OPERATIONS`); ``method`` (a
        registered fitter / deformer / retargeter, or
        ``clean``/``decimate``/``crop``; default per operation); ``params``
        (the method's parameters); ``inputs`` (a folder, a glob or a file, or
        a list of them); ``output`` (the output folder); ``shared`` (the
        operation's shared inputs); ``truth`` (a path template of each
        input's ground truth, with ``{stem}``, ``{name}``, ``{parent}``);
        ``[batch]`` ``chunk``, ``retries``, ``format``; ``data`` (face data bundle).
    base : str or PathLike, optional
        The folder relative paths are relative to (default: the working folder).
    source : str
        The job's name in error messages.

    Returns
    -------
    Job
        With absolute paths.

    Raises
    ------
    InputError
        The first problem found, naming ``source``.
    """
    base = Path(base).resolve() if base is not None else Path.cwd()
    d = _plain_table(d, source)
    op_name = d.get("operation")
    if op_name is None:
        raise job_error(source, f"no operation; set operation = one of {', '.join(OPERATIONS)}")
    if op_name not in OPERATIONS:
        raise job_error(source, f"unknown operation {op_name!r}; choose one of {', '.join(OPERATIONS)}")
    schema = SCHEMAS[op_name]
    method = d.get("method", schema.default_method)
    if not isinstance(method, str) or not method:
        raise job_error(source, f"method must be a name, got {method!r}")
    params = d.get("params", {})
    if not isinstance(params, dict):
        raise job_error(source, "params must be a table, e.g. [params] clamp = true")
    shared = _shared(d.get("shared", {}), op_name, source)
    inputs = _inputs(d.get("inputs"), source)
    output = d.get("output")
    if not isinstance(output, str) or not output:
        raise job_error(source, "no output folder; set output = \"folder\" (or pass -o)")
    truth = _truth(d.get("truth"), op_name, source)
    for k, kind in schema.shared_keys.items():
        if kind == "template" and k in shared:
            check_template(shared[k], f"shared.{k}", source)
    chunk, retries, fmt = _batch_table(d.get("batch", {}), op_name, source)
    data = d.get("data")
    if data is not None and not isinstance(data, str):
        raise job_error(source, "data must be a path (string)")

    for what, x in ([("inputs", x) for x in inputs] + [("output", output), ("data", data or ""), ("truth", truth or "")]
                    + [(f"shared.{k}", v) for k, v in shared.items() if isinstance(v, str)]):
        if "\x00" in x:
            raise job_error(source, f"{what} {x!r}: a path cannot hold a NUL character")

    def absolute(x: str) -> str:
        return str(Path(os.path.expanduser(x)) if os.path.isabs(os.path.expanduser(x)) else base / x)

    out = Path(os.path.normpath(absolute(output)))  # o7/../o7b is o7b: no o7 made on the way
    if out.exists() and not out.is_dir():
        raise job_error(source, f"output {out}: is a file; the output is a folder")
    return Job(operation=op_name, inputs=[absolute(x) for x in inputs], output=out,
               method=method, params=dict(params), shared=dict(shared), truth=truth, chunk=chunk, retries=retries,
               format=fmt, data=absolute(data) if data else None, source=source, base=base)


def _plain_table(d, source: str) -> dict:
    """The job's table with path objects as strings; unknown keys refused."""
    if not isinstance(d, dict):
        raise job_error(source, "a job is a table of keys")
    d = {k: (os.fspath(v) if isinstance(v, os.PathLike) else v) for k, v in d.items()}
    if isinstance(d.get("inputs"), (list, tuple)):
        d["inputs"] = [os.fspath(x) if isinstance(x, os.PathLike) else x for x in d["inputs"]]
    unknown = [k for k in d if k not in JOB_KEYS]
    if unknown:
        raise job_error(source, f"unknown key {unknown[0]!r}; a job has {', '.join(JOB_KEYS)}")
    return d


def _shared(shared, op_name: str, source: str) -> dict:
    """The ``[shared]`` table, each key known to the operation and of its kind."""
    if not isinstance(shared, dict):
        raise job_error(source, "shared must be a table, e.g. [shared] rig = \"rig.npz\"")
    keys = SCHEMAS[op_name].shared_keys
    for k, v in shared.items():
        if k not in keys:
            raise job_error(source, f"unknown shared input {k!r} for {op_name}; it takes {', '.join(keys) or 'none'}")
        ok, what = _KINDS[keys[k]]
        if not ok(v):
            raise job_error(source, f"shared.{k} must be {what}, got {v!r}")
    return shared


def _inputs(inputs, source: str) -> list[str]:
    if inputs is None:
        raise job_error(source, "no inputs; set inputs = a folder, a glob or a list of them")
    if isinstance(inputs, str):
        inputs = [inputs]
    if not isinstance(inputs, list) or not inputs or not all(isinstance(x, str) and x for x in inputs):
        raise job_error(source, "inputs must be a folder, a glob, or a list of them (strings)")
    return inputs


def _truth(truth, op_name: str, source: str) -> str | None:
    if truth is None:
        return None
    if not SCHEMAS[op_name].uses_truth:
        raise job_error(source, f"{op_name} takes no ground truth (truth is for fit, drive and retarget)")
    if not isinstance(truth, str):
        raise job_error(source, "truth must be a path template such as \"truth/{stem}.json\"")
    check_template(truth, "truth", source)
    return truth


def _batch_table(b, op_name: str, source: str) -> tuple[int | None, int, str | None]:
    """``(chunk, retries, format)`` from the ``[batch]`` table."""
    if not isinstance(b, dict):
        raise job_error(source, "batch must be a table: [batch] chunk = 64")
    unknown = [k for k in b if k not in BATCH_KEYS]
    if unknown:
        raise job_error(source, f"unknown key batch.{unknown[0]}; [batch] has {', '.join(BATCH_KEYS)}")
    chunk = b.get("chunk")
    if chunk is not None and (not isinstance(chunk, int) or isinstance(chunk, bool) or not 1 <= chunk <= MAX_CHUNK):
        raise job_error(source, f"batch.chunk must be a positive integer (at most {MAX_CHUNK}), got {chunk!r}")
    retries = b.get("retries", 2)
    if not isinstance(retries, int) or isinstance(retries, bool) or not 0 <= retries <= MAX_RETRIES:
        raise job_error(source, f"batch.retries must be a non-negative integer (at most {MAX_RETRIES}), got "
                                f"{retries!r}")
    fmt = b.get("format")
    if fmt is not None:
        fmt = str(fmt).lower().lstrip(".")
        formats = SCHEMAS[op_name].formats
        if fmt not in formats:
            raise job_error(source, f"batch.format {fmt!r} is not one of {', '.join(formats)} for {op_name}")
    return chunk, retries, fmt


def check_template(t: str, what: str, source: str) -> None:
    """Refuse a path template with other fields than ``{stem}``, ``{name}``, ``{parent}``.

    Parameters
    ----------
    t : str
        The template.
    what : str
        Its key in the job (for the message).
    source : str
        The job's name.

    Raises
    ------
    InputError
    """
    fields = ("stem", "name", "parent")
    try:
        parts = list(string.Formatter().parse(t))
    except ValueError as exc:
        raise job_error(source, f"{what} {t!r}: bad template ({exc}); use {{stem}}, {{name}} or {{parent}}") from None
    for _, field_name, spec, conversion in parts:
        if field_name is not None and (field_name not in fields or spec or conversion):
            raise job_error(source, f"{what} {t!r}: bad template (field {{{field_name}"
                                    f"{'!' + conversion if conversion else ''}{':' + spec if spec else ''}}}); use "
                                    f"{{stem}}, {{name}} or {{parent}}")


def resolve_template(job_base: Path, t: str, src: Path) -> Path:
    """The path that template ``t`` gives for input ``src`` (relative to ``job_base`` unless absolute).

    Parameters
    ----------
    job_base : Path
        The job's folder.
    t : str
        A template with ``{stem}``, ``{name}``, ``{parent}`` (of ``src``).
    src : Path
        The input file.

    Returns
    -------
    Path
    """
    p = Path(os.path.expanduser(t.format(stem=src.stem, name=src.name, parent=str(src.parent))))
    return p if p.is_absolute() else job_base / p
