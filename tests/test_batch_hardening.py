"""Batch isolation and limits (issue 16): inputs from several folders, one run per output folder, output folder
= input folder, malformed jobs as one-line errors, a segfaulting input failing only its own row."""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from facegeom.bench.batch import CX, CY, FOCAL, make_landmark_inputs
from facegeom.errors import InputError
from facegeom.pipelines import batch as fb
from facegeom.pipelines.batch.lock import LOCK_NAME

CAMERA = {"focal": FOCAL, "cx": CX, "cy": CY}


@pytest.fixture(scope="module")
def landmarks(tmp_path_factory, face_model):
    d = tmp_path_factory.mktemp("lm")
    make_landmark_inputs(face_model, d, 8, seed=4)
    return d


def job(base: Path, **kw) -> fb.Job:
    d = {"operation": "fit", "inputs": "landmarks", "output": "out", "shared": dict(CAMERA)}
    d.update(kw)
    return fb.job_from_dict(d, base=base, source=str(base / "job.toml"))


# --------------------------------------------------------------------------- 1. inputs from several folders


def test_inputs_from_several_folders_write_mirrored_subfolders(landmarks, tmp_path):
    for sub, names in (("a", ["t00000.csv", "t00001.csv"]), ("b", ["t00002.csv"]), ("b/deep", ["t00003.csv"])):
        (tmp_path / sub).mkdir(parents=True)
        for n in names:
            shutil.copy(landmarks / "landmarks" / n, tmp_path / sub / n)
    shutil.copy(landmarks / "landmarks" / "t00004.csv", tmp_path / "a" / "t00002.csv")  # same name as b/t00002
    res = fb.run_job(job(tmp_path, inputs=["a/*.csv", "b/**/*.csv"]), inline=True, progress=False)
    assert res.counts["ok"] == 5, [r["message"] for r in res.rows]
    assert sorted(r["output"] for r in res.rows) == ["a/t00000.json", "a/t00001.json", "a/t00002.json",
                                                    "b/deep/t00003.json", "b/t00002.json"]
    for r in res.rows:
        assert (tmp_path / "out" / r["output"]).is_file()
    again = fb.run_job(job(tmp_path, inputs=["a/*.csv", "b/**/*.csv"]), inline=True, progress=False)
    assert again.counts["skipped"] == 5


# --------------------------------------------------------------------------- 2. one run per output folder


def test_two_concurrent_runs_into_one_folder(landmarks, tmp_path, monkeypatch):
    op = fb._OPS["fit"]
    started, go = threading.Event(), threading.Event()
    compute = op.compute

    def slow(state, spec, items):
        started.set()
        assert go.wait(60)
        yield from compute(state, spec, items)

    monkeypatch.setattr(op, "compute", slow)
    first: dict = {}
    t = threading.Thread(target=lambda: first.setdefault("res", fb.run_job(job(landmarks, output=str(tmp_path)),
                                                                            inline=True, progress=False)))
    t.start()
    try:
        assert started.wait(60)
        (tmp_path / ".t00003.abc.tmp.json").write_text("{")  # as if the first run were writing it
        with pytest.raises(InputError, match=f"another batch job \\(pid {os.getpid()}\\) is writing to {tmp_path}"):
            fb.run_job(job(landmarks, output=str(tmp_path)), inline=True, progress=False)
        assert (tmp_path / ".t00003.abc.tmp.json").exists()  # the refused run deleted nothing
    finally:
        go.set()
        t.join(120)
    assert first["res"].counts["ok"] == 8
    assert not (tmp_path / LOCK_NAME).exists()  # released and removed at the end


def test_lock_of_another_process_and_its_stale_lock(landmarks, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time\nfrom facegeom.pipelines.batch.lock import output_lock\n"
                               f"with output_lock({str(out)!r}):\n    print('locked', flush=True)\n"
                               "    time.sleep(120)\n"], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(InputError, match=f"another batch job \\(pid {holder.pid}\\) is writing to {out}"):
            fb.run_job(job(landmarks, output=str(out)), inline=True, progress=False)
        assert not (out / fb.MANIFEST_NAME).exists()
    finally:
        holder.send_signal(signal.SIGKILL)  # dies holding the lock: its file stays behind
        holder.wait(30)
    assert (out / LOCK_NAME).is_file()  # a stale lock file, whose kernel lock died with its process
    res = fb.run_job(job(landmarks, output=str(out)), inline=True, progress=False)
    assert res.counts["ok"] == 8 and not (out / LOCK_NAME).exists()


