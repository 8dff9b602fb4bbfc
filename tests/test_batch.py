"""`facegeom batch` on a real local Dask cluster (2 worker processes on loopback).

Results equal the in-process run of the same chunks bit for bit; a corrupt
input fails its own row; a worker killed mid-job is survived with every output
written once; a rerun recomputes only what is missing; bad jobs are one-line
errors naming the job file.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from facegeom.bench.batch import CX, CY, FOCAL, make_landmark_inputs
from facegeom.errors import InputError
from facegeom.io import read_marker_sequence, read_mesh, read_weights, write_marker_sequence, write_markers, write_mesh
from facegeom.pipelines import batch as fb

from .conftest import grid_mesh, take_files_or_skip


@pytest.fixture(scope="module")
def client():
    distributed = pytest.importorskip("distributed")
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                       dashboard_address=None,
                                       scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"})
    c = distributed.Client(cluster)
    yield c
    c.close()
    cluster.close()


@pytest.fixture(scope="module")
def landmarks(tmp_path_factory, face_model):
    d = tmp_path_factory.mktemp("lm")
    make_landmark_inputs(face_model, d, 48, seed=3)
    return d


def fit_job(src: Path, out: Path, **kw) -> fb.Job:
    d = {"operation": "fit", "method": "sem", "inputs": str(src / "landmarks"), "output": str(out),
         "truth": str(src / "truth" / "{stem}.json"), "shared": {"focal": FOCAL, "cx": CX, "cy": CY},
         "batch": {"chunk": 16}}
    d.update(kw)
    return fb.job_from_dict(d, base=src, source=str(src / "job.toml"))


def rows_by_name(res) -> dict:
    return {Path(r["input"]).name: r for r in res.rows}


def no_temp_files(folder: Path) -> bool:
    return not [p for p in folder.rglob(".*") if ".tmp" in p.name]


def assert_same_arrays(a: Path, b: Path, rig_names=None):
    """The result files of two runs hold the same arrays, bit for bit."""
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file() and not p.name.startswith("batch-"))
    assert files and files == sorted(p.relative_to(b) for p in b.rglob("*")
                                     if p.is_file() and not p.name.startswith("batch-"))
    for rel in files:
        x, y = a / rel, b / rel
        if rel.suffix == ".npz":
            with np.load(x) as zx, np.load(y) as zy:
                assert sorted(zx.files) == sorted(zy.files)
                for k in zx.files:
                    assert np.array_equal(zx[k], zy[k]), (rel, k)
        elif rel.suffix == ".json" and rig_names is not None:
            assert np.array_equal(read_weights(x, rig_names), read_weights(y, rig_names)), rel
        elif rel.suffix in (".ply", ".obj", ".off"):
            for u, v in zip(read_mesh(x), read_mesh(y)):
                assert np.array_equal(u, v), rel
        elif rel.name.endswith(".report.json"):
            continue  # holds timings
        else:
            assert x.read_bytes() == y.read_bytes(), rel


# --------------------------------------------------------------------------- equality with one process


def test_fit_on_cluster_equals_in_process_bit_for_bit(client, landmarks, tmp_path, face_model):
    res = fb.run_job(fit_job(landmarks, tmp_path / "dask"), client=client, progress=False)
    assert res.counts == {"ok": 48, "failed": 0, "skipped": 0, "not run": 0}, res.failed[:1]
    assert res.tasks == 3 and res.chunk == 16
    ref = fb.run_job(fit_job(landmarks, tmp_path / "inline"), inline=True, progress=False)
    assert ref.counts["ok"] == 48
    names = face_model.expression_names
    assert_same_arrays(tmp_path / "dask", tmp_path / "inline", names)
    assert all((tmp_path / "dask" / f"t{k:05d}.json").read_bytes() == (tmp_path / "inline" / f"t{k:05d}.json")
               .read_bytes() for k in range(48))
    # the summary: one row per input, error metrics against the truth, the worker that ran it
    r = rows_by_name(res)["t00000.csv"]
    assert r["status"] == "ok" and r["output"] == "t00000.json" and 0 <= r["err_mean"] < 1.0
    assert {"coef_mae", "coef_max", "err_max", "time_s"} <= set(r)
    assert len({x["worker"] for x in res.rows}) == 2  # both workers took part
    text = (tmp_path / "dask" / fb.SUMMARY_NAME).read_text().splitlines()
    assert text[0].startswith("input,output,status,message,time_s,worker") and len(text) == 49
    # the rig (with its Gram matrix) and the fitter were built once per worker, not per task
    key = fb._plan(fit_job(landmarks, tmp_path / "x"))[0]["key"]
    builds = client.run(lambda: dict(__import__("facegeom.pipelines.batch").pipelines.batch._BUILDS))
    assert sorted(b.get(key) for b in builds.values()) == [1, 1]


@pytest.fixture(scope="module")
def drive_inputs(tmp_path_factory, face_model):
    from facegeom.model import layout, random_sparse_expression

    d = tmp_path_factory.mktemp("drive")
    (d / "in").mkdir()
    (d / "truth").mkdir()
    ids = layout(face_model, "ict80")
    rng = np.random.default_rng(5)
    faces = [face_model.face(None, random_sparse_expression(face_model.expression_names, rng)) for _ in range(11)]
    for k in range(5):  # single frames: vertex_id,x,y,z (shuffled rows) -> one mesh each
        order = rng.permutation(ids.size)
        write_markers(d / "in" / f"f{k}.csv", ids[order], faces[k][ids[order]])
        write_mesh(d / "truth" / f"f{k}.ply", faces[k], face_model.triangles)
    P = np.stack([f[ids] for f in faces[5:]])
    write_marker_sequence(d / "in" / "seq.npz", P, names=[str(i) for i in ids])  # -> vertices (6, n, 3)
    write_markers(d / "layout.csv", ids, np.zeros((ids.size, 3)))
    return d


def test_drive_on_cluster_equals_in_process_bit_for_bit(client, drive_inputs, tmp_path):
    def job(out):
        return fb.job_from_dict({"operation": "drive", "inputs": "in", "output": str(out),
                                 "truth": "truth/{stem}.ply", "shared": {"markers": "layout.csv"}},
                                base=drive_inputs, source="drive.toml")

    res = fb.run_job(job(tmp_path / "dask"), client=client, progress=False)
    assert res.counts["ok"] == 6, [r["message"] for r in res.rows]
    assert res.tasks == 6  # frames and a sequence: one input per task (16 frames per task when all are frames)
    ref = fb.run_job(job(tmp_path / "inline"), inline=True, progress=False)
    assert ref.counts["ok"] == 6
    assert_same_arrays(tmp_path / "dask", tmp_path / "inline")
    rows = rows_by_name(res)
    assert 0 < rows["f0.csv"]["err_mean"] < 0.5  # cm, 80 markers on the face
    assert "ground truth" in rows["seq.npz"]["message"]  # no truth/seq.ply: result kept, metrics missing
    with np.load(tmp_path / "dask" / "seq.npz") as z:
        assert z["vertices"].shape == (6, 9409, 3)


# --------------------------------------------------------------------------- failures, worker death, resume


def test_corrupt_input_fails_its_own_row(client, landmarks, tmp_path):
    src = tmp_path / "src"
    shutil.copytree(landmarks, src)
    (src / "landmarks" / "t00007.csv").write_bytes(b"\x00\x01garbage\xff")
    (src / "landmarks" / "t00020.csv").write_text("vertex_id,u,v\n12,1.0\n")
    res = fb.run_job(fit_job(src, tmp_path / "out"), client=client, progress=False)
    rows = rows_by_name(res)
    assert res.counts["failed"] == 2 and res.counts["ok"] == 46
    assert rows["t00007.csv"]["status"] == "failed" and "t00007.csv" in rows["t00007.csv"]["message"]
    assert "line 2: expected 3 values, got 2" in rows["t00020.csv"]["message"]
    assert not (tmp_path / "out" / "t00007.json").exists()
    summary = (tmp_path / "out" / fb.SUMMARY_NAME).read_text()
    assert "failed" in summary and "expected 3 values" in summary


def _arm_kill(marker: str, index: int):
    """On a worker: kill this process right after item ``index``'s output is written (once, via ``marker``)."""
    import facegeom.pipelines.batch as b

    op = b._OPS["fit"]
    write = op.write

    def write_then_die(state, spec, item, result):
        metrics = write(state, spec, item, result)
        if item["index"] == index:
            try:
                fd = os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            except FileExistsError:
                return metrics
            st = os.stat(item["outputs"][0])
            os.write(fd, json.dumps({"ino": st.st_ino, "mtime_ns": st.st_mtime_ns, "pid": os.getpid()}).encode())
            os.close(fd)
            os.kill(os.getpid(), signal.SIGKILL)
        return metrics

    op.write = write_then_die
    return os.getpid()


