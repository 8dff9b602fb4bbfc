"""``facegeom bench production``: the paths a studio runs every day, at production scale, as a user runs them.

Every case runs as its own child process with single-threaded BLAS, so the
interpreter's start-up and the imports count as they do for a user, and the
child's peak resident set is that case's alone. Per case and run: the child's
CPU seconds (user + system, the delta of ``RUSAGE_CHILDREN`` around it), its
wall seconds and its peak resident set (``ru_maxrss`` of that child), all
measured by a small launcher process (:func:`run_child`; a child started from
it inherits a peak of about 12 MB, not this process's); the table reports the
median CPU and wall over the runs and the largest peak.

The cases (targets in :data:`TARGETS`):

``help``
    ``facegeom --help`` and ``facegeom solve --help``.
``solve-gaps``
    A Python child that builds 1,000 frames of the 80 ``ict80`` markers on the
    generic ICT rig (random smooth weights, seeded) with 5 % of the samples
    lost in runs of 5-30 frames, then times
    :func:`~facegeom.methods.marker_solve.solve_markers` on the gap-free and
    the gap sequence (CPU of the solve per 1,000 frames, median of 3 solves;
    mean absolute weight error against the truth).
``solve-cli``
    ``facegeom solve capture.c3d -o curves.csv`` on a 600-frame C3D (millimetres,
    markers named ``v<vertex>``) with 229 lost samples in runs of 5-30 frames.
``rig-route``
    ``facegeom animate --take take.csv --character char.npz -o out.glb``: a
    100,000-frame Live Link Face take on a ~76,000-vertex character (the
    MakeHuman ARKit test rig subdivided twice).
``marker-route``
    ``facegeom animate ... --route markers`` on the first 1,000 frames of the
    same take and character: registration, retargeting, deformer fit and the
    ``.glb``; the route's own time split is parsed from its output.
``marker-route-registered``
    ``marker-route`` again on a head registered before (every take after the
    first onto a character): the registration cache is on (the user cache,
    where any command keeps a head's registration) and an untimed run fills it
    first.
``marker-route-long``
    The same on the whole take (100,000 frames): minutes, so it runs once
    (:data:`LONG_RUNS`) whatever ``repeat`` asks.

Set-up (the character, the take and the capture) is built once into
``OUT/setup`` and reused while its parameters, size and modification time
match (``OUT/setup/manifest.json``); the commands run in that folder. The
children's output goes to ``OUT/logs``.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facegeom.bench.report import Report, format_table, machine_note, write_json
from facegeom.errors import FacegeomError, InputError

__all__ = ["CASES", "TARGETS", "Sizes", "build_character", "main", "run", "run_child", "solve_gaps", "write_take"]

CASES = ("help", "solve-gaps", "solve-cli", "rig-route", "marker-route", "marker-route-registered",
         "marker-route-long")
"""The cases, in the order they run."""

TARGETS = {
    "help": "<= 0.1 s CPU",
    "solve-gaps": "solve <= 0.25 s CPU / 1,000 frames with gaps",
    "solve-cli": "<= 1 s wall",
    "rig-route": "<= 2 s CPU, <= 512 MB",
    "marker-route": "<= 10 s CPU",
    "marker-route-registered": "<= 10 s CPU",
    "marker-route-long": "<= 600 s CPU, <= 4096 MB",
}

LONG_RUNS = 1  # runs of marker-route-long (a run takes minutes; its medians are of one)
"""What each case should meet (the ``target`` column)."""

#: single-threaded BLAS and OpenMP in every child: the numbers of one core, comparable between machines
THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "VECLIB_MAXIMUM_THREADS",
                    "NUMEXPR_NUM_THREADS")

HEAD = Path(__file__).resolve().parents[2] / "tests" / "data" / "heads" / "makehuman_arkit.npz"
"""The default source of the character: the MakeHuman ARKit rig of a source checkout (CC0)."""

CAPTURE_FRAMES, CAPTURE_LOST = 600, 229  # solve-cli: frames of the C3D and samples lost in it


@dataclass(frozen=True)
class Sizes:
    """The sizes of the production cases (the defaults are production scale; tests shrink them).

    Attributes
    ----------
    frames_rig : int
        Frames of the Live Link take the rig route plays.
    frames_markers : int
        Frames of that take the marker route drives (the first ones).
    subdivide : int
        Rounds of midpoint subdivision of the head into the character (2: ~76,000 vertices).
    timeout : float
        Seconds before a child is stopped (the case then fails its check).
    """

    frames_rig: int = 100_000
    frames_markers: int = 1000
    subdivide: int = 2
    timeout: float = 1800.0


# ----------------------------------------------------------------------------- children


def child_env(data: str | None = None, code: str | None = None) -> dict:
    """The environment of a child: this one with single-threaded BLAS, the registration cache off (a head registered
    by an earlier run would make the marker route's registration free: the first run on a head is what is timed),
    ``FACEGEOM_DATA`` when ``data`` is given, and the ``facegeom`` package of the checkout ``code`` first on the
    path when it is given (another version's commands, timed beside these: ``git worktree add DIR COMMIT``)."""
    from facegeom.methods.registration_cache import ENV_VAR

    env = dict(os.environ, **{k: "1" for k in THREAD_VARIABLES}, **{ENV_VAR: "off"})
    if data is not None:
        env["FACEGEOM_DATA"] = str(data)
    if code is not None:
        env["PYTHONPATH"] = os.pathsep.join([str(Path(code).resolve()), *filter(None, [env.get("PYTHONPATH")])])
    return env


def facegeom_command() -> list[str]:
    """How a user starts facegeom here: the ``facegeom`` script beside this interpreter, else ``python -m facegeom``."""
    script = Path(sys.executable).with_name("facegeom")
    if script.is_file() and os.access(script, os.X_OK):
        return [str(script)]
    return [sys.executable, "-m", "facegeom"]


# The measuring parent of every case: a small Python process that starts the command and waits for it. Linux
# hands a child the peak resident set of the process it was started from (exec keeps the larger of the old and
# the new peak), so a command started straight from this process, which holds the face model and the set-up,
# would report this process's peak; from the launcher it inherits a few megabytes, below any command's own peak.
_LAUNCHER = """
import json, os, resource, subprocess, sys, threading, time
result, timeout, argv = sys.argv[1], float(sys.argv[2]), sys.argv[3:]
killed = threading.Event()
before = resource.getrusage(resource.RUSAGE_CHILDREN)
t0 = time.perf_counter()
proc = subprocess.Popen(argv)
def stop():
    killed.set()
    proc.kill()
timer = threading.Timer(timeout, stop)
timer.start()
_, status, usage = os.wait4(proc.pid, 0)
timer.cancel()
wall = time.perf_counter() - t0
after = resource.getrusage(resource.RUSAGE_CHILDREN)
with open(result, "w") as fh:
    json.dump({"cpu_s": after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime, "wall_s": wall,
               "maxrss": usage.ru_maxrss, "returncode": os.waitstatus_to_exitcode(status),
               "timed_out": killed.is_set()}, fh)
"""


def run_child(argv: list[str], cwd: str | os.PathLike, env: dict, log: str | os.PathLike,
              timeout: float = 1800.0) -> dict:
    """Run one command as a child process to its end: its CPU, wall time, peak resident set and output.

    The command is started by a small launcher process that measures it (see
    ``_LAUNCHER``): the child's numbers are its own, not those of the process
    running the benchmark.

    Parameters
    ----------
    argv : list of str
        The command.
    cwd : path-like
        Its working folder.
    env : dict
        Its environment (see :func:`child_env`).
    log : path-like
        File receiving its standard output and error.
    timeout : float
        Seconds after which it is killed.

    Returns
    -------
    dict
        ``cpu_s`` (user + system seconds: the change of the launcher's
        ``RUSAGE_CHILDREN`` across the run, so processes the command starts
        count too), ``wall_s`` (from its start to its end), ``rss_mb`` (its
        peak resident set, ``ru_maxrss`` from ``wait4``), ``returncode``,
        ``timed_out`` and ``output`` (the log's text).

    Raises
    ------
    FacegeomError
        The system has no ``wait4`` (the measurement needs POSIX), or the launcher failed.
    """
    import tempfile

    if not hasattr(os, "wait4"):
        raise FacegeomError("bench production measures children with wait4, which this system does not have")
    fd, result = tempfile.mkstemp(suffix=".json", prefix="facegeom-bench-")
    os.close(fd)
    try:
        with open(log, "wb") as fh:
            launcher = subprocess.run([sys.executable, "-c", _LAUNCHER, result, str(timeout), *argv], check=False,
                                      cwd=cwd, env=env, stdout=fh, stderr=subprocess.STDOUT, timeout=timeout + 60)
        try:
            res = json.loads(Path(result).read_text())
        except ValueError:
            raise FacegeomError(f"the measuring launcher failed (exit {launcher.returncode}); see {log}") from None
    finally:
        os.unlink(result)
    rss = res.pop("maxrss") / (2 ** 20 if sys.platform == "darwin" else 2 ** 10)  # bytes on macOS, kB elsewhere
    return {**res, "rss_mb": float(rss), "output": Path(log).read_text(errors="replace")}


# ----------------------------------------------------------------------------- the solve protocol


def _smooth_weights(T: int, K: int, share: float, rng) -> np.ndarray:
    """``(T, K)`` random smooth weights at 60 fps: clipped sines, about ``share`` of the shapes active."""
    t = np.arange(T) / 60
    return (np.clip(0.5 + 0.5 * np.sin(t[:, None] * rng.uniform(0.5, 3, K) + rng.uniform(0, 6, K)), 0, 1)
            * (rng.random(K) < share))


def _lose_runs(X: np.ndarray, samples: int, rng) -> np.ndarray:
    """``X (T, p, 3)`` with at least ``samples`` marker samples set to NaN, in runs of 5-30 frames (in place)."""
    T, p = X.shape[:2]
    done = 0
    while done < samples:
        j, a, n = rng.integers(p), rng.integers(T), int(rng.integers(5, 31))
        done += int((~np.isnan(X[a:a + n, j, 0])).sum())  # a run over samples already lost adds only the new ones
        X[a:a + n, j] = np.nan
    return X


def solve_gaps(frames: int = 1000, share: float = 0.05, runs: int = 3) -> dict:
    """Time the marker solve on ``frames`` frames of the ``ict80`` markers, without and with lost samples.

    The generic ICT rig, random smooth weights (seed 0, about 40 % of the
    shapes active), head motion and 0.1 mm noise as in
    :func:`facegeom.bench.solve.make_sequence`; then ``share`` of the samples
    lost in runs of 5-30 frames (same generator).

    Parameters
    ----------
    frames : int
        Frames of the sequence.
    share : float
        Share of the marker samples lost.
    runs : int
        Solves timed per sequence (the median is reported).

    Returns
    -------
    dict
        ``frames``, ``lost_share``, and per sequence (``gap-free``, ``gaps``)
        ``cpu_s_per_1000`` (process CPU of the solve, scaled to 1,000 frames)
        and ``weight_error`` (mean absolute weight error against the truth).
    """
    from facegeom.bench.solve import make_sequence
    from facegeom.methods.marker_solve import solve_markers
    from facegeom.model import BlendshapeRig, load_face_model
    from facegeom.model.layouts import layout

    model = load_face_model(None)
    rig = BlendshapeRig.from_face_model(model)
    ids = layout(model, "ict80")
    rng = np.random.default_rng(0)
    W = _smooth_weights(frames, rig.n_shapes, 0.4, rng)
    X, _, _ = make_sequence(rig, ids, W, 0.01, 0.0, rng)
    Xg = _lose_runs(X.copy(), int(share * frames * len(ids)), rng)
    out = {"frames": frames, "lost_share": float(np.isnan(Xg[..., 0]).mean())}
    for name, Xi in (("gap-free", X), ("gaps", Xg)):
        times = []
        for _ in range(runs):
            c0 = time.process_time()
            s = solve_markers(Xi, ids, rig)
            times.append(time.process_time() - c0)
        out[name] = {"cpu_s_per_1000": float(np.median(times)) * 1000 / frames,
                     "weight_error": float(np.abs(s.weights - W).mean())}
    return out


def _solve_child() -> str:
    """The solve-gaps child's program: the protocol's own functions written out (not imported from this module), so
    that it runs with the facegeom package of another checkout (``--code``), where only the solver is its own."""
    import inspect

    return "\n".join(["import json, sys, time", "import numpy as np",
                      *(inspect.getsource(f) for f in (_smooth_weights, _lose_runs, solve_gaps)),
                      'print("RESULT " + json.dumps(solve_gaps(int(sys.argv[1]))))'])


def write_capture(model, path: Path, truth: Path) -> None:
    """The solve-cli capture: 600 frames of the ``ict80`` markers in mm (``v<id>``), 229 samples lost in runs.

    Seed 1, about 30 % of the shapes active; the true weights go to ``truth`` (``.npy``).
    """
    from facegeom.bench.solve import make_sequence
    from facegeom.io.c3d import write_c3d
    from facegeom.model import BlendshapeRig
    from facegeom.model.layouts import layout

    rig = BlendshapeRig.from_face_model(model)
    ids = layout(model, "ict80")
    rng = np.random.default_rng(1)
    W = _smooth_weights(CAPTURE_FRAMES, rig.n_shapes, 0.3, rng)
    X, _, _ = make_sequence(rig, ids, W, 0.01, 0.0, rng)
    _lose_runs(X, CAPTURE_LOST, rng)
    write_c3d(path, X * 10.0, [f"v{i}" for i in ids], fps=60.0, unit="mm")  # the rig is in cm
    np.save(truth, W)


# ----------------------------------------------------------------------------- the character and the take


def write_take(path: str | os.PathLike, frames: int) -> Path:
    """A synthetic Live Link Face take: 52 smooth weight curves in [0, 1] and the head turning, at 60 fps.

    Parameters
    ----------
    path : path-like
        The ``.csv`` to write.
    frames : int
        Rows.

    Returns
    -------
    Path
        ``path``.
    """
    from facegeom.io.takes import ARKIT_NAMES, write_livelink_csv

    t = np.arange(frames) / 60.0
    k = np.arange(len(ARKIT_NAMES))
    W = 0.5 + 0.5 * np.sin(t[:, None] * (0.3 + 0.05 * k) + k)
    R = np.zeros((frames, 9))
    R[:, 0], R[:, 1], R[:, 2] = 0.25 * np.sin(0.7 * t), 0.1 * np.sin(1.3 * t + 1.0), 0.05 * np.sin(0.4 * t)
    return write_livelink_csv(path, W, ARKIT_NAMES, 60.0, start=3600.0, rotations=R)


def build_character(head: str | os.PathLike, path: str | os.PathLike, subdivide: int) -> int:
    """A large character: a rig ``.npz`` subdivided ``subdivide`` times (libigl's midpoint ``upsample``).

    The shapes' deltas ride along as extra coordinates, so every new vertex's
    delta is the mean of its edge's ends, as its position is; the parts of the
    source are dropped (the routes find the pieces of the mesh themselves).

    Parameters
    ----------
    head : path-like
        A rig ``.npz`` (``neutral``, ``deltas``, ``names``, ``triangles``, ``units``, ``up``).
    path : path-like
        The character ``.npz`` to write.
    subdivide : int
        Rounds of subdivision (each about quadruples the triangles).

    Returns
    -------
    int
        Vertices of the character.
    """
    with np.load(head) as z:
        V, F, D = z["neutral"], z["triangles"].astype(np.int64), z["deltas"]
        names, units, up = z["names"], z["units"], z["up"]
    B = D.shape[0]
    X = np.concatenate([V, D.transpose(1, 0, 2).reshape(V.shape[0], -1)], axis=1)
    if subdivide:
        import igl

        for _ in range(subdivide):
            X, F = igl.upsample(X, F)
    V2 = X[:, :3]
    D2 = X[:, 3:].reshape(-1, B, 3).transpose(1, 0, 2)
    with open(path, "wb") as fh:
        np.savez(fh, neutral=V2, deltas=D2, names=names, triangles=F, landmark_ids=np.zeros(0, np.int64),
                 units=units, up=up)
    return int(V2.shape[0])


class SetupCache:
    """The set-up files of ``OUT/setup``, reused while their parameters, size and modification time match.

    Parameters
    ----------
    folder : Path
        The set-up folder (created if missing).
    echo : callable(str)
        Receives a line per file built or reused.
    """

    def __init__(self, folder: Path, echo: Callable[[str], None]):
        self.folder = folder
        self.folder.mkdir(parents=True, exist_ok=True)
        self.manifest = folder / "manifest.json"
        self.echo = echo
        try:
            self.entries = json.loads(self.manifest.read_text())
        except (OSError, ValueError):
            self.entries = {}

    def get(self, name: str, params: dict, build: Callable[[list[Path]], object], extra: tuple[str, ...] = ()) -> Path:
        """``folder/name``, built by ``build([paths])`` unless a file made with ``params`` is still there.

        ``extra`` names further files ``build`` writes beside it (checked the same way).
        """
        paths = [self.folder / n for n in (name, *extra)]
        entry = self.entries.get(name)
        if entry and entry.get("params") == params and all(
                p.is_file() and entry["files"].get(p.name) == _stamp(p) for p in paths):
            self.echo(f"  set-up: reusing {paths[0]}")
            return paths[0]
        t0 = time.perf_counter()
        build(paths)
        self.entries[name] = {"params": params, "files": {p.name: _stamp(p) for p in paths}}
        write_json(self.manifest, self.entries)
        self.echo(f"  set-up: built {paths[0]} ({paths[0].stat().st_size / 2**20:.1f} MB, "
                  f"{time.perf_counter() - t0:.1f} s)")
        return paths[0]


def _stamp(path: Path) -> list[int]:
    """``[size, mtime_ns]`` of a file: what tells a cached set-up file from a changed one."""
    st = path.stat()
    return [st.st_size, st.st_mtime_ns]


# ----------------------------------------------------------------------------- checks of the outputs


_REGISTRATION = re.compile(r"^(rigid fit|identity fit|non-rigid fit):.*\(([\d.]+) s\)\s*$", re.MULTILINE)
_RETARGET = re.compile(r"^retarget ([\d.]+) s, deformer fit ([\d.]+) s", re.MULTILINE)
_GLB = re.compile(r"^wrote \S+ \((\d+) frames driven and stored as (\d+) morph targets in ([\d.]+) s, "
                  r"every vertex within ([\d.]+) mm\)", re.MULTILINE)
_PLAYED = re.compile(r"frames 0\.\.(\d+) \(.*\) on \S+: (\d+) shapes, (\d+) vertices", re.MULTILINE)
_SOLVED = re.compile(r": (\d+) frames x (\d+) markers -> (\d+) shapes in ([\d.]+) s .*?(\d+) lost markers",
                     re.MULTILINE)


def _is_glb(path: Path) -> bool:
    """Whether ``path`` starts as a binary glTF does (the ``glTF`` magic)."""
    try:
        with open(path, "rb") as fh:
            return fh.read(4) == b"glTF"
    except OSError:
        return False


def marker_route_split(output: str) -> dict:
    """The marker route's own time split from ``facegeom animate --route markers``'s output (seconds).

    Keys, where printed: ``rigid fit``, ``identity fit``, ``non-rigid fit``,
    ``retarget``, ``deformer fit``, ``glb write``.
    """
    split = {m.group(1): float(m.group(2)) for m in _REGISTRATION.finditer(output)}
    if m := _RETARGET.search(output):
        split["retarget"], split["deformer fit"] = float(m.group(1)), float(m.group(2))
    if m := _GLB.search(output):
        split["glb write"] = float(m.group(3))
    return split


def _failed(res: dict) -> str | None:
    """Why a child failed (timed out, or the last line of its output), or None."""
    if res["timed_out"]:
        return "failed: timed out"
    if res["returncode"] != 0:
        tail = (res["output"].strip().splitlines() or ["no output"])[-1]
        return f"failed: exit {res['returncode']}: {tail[:200]}"
    return None


# ----------------------------------------------------------------------------- the cases


@dataclass
class _Case:
    """One row of the table: a command run as a child, how to check its result and what it must meet."""

    case: str
    command: str  # as shown in the table
    argv: list[str]
    check: Callable[[dict], tuple[bool, str, dict]]  # child result -> (passed, note, extra numbers)
    met: Callable[[dict], bool]  # the row's medians and extras -> target met
    target: str
    before: Callable[[], None] = lambda: None  # e.g. remove the previous run's output
    runs: int | None = None  # runs whatever ``repeat`` asks (None: ``repeat``)
    env: dict | None = None  # environment variables changed for this case's children
    warm: bool = False  # one untimed run first (e.g. to fill a cache)


def _remove(*paths: Path) -> Callable[[], None]:
    def go():
        for p in paths:
            p.unlink(missing_ok=True)
    return go


def _cases(names, setup: SetupCache, model, sizes: Sizes, head: Path, echo) -> list[_Case]:
    """The runnable cases among ``names`` (building their set-up first)."""
    fg = facegeom_command()
    folder = setup.folder
    out: list[_Case] = []

    if "help" in names:
        def help_check(res):
            ok = "Usage:" in res["output"]
            return ok, "usage printed" if ok else "failed: no usage text", {}

        for args in (["--help"], ["solve", "--help"]):
            out.append(_Case("help", "facegeom " + " ".join(args), fg + args, help_check,
                             lambda r: r["cpu_s"] <= 0.1, TARGETS["help"]))

    if "solve-gaps" in names:
        def gaps_check(res):
            line = next((x for x in res["output"].splitlines()[::-1] if x.startswith("RESULT ")), None)
            if line is None:
                return False, "failed: no result printed", {}
            r = json.loads(line[len("RESULT "):])
            free, gaps = r["gap-free"], r["gaps"]
            # the gaps cost accuracy only where markers are missing: a few percent of the samples
            ok = gaps["weight_error"] <= 1.5 * free["weight_error"] + 0.01
            note = (f"solve CPU per 1,000 frames: gap-free {free['cpu_s_per_1000']:.3f} s, with gaps "
                    f"{gaps['cpu_s_per_1000']:.3f} s; weight error {free['weight_error']:.4f} / "
                    f"{gaps['weight_error']:.4f} ({100 * r['lost_share']:.1f} % of samples lost)")
            return ok, note if ok else "failed: " + note, {"solve_s_per_1000": gaps["cpu_s_per_1000"],
                                                           "weight_error_gaps": gaps["weight_error"],
                                                           "weight_error_free": free["weight_error"]}

        out.append(_Case("solve-gaps", "python -c 'facegeom.bench.production.solve_gaps(1000)'",
                         [sys.executable, "-c", _solve_child(), "1000"], gaps_check,
                         lambda r: r.get("solve_s_per_1000", np.inf) <= 0.25, TARGETS["solve-gaps"]))

    if "solve-cli" in names:
        from facegeom.model import locate_data

        capture = setup.get("capture.c3d", {"frames": CAPTURE_FRAMES, "lost": CAPTURE_LOST, "seed": 1,
                                            "data": str(locate_data(None))},
                            lambda p: write_capture(model, p[0], p[1]), extra=("capture-truth.npy",))
        curves = folder / "curves.csv"

        def solve_check(res):
            from facegeom.io.takes import ict_to_arkit, read_take

            if not curves.is_file():
                return False, "failed: no curves written", {}
            take = read_take(curves)
            truth, _ = ict_to_arkit(np.load(folder / "capture-truth.npy"), model.expression_names)
            if take.n_frames != truth.shape[0]:
                return False, f"failed: {take.n_frames} frames written of {truth.shape[0]}", {}
            err = float(np.abs(take.weights - truth).mean())
            m = _SOLVED.search(res["output"])
            lost = f", {m.group(5)} lost marker samples" if m else ""
            ok = err < 0.05
            note = f"{take.n_frames} frames of curves{lost}; weight error vs truth {err:.4f} (ARKit)"
            return ok, note if ok else "failed: " + note, {"weight_error": err}

        out.append(_Case("solve-cli", f"facegeom solve {capture.name} -o {curves.name}",
                         fg + ["solve", capture.name, "-o", curves.name], solve_check,
                         lambda r: r["wall_s"] <= 1.0, TARGETS["solve-cli"], _remove(curves)))

    if {"rig-route", "marker-route", "marker-route-registered", "marker-route-long"} & set(names):
        take = setup.get("take.csv", {"frames": sizes.frames_rig}, lambda p: write_take(p[0], sizes.frames_rig))
        hs = head.stat()
        character = setup.get("char.npz", {"head": str(head.resolve()), "head_stamp": [hs.st_size, hs.st_mtime_ns],
                                           "subdivide": sizes.subdivide},
                              lambda p: build_character(head, p[0], sizes.subdivide))
        with np.load(character) as z:
            n_vertices = int(z["neutral"].shape[0])
        echo(f"  character: {n_vertices} vertices; take: {sizes.frames_rig} frames")

    if "rig-route" in names:
        glb = folder / "out.glb"

        def rig_check(res):
            m = _PLAYED.search(res["output"])
            if m is None or not _is_glb(glb):
                return False, "failed: no animated .glb", {}
            T, V = int(m.group(1)) + 1, int(m.group(3))
            ok = T == sizes.frames_rig and V == n_vertices
            note = (f"{T} frames on {V} vertices, {m.group(2)} shapes; .glb {glb.stat().st_size / 2**20:.1f} MB")
            return ok, note if ok else "failed: " + note, {}

        out.append(_Case("rig-route", f"facegeom animate --take {take.name} --character {character.name} -o {glb.name}",
                         fg + ["animate", "--take", take.name, "--character", character.name, "-o", glb.name],
                         rig_check, lambda r: r["cpu_s"] <= 2.0 and r["rss_mb"] <= 512, TARGETS["rig-route"],
                         _remove(glb)))

    def marker_case(case, frames, glb, met, runs=None, env=None, warm=False):
        def marker_check(res):
            m = _GLB.search(res["output"])
            if m is None or not _is_glb(glb):
                return False, "failed: no animated .glb", {}
            split = marker_route_split(res["output"])
            if warm:  # the head registered before: its registration read, not computed (its lines are replayed)
                if "registration: reused from the cache" not in res["output"]:
                    return False, "failed: the head was registered again (no cached registration used)", {}
                split = {k: v for k, v in split.items() if not k.endswith(" fit") or k == "deformer fit"}
            got, within = int(m.group(1)), float(m.group(4))
            ok = got == frames and within <= 0.1 + 5e-4  # the writer's tolerance, as printed
            note = (f"{got} frames, every vertex within {within:.3f} mm; "
                    + ", ".join(f"{k} {v:.2f} s" for k, v in split.items()))
            return ok, note if ok else "failed: " + note, {"split_s": split}

        window = ["--frames", str(frames)] if frames < sizes.frames_rig else []
        return _Case(case, " ".join(["facegeom animate --take", take.name, *window, "--character", character.name,
                                     "--route markers -o", glb.name]),
                     fg + ["animate", "--take", take.name, *window, "--character", character.name, "--route",
                           "markers", "-o", glb.name],
                     marker_check, met, TARGETS[case], _remove(glb), runs, env, warm)

    if "marker-route" in names:
        out.append(marker_case("marker-route", sizes.frames_markers, folder / "mr.glb",
                               lambda r: r["cpu_s"] <= 10.0))
    if "marker-route-registered" in names:
        from facegeom.methods.registration_cache import ENV_VAR

        out.append(marker_case("marker-route-registered", sizes.frames_markers, folder / "mr.glb",
                               lambda r: r["cpu_s"] <= 10.0, None, {ENV_VAR: "on"}, True))
    if "marker-route-long" in names:
        out.append(marker_case("marker-route-long", sizes.frames_rig, folder / "mr-long.glb",
                               lambda r: r["cpu_s"] <= 600.0 and r["rss_mb"] <= 4096, LONG_RUNS))
    return out


def parse_cases(text: str) -> tuple[str, ...]:
    """``--cases``: ``all`` or comma-separated names of :data:`CASES` -> the names, in running order.

    Raises
    ------
    InputError
        An unknown name, or none.
    """
    if text.strip().lower() == "all":
        return CASES
    names = [c.strip() for c in text.split(",") if c.strip()]
    bad = [c for c in names if c not in CASES]
    if bad or not names:
        raise InputError(f"--cases: unknown case {bad[0] if bad else 'none given'!r}; choose from {', '.join(CASES)}")
    return tuple(c for c in CASES if c in names)


def _load() -> str:
    """The load averages (1, 5, 15 minutes), or ``n/a`` where the system has none."""
    try:
        return " ".join(f"{x:.2f}" for x in os.getloadavg())
    except (AttributeError, OSError):
        return "n/a"


def run(model, names, out: Path, sizes: Sizes = Sizes(), repeat: int = 3, head: Path = HEAD, data: str | None = None,
        echo: Callable[[str], None] = print, code: str | None = None) -> list[dict]:
    """Run the chosen cases, each ``repeat`` times in its own child; one row per command.

    Parameters
    ----------
    model : FaceModel
        The ICT face model (for the capture's set-up and the solve check).
    names : sequence of str
        Cases (see :data:`CASES`).
    out : Path
        Output folder: ``setup/`` (cached inputs, the commands' working
        folder) and ``logs/`` go in it.
    sizes : Sizes
        Frames, subdivision and the children's timeout.
    repeat : int
        Runs per command (median CPU and wall, largest peak).
    head : Path
        The rig subdivided into the character.
    data : str, optional
        The face data bundle the children use (``$FACEGEOM_DATA``); default theirs.
    echo : callable(str)
        Receives a line as each case starts and ends.
    code : str, optional
        A checkout whose ``facegeom`` package the children run instead of this one (another version).

    Returns
    -------
    list of dict
        ``case``, ``command``, ``cpu_s``, ``wall_s``, ``rss_mb``, ``target``,
        ``met``, ``check`` (``ok`` or ``failed``), ``note``, ``runs`` (every
        run's numbers) and the case's extra numbers.
    """
    setup = SetupCache(out / "setup", echo)
    logs = out / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    env = child_env(data, code)
    rows = []
    for case in _cases(names, setup, model, sizes, Path(head), echo):
        echo(f"{case.case}: {case.command} ...")
        runs, results = [], []
        times = case.runs or repeat
        case_env = env if case.env is None else {**env, **case.env}
        if case.warm:
            case.before()
            warmed = run_child(case.argv, setup.folder, case_env, logs / f"{case.case}-warm-up.log", sizes.timeout)
            echo(f"  warm-up run (not timed): CPU {warmed['cpu_s']:.2f} s")
        for i in range(times):
            case.before()
            slug = re.sub(r"[^a-z0-9]+", "-", case.command.lower()).strip("-")[:60]
            res = run_child(case.argv, setup.folder, case_env, logs / f"{case.case}-{slug}-{i + 1}.log",
                            sizes.timeout)
            failure = _failed(res)
            passed, note, extra = (False, failure, {}) if failure else case.check(res)
            runs.append({**{k: res[k] for k in ("cpu_s", "wall_s", "rss_mb")},
                         **{k: v for k, v in extra.items() if isinstance(v, float)}})  # e.g. the in-child solve
            results.append((passed, note, extra))
            echo(f"  run {i + 1}/{times}: CPU {res['cpu_s']:.2f} s, wall {res['wall_s']:.2f} s, "
                 f"peak {res['rss_mb']:.0f} MB; {note}")
            if failure:
                break  # a broken command fails the same way again
        passed = all(p for p, _, _ in results)
        note = next((n for p, n, _ in results if not p), results[-1][1])
        extra = results[-1][2]
        if "solve_s_per_1000" in extra:  # the in-child solve times: their median over the runs too
            extra["solve_s_per_1000"] = float(np.median([e.get("solve_s_per_1000", np.nan) for _, _, e in results]))
        row = {"case": case.case, "command": case.command,
               "cpu_s": float(np.median([r["cpu_s"] for r in runs])),
               "wall_s": float(np.median([r["wall_s"] for r in runs])),
               "rss_mb": float(max(r["rss_mb"] for r in runs)), "target": case.target, **extra}
        row["met"] = bool(passed and case.met(row))
        row.update(check="ok" if passed else "failed", note=note, runs=runs)
        rows.append(row)
        echo(f"{case.case}: done, CPU {row['cpu_s']:.2f} s, wall {row['wall_s']:.2f} s, peak {row['rss_mb']:.0f} MB; "
             f"target {case.target}: {'met' if row['met'] else 'not met'}; check {row['check']}")
    return rows


def table(rows: list[dict]) -> str:
    """The Markdown table: case, command, CPU s (median), wall s (median), peak RSS MB, target, met?"""
    def target(r):
        if "solve_s_per_1000" in r:
            return f"{r['target']} ({r['solve_s_per_1000']:.3f} s)"
        return r["target"]
    return format_table(["case", "command", "CPU s (median)", "wall s (median)", "peak RSS MB", "target", "met?"],
                        [[r["case"], f"`{r['command']}`", r["cpu_s"], r["wall_s"], r["rss_mb"], target(r),
                          ("yes" if r["met"] else "no") + ("" if r["check"] == "ok" else " (check failed)")]
                         for r in rows])


def main(model, names, out, sizes: Sizes = Sizes(), repeat: int = 3, head: Path = HEAD, data: str | None = None,
         echo: Callable[[str], None] = print, code: str | None = None) -> list[dict]:
    """Run :func:`run` and write ``production.csv``, ``production.json`` and ``production-summary.md`` into ``out``.

    Parameters
    ----------
    model, names, sizes, repeat, head, data, code
        As in :func:`run`.
    out : path-like
        Output folder.
    echo : callable(str)
        Receives the progress lines, the table, the notes and the files written.

    Returns
    -------
    list of dict
        The rows of :func:`run`.
    """
    out = Path(out)
    if {"rig-route", "marker-route", "marker-route-registered", "marker-route-long"} & set(names):
        # before any work: a bad size or head is one line at once
        if sizes.frames_markers > sizes.frames_rig:
            raise InputError(f"the marker route's {sizes.frames_markers} frames exceed the take's {sizes.frames_rig}")
        if not Path(head).is_file():
            raise InputError("no such rig to subdivide into the character", head)
    load_start, started = _load(), time.strftime("%Y-%m-%d %H:%M")
    echo(f"bench production: {', '.join(names)}; {repeat} run(s) each; load average at start {load_start}")
    if code is not None and not (Path(code) / "facegeom" / "__init__.py").is_file():
        raise InputError("not a facegeom checkout (no facegeom/__init__.py in it)", code)
    if code is not None:
        echo(f"the commands run the facegeom package of {code}")
    rows = run(model, names, out, sizes, repeat, head, data, echo, code)
    load_end = _load()
    report = Report(out, "production", echo)
    flat = [{k: (json.dumps(v) if isinstance(v, (dict, list)) else v) for k, v in r.items()} for r in rows]
    keys = list(dict.fromkeys(k for r in flat for k in r))
    report.csv([{k: r.get(k, "") for k in keys} for r in flat])
    meta = {"machine": machine_note(), "started": started, "load_start": load_start, "load_end": load_end,
            "repeat": repeat, "sizes": sizes.__dict__, "blas_threads": 1, "code": code}
    report.written.append(write_json(out / "production.json", {**meta, "rows": rows}))
    notes = "\n".join(f"- {r['case']}, `{r['command']}`: {r['note']}" for r in rows)
    note = (f"Each command a child process with single-threaded BLAS; median of {repeat} run(s) (CPU: user + system "
            f"of the child; peak RSS: the largest of the runs). {sizes.frames_rig:,} take frames on the rig route, "
            f"{sizes.frames_markers:,} on the marker route (the whole take on the long one, {LONG_RUNS} run), the head subdivided {sizes.subdivide} time(s). "
            f"{machine_note()}; load average (1, 5, 15 min) {load_start} at start, {load_end} at the end "
            f"({started}).{f' The commands ran the facegeom package of {code}.' if code else ''}")
    report.summary(table(rows) + "\n\n" + notes, note)
    report.done()
    return rows