# --------------------------------------------------------------------------- 3. output folder = input folder


@pytest.mark.parametrize("inputs", ["landmarks", "landmarks/*.csv"])
def test_output_folder_that_is_the_input_folder_is_refused(landmarks, tmp_path, inputs):
    shutil.copytree(landmarks / "landmarks", tmp_path / "landmarks")
    with pytest.raises(InputError, match="every file it matches is in the output folder .*landmarks.*choose an "
                                         "output folder outside the inputs") as e:
        fb.run_job(job(tmp_path, inputs=inputs, output="landmarks"), inline=True, progress=False)
    assert str(e.value).startswith(str(tmp_path / "job.toml"))
    assert sorted(p.name for p in (tmp_path / "landmarks").iterdir()) == sorted(
        p.name for p in (landmarks / "landmarks").iterdir())  # nothing written
    # earlier outputs under a glob's root are still left out, silently
    res = fb.run_job(job(tmp_path, inputs="**/*.csv", output="landmarks/out", batch={"format": "csv"}),
                     inline=True, progress=False)
    assert res.counts["ok"] == 8
    again = fb.run_job(job(tmp_path, inputs="**/*.csv", output="landmarks/out", batch={"format": "csv"}),
                       inline=True, progress=False)
    assert again.counts["skipped"] == 8 and len(again.rows) == 8


# --------------------------------------------------------------------------- 5. a native crash in one input


def _segfault_on(name: str):
    """Make ``read_fit_target`` of the input called ``name`` crash this process with SIGSEGV."""
    import facegeom.model as model

    read = model.read_fit_target

    def crashing(path, *a, **kw):
        if os.path.basename(str(path)) == name:
            import faulthandler

            faulthandler.disable()  # a deliberate crash: no "Fatal Python error" dump in the test log
            os.kill(os.getpid(), signal.SIGSEGV)
        return read(path, *a, **kw)

    model.read_fit_target = crashing


def test_segfault_on_dask_fails_only_its_input(landmarks, tmp_path):
    dask = pytest.importorskip("dask")
    distributed = pytest.importorskip("distributed")

    class Crash(distributed.WorkerPlugin):  # local: pickled by value, set up on every (re)started worker
        def setup(self, worker):
            _segfault_on("t00005.csv")

    with dask.config.set({"distributed.scheduler.allowed-failures": 1}):
        cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                           dashboard_address=None,
                                           scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"})
    with cluster, distributed.Client(cluster) as client:
        client.register_plugin(Crash())
        res = fb.run_job(job(landmarks, output=str(tmp_path), batch={"chunk": 4, "retries": 0}), client=client,
                         progress=False)
    rows = {Path(r["input"]).name: r for r in res.rows}
    # a worker that died may have held a finished chunk's result: its rerun skips the outputs it wrote
    assert res.counts["ok"] + res.counts["skipped"] == 7 and res.counts["failed"] == 1, res.failed
    assert "died each time it ran this input" in rows["t00005.csv"]["message"]
    assert all(r["status"] != "failed" for n, r in rows.items() if n != "t00005.csv")
    assert all((tmp_path / f"t{k:05d}.json").is_file() for k in range(8) if k != 5)
    assert not (tmp_path / "t00005.json").exists() and (tmp_path / "t00004.json").is_file()


def test_segfault_inline_isolated_fails_only_its_input(landmarks, tmp_path, monkeypatch):
    import facegeom.model as model

    monkeypatch.setattr(model, "read_fit_target", model.read_fit_target)  # restored after the test
    _segfault_on("t00005.csv")
    res = fb.run_job(job(landmarks, output=str(tmp_path), batch={"chunk": 4}), inline=True, isolate=True,
                     progress=False)
    rows = {Path(r["input"]).name: r for r in res.rows}
    assert res.counts["ok"] == 7 and res.counts["failed"] == 1, [r["message"] for r in res.rows]
    assert "process died while processing this input (SIGSEGV" in rows["t00005.csv"]["message"]
    assert res.engine.startswith("inline") and (tmp_path / "t00004.json").is_file()