def test_worker_killed_mid_job_is_survived(client, landmarks, tmp_path, face_model):
    marker = tmp_path / "killed.json"
    pids = client.run(_arm_kill, str(marker), 5)
    try:
        res = fb.run_job(fit_job(landmarks, tmp_path / "out"), client=client, progress=False)
        info = json.loads(marker.read_text())
        assert info["pid"] in pids.values()  # a worker did die, after writing item 5 of chunk 0
        assert res.counts["failed"] == 0 and res.counts["ok"] + res.counts["skipped"] == 48
        rows = rows_by_name(res)
        assert rows["t00005.csv"]["status"] == "skipped"  # the retry found it complete and left it
        assert info["pid"] not in {int(r["worker"].rsplit(":", 1)[1]) for r in res.rows if r["status"] == "ok"}
        st = os.stat(tmp_path / "out" / "t00005.json")
        assert (st.st_ino, st.st_mtime_ns) == (info["ino"], info["mtime_ns"])  # written exactly once
        assert all((tmp_path / "out" / f"t{k:05d}.json").is_file() for k in range(48))  # nothing lost
        assert no_temp_files(tmp_path / "out")
        fb.run_job(fit_job(landmarks, tmp_path / "inline"), inline=True, progress=False)
        for k in range(48):  # the retried chunk fitted fewer targets together: equal to rounding
            a = read_weights(tmp_path / "out" / f"t{k:05d}.json", face_model.expression_names)
            b = read_weights(tmp_path / "inline" / f"t{k:05d}.json", face_model.expression_names)
            np.testing.assert_allclose(a, b, atol=1e-6)
    finally:
        client.restart()  # fresh, unpatched workers for the other tests
        client.wait_for_workers(2, timeout=60)


