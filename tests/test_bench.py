"""`facegeom bench batch | cleanup` end to end at a tiny size, and the benchmarks' report writer."""
import json
import os
import subprocess
import sys

import pytest
from click.testing import CliRunner

from facegeom.bench.batch import BLAS_THREAD_VARIABLES, blas_threads
from facegeom.bench.report import Report, format_table
from facegeom.cli.main import cli


def test_bench_cleanup_command(face_model):
    r = CliRunner().invoke(cli, ["bench", "cleanup", "--vertices", "12000", "--repeats", "2"])
    assert r.exit_code == 0, r.output
    lines = r.output.splitlines()
    assert lines[0].startswith("machine: ")
    assert lines[1].startswith("mesh: 12,") and "clean; dirty:" in lines[1]
    assert lines[2].startswith("defects: {'duplicate_vertices': ")
    assert any(line.startswith("  keep the largest component ") for line in lines)
    assert lines[-1].startswith("clean + index map: median ") and " of 2 (" in lines[-1]


def test_bench_batch_command(tmp_path, face_model):
    out = tmp_path / "res" / "batch.json"
    work = tmp_path / "work"
    r = subprocess.run([sys.executable, "-m", "facegeom", "bench", "batch", "--fits", "4", "--frames", "20",
                        "--per-file", "10", "--workers", "1", "--noop", "5", "--repeats", "1", "--work", str(work),
                        "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    res = json.loads(out.read_text())
    assert out.read_text().endswith("}\n")
    assert (res["fits"], res["frames"], res["workers"], res["noop_tasks"]) == (4, 20, 1, 5)
    assert res["blas_threads_plain_loop"] == "1"
    assert res["fit_tasks"] == 1 and res["drive_tasks"] == 2
    assert res["drive_outputs_identical"] is True
    assert len(res["drive_warm_runs_s"]["dask"]) == 1
    assert json.loads(r.stdout[r.stdout.index("{"):]) == res  # the same numbers printed
    assert "fit, plain loop (one process): " in r.stdout and "scheduler overhead: 5 no-op tasks" in r.stdout
    assert len(list((work / "fit-dask").glob("t*.json"))) == 4  # --work is kept


def test_bench_batch_example(tmp_path, face_model):
    r = CliRunner().invoke(cli, ["bench", "batch", "--example", str(tmp_path / "ex"), "--fits", "3"])
    assert r.exit_code == 0, r.output
    assert r.output.startswith("wrote 3 landmark files to ")
    assert len(list((tmp_path / "ex" / "landmarks").glob("*.csv"))) == 3
    assert len(list((tmp_path / "ex" / "truth").glob("*.json"))) == 3


def test_blas_threads_limits_this_process_and_restores_the_environment(monkeypatch):
    import numpy as np  # noqa: F401 - BLAS loaded, as in a facegeom subcommand
    from threadpoolctl import threadpool_info

    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "7")
    monkeypatch.delenv("MKL_NUM_THREADS", raising=False)
    with blas_threads("1"):
        assert all(os.environ[v] == "1" for v in BLAS_THREAD_VARIABLES)
        assert all(p["num_threads"] == 1 for p in threadpool_info() if p["user_api"] == "blas")
    assert os.environ["OPENBLAS_NUM_THREADS"] == "7" and "MKL_NUM_THREADS" not in os.environ
    with blas_threads("default"):
        assert os.environ["OPENBLAS_NUM_THREADS"] == "7"


def test_report_writes_csv_summary_plot(tmp_path):
    import matplotlib.pyplot as plt

    said = []
    rep = Report(tmp_path / "out", "demo", said.append)
    rep.csv([{"a": 1, "b": 2.5}])
    rep.csv([{"frame": 0}], "frames")
    table = format_table(["a", "b"], [[1, 2.5]])
    rep.summary(table, "note")
    rep.plot(lambda: plt.subplots()[0])
    files = rep.done()
    assert [p.name for p in files] == ["demo.csv", "demo-frames.csv", "demo-summary.md", "demo.png"]
    assert (tmp_path / "out" / "demo.csv").read_text().splitlines() == ["a,b", "1,2.5"]
    assert (tmp_path / "out" / "demo-summary.md").read_text() == table + "\n\nnote\n"
    assert (tmp_path / "out" / "demo.png").read_bytes()[:4] == b"\x89PNG"
    assert said == [table, "note", "wrote " + ", ".join(str(p) for p in files)]


def test_report_without_folder_only_echoes(tmp_path):
    said = []
    rep = Report(None, "demo", said.append)
    assert rep.csv([{"a": 1}]) is None and rep.summary("t", "n") is None
    assert rep.plot(lambda: pytest.fail("no folder: nothing to draw")) is None
    assert rep.done() == [] and said == ["t", "n"]


def test_report_is_atomic(tmp_path):
    rep = Report(tmp_path, "demo", lambda s: None)
    rep.csv([{"a": 1}])
    before = (tmp_path / "demo.csv").read_bytes()
    with pytest.raises(ValueError):  # the second row has a key the header lacks: fails after the header
        rep.csv([{"a": 2}, {"a": 3, "oops": 4}])
    assert (tmp_path / "demo.csv").read_bytes() == before
    with pytest.raises(ValueError):
        rep.csv([{"x": 1}, {"y": 2}], "fresh")

    def broken_figure():
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots()
        ax.plot([0, 1], [0, 1])

        def fail(*args, **kwargs):
            with open(args[0], "wb") as fh:  # a partial PNG, then the error
                fh.write(b"\x89PNG partial")
            raise RuntimeError("disk full")

        fig.savefig = fail
        return fig

    with pytest.raises(RuntimeError, match="disk full"):
        rep.plot(broken_figure)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo.csv"]  # no partial file, no temporary left
    assert rep.written == [tmp_path / "demo.csv"]