def test_cli_isolate_flag(landmarks, tmp_path, monkeypatch):
    """``facegeom batch --inline --isolate``: the crashing input fails alone (exit 1); --isolate needs --inline."""
    from click.testing import CliRunner

    import facegeom.model as model
    from facegeom.cli import cli

    monkeypatch.setattr(model, "read_fit_target", model.read_fit_target)  # restored after the test
    _segfault_on("t00002.csv")
    jf = tmp_path / "job.toml"
    jf.write_text(f'operation = "fit"\ninputs = "{landmarks / "landmarks"}/*.csv"\noutput = "out"\n'
                  f"[batch]\nchunk = 4\n[shared]\nfocal = {FOCAL}\ncx = {CX}\ncy = {CY}\n")
    r = CliRunner().invoke(cli, ["batch", str(jf), "--isolate"])
    assert r.exit_code == 2 and "--isolate applies to --inline runs" in r.output
    r = CliRunner().invoke(cli, ["batch", str(jf), "--inline", "--isolate", "--quiet"])
    assert r.exit_code == 1, r.output
    assert "7 ok, 1 failed" in r.output and "t00002.csv" in r.output and "SIGSEGV" in r.output
    assert len(list((tmp_path / "out").glob("t*.json"))) == 7 and not (tmp_path / "out" / "t00002.json").exists()


# --------------------------------------------------------------------------- 4. malformed jobs


@pytest.mark.parametrize("change, problem", [
    ({"output": "afile"}, "output .*afile: is a file; the output is a folder"),
    ({"params": {"speed": 3}}, "fitter 'sem-ls' has no parameter 'speed'; valid parameters: exclusion, clamp"),
    ({"params": {"alternations": "banana"}}, r"alternations must be an integer in \[0, 100\]"),
    ({"params": {"covered_only": "yes"}}, "covered_only must be true or false, got 'yes'"),
    ({"params": {"region": "banana"}}, "region must be a list of vertex ids"),
    ({"operation": "drive", "params": {"d": "banana"}, "shared": {"markers": "ict80"}}, "d must be 1, 2 or 3 .*got 'banana'"),
    ({"operation": "drive", "params": {"smoothness": [1]}, "shared": {"markers": "ict80"}}, r"smoothness must be a number in \[0, 1e\+06\]"),
    ({"operation": "retarget", "params": {"window": "x"}, "shared": {"labels": "{stem}.csv"}},
     r"window must be an integer in \[1, 1000\]"),
    ({"operation": "retarget", "method": "rbf", "params": {"kernel": "banana"}, "shared": {"labels": "{stem}.csv"}},
     "kernel must be one of"),
    ({"operation": "clean", "inputs": "m", "params": {"largest_component": "x"}, "shared": {}},
     "params.largest_component must be true or false"),
    ({"operation": "clean", "method": "crop", "inputs": "m", "params": {"id_range": "a:b"}, "shared": {}},
     "params.id_range: id range must hold integers"),
    ({"truth": "{stem.upper}"}, "bad template"),
    ({"truth": "{stem:>999999999999}"}, "bad template"),
    ({"output": "a\x00b"}, "cannot hold a NUL character"),
    ({"batch": {"chunk": 2**70}}, "batch.chunk must be a positive integer"),
    ({"batch": {"chunk": -4}}, "batch.chunk must be a positive integer"),
    ({"batch": {"retries": 2**70}}, "batch.retries must be a non-negative integer"),
    ({"shared": {**CAMERA, "focal": -1.0}}, "shared.focal must be a positive number"),
    ({"shared": {**CAMERA, "cx": float("nan")}}, "shared.cx must be a number"),
    ({"inputs": []}, "inputs must be a folder, a glob, or a list of them"),
    ({"inputs": ["lm", 3]}, "inputs must be a folder, a glob, or a list of them"),
    ({"operation": 3}, "unknown operation 3"),
    ({"method": "nope"}, "no fitter named 'nope'"),
])
def test_malformed_job_is_one_line_error_naming_the_file(tmp_path, change, problem):
    (tmp_path / "lm").mkdir()
    (tmp_path / "lm" / "a.csv").write_text("vertex_id,u,v\n1,2,3\n")
    (tmp_path / "m").mkdir()
    (tmp_path / "m" / "a.obj").write_text("v 0 0 0\n")
    (tmp_path / "afile").write_text("not a folder")
    d = {"operation": "fit", "inputs": "lm", "output": "o", "shared": dict(CAMERA), **change}
    with pytest.raises(InputError, match=problem) as e:
        fb.run_job(fb.job_from_dict(d, base=tmp_path, source=str(tmp_path / "job.toml")), inline=True,
                   progress=False)
    assert str(e.value).startswith(str(tmp_path / "job.toml")) and "\n" not in str(e.value)
    assert not (tmp_path / "o").exists()  # refused while planning: nothing written, no worker started