def test_resume_recomputes_only_what_is_missing(client, landmarks, tmp_path):
    out = tmp_path / "out"
    first = fb.run_job(fit_job(landmarks, out), client=client, progress=False)
    assert first.counts["ok"] == 48
    # a rerun has nothing to do, and keeps the metrics of the run that wrote each output
    second = fb.run_job(fit_job(landmarks, out), client=client, progress=False)
    assert second.counts["skipped"] == 48 and second.tasks == 0
    assert [r["err_mean"] for r in second.rows] == [f"{r['err_mean']:.6g}" for r in first.rows]
    # interrupted: the summary and a few outputs are gone
    (out / fb.SUMMARY_NAME).unlink()
    gone = ["t00003.json", "t00017.json", "t00040.json"]
    for g in gone:
        (out / g).unlink()
    before = {p.name: (p.stat().st_ino, p.stat().st_mtime_ns) for p in out.glob("t*.json")}
    # a writer killed mid-write leaves its temporary file: removed on resume; files of others stay
    (out / ".t00003.k2j_x9.tmp.json").write_text("{\"weig")
    (out / ".t00044.zz.tmp.json").write_text("")
    (out / ".notes.tmp.json").write_text("mine")
    again = fb.run_job(fit_job(landmarks, out), client=client, progress=False)
    assert not (out / ".t00003.k2j_x9.tmp.json").exists() and not (out / ".t00044.zz.tmp.json").exists()
    assert (out / ".notes.tmp.json").read_text() == "mine"
    (out / ".notes.tmp.json").unlink()
    assert again.counts == {"ok": 3, "failed": 0, "skipped": 45, "not run": 0}
    assert again.tasks == 3  # one per chunk holding a missing output, each with that item only
    assert sorted(r["output"] for r in again.rows if r["status"] == "ok") == gone
    after = {p.name: (p.stat().st_ino, p.stat().st_mtime_ns) for p in out.glob("t*.json")}
    assert {k: after[k] for k in before} == before  # the others were not touched
    assert no_temp_files(out)


