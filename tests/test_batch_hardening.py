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