def test_every_method_names_a_mistyped_parameter():
    import inspect

    from facegeom import registry

    problems = []
    for kind in registry.KINDS:
        for name in registry.available(kind):
            try:
                cls = registry.get(kind, name)
            except InputError:  # an optional baseline that is not installed
                continue
            for p in list(inspect.signature(cls.__init__).parameters)[1:]:
                for bad in ("banana", [1], float("nan")):
                    try:
                        registry.create(kind, name, **{p: bad})
                    except InputError as exc:
                        if p not in str(exc):
                            problems.append(f"{kind} {name} {p}={bad!r}: {exc}")
                    except Exception as exc:  # noqa: BLE001
                        problems.append(f"{kind} {name} {p}={bad!r}: {type(exc).__name__}: {exc}")
    assert not problems, "\n".join(problems)


def test_sem_fits_the_neutral_face_as_a_point_cloud(face_model):
    from facegeom.methods.sem import SEMFitter
    from facegeom.model import PointCloudTarget, load_rig

    rig = load_rig(None, lambda: face_model)
    res = SEMFitter().fit(rig, PointCloudTarget(face_model.neutral))  # was KeyError: nothing to select
    assert res.weights.shape == (rig.n_shapes,) and abs(res.weights).max() < 1e-6


# --------------------------------------------------------------------------- 6. limits of the readers


@pytest.mark.parametrize("reader, text, what", [
    ("read_marker_sequence", "frame,marker,x,y,z\n0,a,0,0,0\n99999999999999999999,a,0,0,0\n", "frame"),
    ("read_markers", "vertex_id,x,y,z\n1,0,0,0\n-9223372036854775809,0,0,0\n", "vertex_id"),
    ("read_landmarks", "vertex_id,u,v\n1,0,0\n99999999999999999999,0,0\n", "vertex_id"),
    ("read_vertex_csv", "vertex_id,x,y,z\n1,0,0,0\n9223372036854775808,0,0,0\n", "vertex_id"),
])
def test_readers_refuse_integers_beyond_int64(tmp_path, reader, text, what):
    import facegeom.io as io

    f = tmp_path / "in.csv"
    f.write_text(text)
    args = (f, 10) if reader == "read_vertex_csv" else (f,)
    with pytest.raises(InputError, match=f"^{f}: line 3: {what} .* does not fit a 64-bit integer$"):
        getattr(io, reader)(*args)


def test_sparse_frame_numbers_do_not_allocate_the_gap(tmp_path):
    import resource

    from facegeom.io import read_marker_sequence, read_retarget_inputs

    f = tmp_path / "sparse.csv"
    f.write_text("frame,marker,x,y,z\n0,a,0,0,0\n0,b,1,0,0\n300000000,a,0,1,0\n300000000,b,1,1,0\n")
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    seq = read_marker_sequence(f)  # frames are labels: a sorted index array
    assert seq.frames.tolist() == [0, 300000000] and seq.positions.shape == (2, 2, 3)
    with pytest.raises(InputError, match="source frames must run 0..T-1 without holes; frame 1 is absent"):
        read_retarget_inputs(f, f)  # retargeting needs consecutive source frames: refused, not allocated
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 200_000  # KiB: no 2-8 GB index arrays