def test_output_folder_of_another_job_is_refused(landmarks, tmp_path):
    fb.run_job(fit_job(landmarks, tmp_path / "out", inputs=str(landmarks / "landmarks" / "t0000[0-3].csv")),
               inline=True, progress=False)
    other = fit_job(landmarks, tmp_path / "out", inputs=str(landmarks / "landmarks" / "t0000[0-3].csv"),
                    params={"clamp": True})
    with pytest.raises(InputError, match="another job.*params"):
        fb.run_job(other, inline=True, progress=False)
    res = fb.run_job(other, inline=True, progress=False, overwrite=True)
    assert res.counts["ok"] == 4


def test_shared_state_that_cannot_be_built_fails_the_chunks(landmarks, tmp_path, monkeypatch):
    def broken(spec):
        raise InputError("cannot read the rig", "rig.npz")

    monkeypatch.setattr(fb._OPS["fit"], "state", broken)
    res = fb.run_job(fit_job(landmarks, tmp_path / "out"), inline=True, progress=False)
    assert res.counts["failed"] == 48
    assert res.rows[0]["message"] == "task failed: shared state: rig.npz: cannot read the rig"


# --------------------------------------------------------------------------- the other operations


def test_retarget_animate_clean_on_cluster(client, tmp_path, face_model):
    from .test_cli_retarget import _pair

    # retarget: two sources with their labels (one broken), ground truth for the metrics
    r = tmp_path / "rt"
    (r / "src").mkdir(parents=True)
    (r / "labels").mkdir()
    (r / "truth").mkdir()
    lab = np.array([0, 6, 12, 19, 25, 31, 39])
    for k in range(2):
        X, Y = _pair(seed=k)
        write_marker_sequence(r / "src" / f"s{k}.csv", X)
        write_marker_sequence(r / "truth" / f"s{k}.npz", Y)
        write_marker_sequence(r / "labels" / f"s{k}.csv", Y[lab], frames=lab)
    write_marker_sequence(r / "labels" / "s1.csv", Y[lab[:1]], frames=lab[:1])  # one labelled frame only
    job = {"operation": "retarget", "inputs": "src/*.csv", "shared": {"labels": "labels/{stem}.csv"},
           "truth": "truth/{stem}.npz"}
    res = fb.run_job(fb.job_from_dict({**job, "output": "out"}, base=r), client=client, progress=False)
    rows = rows_by_name(res)
    assert rows["s0.csv"]["status"] == "ok" and rows["s0.csv"]["err_mean"] < 0.1
    assert rows["s1.csv"]["status"] == "failed" and "at least two labelled frames" in rows["s1.csv"]["message"]
    fb.run_job(fb.job_from_dict({**job, "output": "ref"}, base=r), inline=True, progress=False)
    assert_same_arrays(r / "out", r / "ref")
    assert read_marker_sequence(r / "out" / "s0.npz").positions.shape == (40, 8, 3)

    # clean: two dirty grids (duplicated vertices) with markers carried through, one truncated file
    c = tmp_path / "cl"
    c.mkdir()
    for k in range(2):
        V, F = grid_mesh(6 + k, 6)
        V2 = np.r_[V, V[:3]]
        F2 = F.copy()
        F2[0] = [V.shape[0], V.shape[0] + 1, V.shape[0] + 2]  # a face on the duplicates
        write_mesh(c / f"g{k}.obj", V2, F2)
        write_markers(c / f"g{k}.markers.csv", np.array([4, 10]), V2[[4, 10]])
    (c / "bad.obj").write_text("v 0 0 0\nv 1 0 0\nf 1 2 3\n")
    job = {"operation": "clean", "inputs": "*.obj", "shared": {"markers": "{stem}.markers.csv", "map": "npz"},
           "params": {"largest_component": True}}
    res = fb.run_job(fb.job_from_dict({**job, "output": "out"}, base=c), client=client, progress=False)
    rows = rows_by_name(res)
    assert rows["g0.obj"]["status"] == "ok" and rows["g0.obj"]["vertices_out"] == 36
    assert rows["bad.obj"]["status"] == "failed" and "bad.obj" in rows["bad.obj"]["message"]
    for name in ("g1.obj", "g1.map.npz", "g1.markers.csv", "g1.report.json"):
        assert (c / "out" / name).is_file(), name
    fb.run_job(fb.job_from_dict({**job, "output": "ref"}, base=c), inline=True, progress=False)
    assert_same_arrays(c / "out", c / "ref")

    # animate: one real take, 20 frames
    take = take_files_or_skip()[0]
    a = tmp_path / "an"
    a.mkdir()
    job = {"operation": "animate", "inputs": str(take), "shared": {"frames": 20, "labels": 4}}
    res = fb.run_job(fb.job_from_dict({**job, "output": "out"}, base=a), client=client, progress=False)
    row = res.rows[0]
    assert row["status"] == "ok", row["message"]
    assert 0 < row["face_err_mm_mean"] < 5
    with np.load(a / "out" / f"{take.stem}.npz") as z:
        assert z["vertices"].shape == (20, 9409, 3)


# --------------------------------------------------------------------------- bad jobs, the command line


@pytest.mark.parametrize("text, problem", [
    ("operation = \n", "not valid TOML"),
    ('operation = "fitt"\ninputs = "x"\noutput = "o"\n', "unknown operation 'fitt'"),
    ('operation = "fit"\nmethod = "nope"\ninputs = "lm"\noutput = "o"\n[shared]\nfocal = 1.0\ncx = 1.0\ncy = 1.0\n',
     "no fitter named 'nope'"),
    ('operation = "fit"\ninputs = "nothing/*.csv"\noutput = "o"\n', "no input matched"),
    ('operation = "fit"\ninputs = "lm"\noutput = "o"\n[shared]\nrig = "gone.npz"\nfocal = 1.0\ncx = 1.0\ncy = 1.0\n',
     "shared.rig .*gone.npz: file not found"),
    ('operation = "fit"\ninputs = "lm"\noutput = "o"\n', "need the camera"),
    ('operation = "fit"\ninputs = "lm"\noutput = "o"\n[shared]\nrig = "lm/a.csv"\n', "shared.rig: .*a.csv"),
    ('operation = "fit"\ninputs = "lm"\noutput = "o"\nspeed = 3\n', "unknown key 'speed'"),
    ('operation = "drive"\ninputs = "lm"\noutput = "o"\n[shared]\nlabels = "x"\n', "unknown shared input 'labels'"),
    ('operation = "retarget"\ninputs = "lm"\noutput = "o"\n', "needs shared.labels"),
    ('operation = "clean"\nmethod = "smooth"\ninputs = "lm"\noutput = "o"\n', "clean runs one of"),
])
def test_bad_job_is_an_input_error_naming_the_file(tmp_path, text, problem):
    (tmp_path / "lm").mkdir()
    (tmp_path / "lm" / "a.csv").write_text("vertex_id,u,v\n1,2,3\n")
    (tmp_path / "lm" / "a.obj").write_text("v 0 0 0\n")
    job = tmp_path / "job.toml"
    job.write_text(text)
    with pytest.raises(InputError, match=problem) as e:
        fb.run_job(fb.load_job(job), inline=True, progress=False)
    assert str(e.value).startswith(str(job))


def test_cli_batch_on_a_scheduler(client, landmarks, tmp_path):
    src = tmp_path / "src"
    shutil.copytree(landmarks, src)
    for p in sorted((src / "landmarks").glob("*.csv"))[8:]:
        p.unlink()
    (src / "landmarks" / "t00002.csv").write_text("nonsense\n")
    (src / "job.toml").write_text(
        'operation = "fit"\ninputs = "landmarks"\noutput = "out"\ntruth = "truth/{stem}.json"\n'
        f"[shared]\nfocal = {FOCAL}\ncx = {CX}\ncy = {CY}\n")
    env = {**os.environ, "DASK_SCHEDULER_ADDRESS": client.scheduler.address}
    r = subprocess.run([sys.executable, "-m", "facegeom", "batch", str(src / "job.toml"), "--quiet"],
                       capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 1, r.stderr  # an input failed
    assert "7 ok, 1 failed, 0 skipped" in r.stdout and client.scheduler.address in r.stdout
    assert "failed: landmarks/t00002.csv:" in r.stderr and "vertex_id,u,v" in r.stderr
    assert "Traceback" not in r.stderr
    r = subprocess.run([sys.executable, "-m", "facegeom", "batch", str(tmp_path / "none.toml")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and r.stderr.strip() == f"facegeom: error: {tmp_path / 'none.toml'}: file not found"
