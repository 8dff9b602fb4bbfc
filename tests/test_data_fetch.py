"""``facegeom data``: fetch (pooch, verified, resumable), build from a folder, info; against a loopback mirror.

The mirror is a tiny HTTP server on 127.0.0.1 started here, serving the seven
untouched ICT-FaceKit files of ``original/`` next to the face data (or of the
cache's download folder) under a test registry: a subset of the real one, so the
hashes are the real ones. No test touches the internet.
"""
from __future__ import annotations

import math
import os
import re
import shutil
import socket
import threading
import types
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np
import pooch
import pytest

from facegeom.errors import DataNotFoundError, DownloadError, InputError
from facegeom.model import download as dl
from facegeom.model import face as fd

from .conftest import ICT_ORIGINAL_NAMES as NAMES

PREFIX = "/mirror/"


@pytest.fixture(scope="module")
def registry_file(original, tmp_path_factory):
    """A registry of the seven files (the real header and the real lines of those files)."""
    real = dl.resources.files("facegeom.model").joinpath(dl.REGISTRY_FILE).read_text(encoding="utf-8")
    keep = {f"{dl.MODEL_FOLDER}/{n}" for n in NAMES}
    lines = [ln for ln in real.splitlines() if ln.startswith("#") or (ln.split() and ln.split()[0] in keep)]
    f = tmp_path_factory.mktemp("registry") / "test-registry.txt"
    f.write_text("\n".join(lines) + "\n")
    return f


@pytest.fixture(scope="module")
def registry(registry_file):
    reg = dl.read_registry(registry_file)
    assert len(reg.files) == len(NAMES)
    return reg


class Mirror:
    """Serves ``files`` (path -> bytes) under ``/mirror/``; can cut a body short, corrupt it, or 404."""

    def __init__(self, files: dict[str, bytes]):
        self.files = dict(files)
        self.cut: dict[str, float] = {}  # path -> how many more times to cut its body short
        self.corrupt: set[str] = set()
        self.requests: list[str] = []
        mirror = self

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self):
                path = self.path[len(PREFIX):] if self.path.startswith(PREFIX) else None
                mirror.requests.append(path)
                if path not in mirror.files:
                    self.send_error(404)
                    return
                body = mirror.files[path]
                if path in mirror.corrupt:
                    body = body[:-9] + b"#corrupt\n"
                self.send_response(200)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                if mirror.cut.get(path, 0) > 0:
                    mirror.cut[path] -= 1
                    self.wfile.write(body[: len(body) // 3])  # then the connection drops
                    self.close_connection = True
                    return
                self.wfile.write(body)

            def log_message(self, *args):
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}{PREFIX}"
        self.thread = threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
        self.thread.start()

    def count(self, name: str) -> int:
        return self.requests.count(f"{dl.MODEL_FOLDER}/{name}")

    def close(self):
        self.server.shutdown()
        self.server.server_close()


@pytest.fixture
def mirror(original, monkeypatch, tmp_path):
    files = {f"{dl.MODEL_FOLDER}/{n}": (original / n).read_bytes() for n in NAMES}
    lic = original.parent / dl.LICENSE_PATH
    if lic.is_file():
        files[dl.LICENSE_PATH] = lic.read_bytes()
    m = Mirror(files)
    monkeypatch.setattr(pooch.core, "time", types.SimpleNamespace(sleep=lambda s: None))  # pooch waits between tries
    monkeypatch.setenv(dl.URL_ENV_VAR, m.url)
    monkeypatch.setenv(fd.CACHE_ENV_VAR, str(tmp_path / "cache"))
    yield m
    m.close()


def _fetch(registry, **kw):
    lines = []
    out = dl.fetch_data(identities=kw.pop("identities", 2), registry=registry, echo=lines.append, progress=False,
                        **kw)
    return out, lines


def _no_lookup_but_cache(monkeypatch, tmp_path):
    monkeypatch.delenv(fd.ENV_VAR, raising=False)
    monkeypatch.setattr(fd, "default_data_path", lambda: tmp_path / "no-shared")


# --------------------------------------------------------------------------- fetch


def test_fetch_builds_the_bundle_in_the_cache(mirror, registry, original, tmp_path, monkeypatch):
    out, lines = _fetch(registry)
    cache = tmp_path / "cache"
    assert out == cache / "ict-face-light" / fd.BUNDLE_NAME  # $FACEGEOM_CACHE honoured
    assert (cache / "ICT-FaceKit" / registry.commit / dl.MODEL_FOLDER / "jawOpen.obj").is_file()
    # downloaded files honour the umask (pooch's temporary files are 0600)
    mask = os.umask(0)
    os.umask(mask)
    for f in (cache / "ICT-FaceKit" / registry.commit / dl.MODEL_FOLDER).iterdir():
        assert f.stat().st_mode & 0o777 == 0o666 & ~mask, f
    # the announcement: file count and size up front, from the registry; the address of $FACEGEOM_DATA_URL
    size = sum(registry.files[f"{dl.MODEL_FOLDER}/{n}"][1] for n in NAMES)
    assert mirror.url in lines[0]  # said before the first request
    assert f"7 files, {size / 1e6:.1f} MB" in lines[1] and "3 expressions, 2 identities" in lines[1]
    assert all(mirror.count(n) == 1 for n in NAMES)
    # the bundle: what the importer reads from the same files, with the commit as its source
    m = fd.load_face_model(out)
    assert (m.n_expressions, m.n_identities) == (3, 2) and registry.commit in m.source
    ref = fd.import_ict_folder(original)
    np.testing.assert_array_equal(m.expression_deltas, ref["expression_deltas"])
    np.testing.assert_array_equal(m.identity_modes, ref["identity_modes"])
    if dl.LICENSE_PATH in mirror.files:
        assert (out.parent / dl.LICENSE_COPY).read_bytes() == mirror.files[dl.LICENSE_PATH]
    # a second fetch downloads nothing
    mirror.requests.clear()
    _, lines = _fetch(registry)
    assert mirror.requests == [] and "7 files" in lines[1].split("),")[-1]
    # the data lookup ends with the cache
    _no_lookup_but_cache(monkeypatch, tmp_path)
    assert fd.locate_data() == out


def test_fewer_identities_and_none(mirror, registry):
    out, _ = _fetch(registry, identities=0)
    m = fd.load_face_model(out)
    assert m.n_identities == 0 and m.identity_modes.shape == (0, m.n_vertices, 3)
    np.testing.assert_array_equal(m.face(expression={"jawOpen": 0.0}), m.neutral)
    assert mirror.count("identity000.obj") == 0
    with pytest.raises(InputError, match="registry lists no"):
        _fetch(registry, identities=3)  # the test registry has two


def test_dropped_connection_is_retried(mirror, registry):
    mirror.cut[f"{dl.MODEL_FOLDER}/identity000.obj"] = 1
    out, _ = _fetch(registry)
    assert mirror.count("identity000.obj") == 2 and mirror.count("identity001.obj") == 1
    assert fd.load_face_model(out).n_identities == 2


def test_interrupted_fetch_continues_where_it_stopped(mirror, registry, tmp_path):
    mirror.cut[f"{dl.MODEL_FOLDER}/jawOpen.obj"] = math.inf
    with pytest.raises(DownloadError) as e:
        _fetch(registry)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"{dl.MODEL_FOLDER}/jawOpen.obj: ") and "again to continue" in msg
    assert not (tmp_path / "cache" / "ict-face-light").exists()  # no bundle from a partial download
    raw = tmp_path / "cache" / "ICT-FaceKit" / registry.commit / dl.MODEL_FOLDER
    assert (raw / "generic_neutral_mesh.obj").is_file() and not (raw / "jawOpen.obj").exists()
    assert not [p for p in raw.iterdir() if p.name not in NAMES]  # no partial or temporary file left
    mirror.cut.clear()
    mirror.requests.clear()
    _fetch(registry)
    assert mirror.count("generic_neutral_mesh.obj") == 0 and mirror.count("vertex_indices.json") == 0
    assert mirror.count("jawOpen.obj") == 1 and mirror.count("identity001.obj") == 1


def test_corrupted_file_is_downloaded_again_once_then_one_line(mirror, registry, tmp_path):
    mirror.corrupt.add(f"{dl.MODEL_FOLDER}/mouthSmile_L.obj")
    with pytest.raises(DownloadError) as e:
        _fetch(registry)
    msg = str(e.value)
    expected = registry.files[f"{dl.MODEL_FOLDER}/mouthSmile_L.obj"][0]
    assert "\n" not in msg and msg.startswith(f"{dl.MODEL_FOLDER}/mouthSmile_L.obj: SHA-256 mismatch")
    assert f"expected {expected}, got " in msg
    assert mirror.count("mouthSmile_L.obj") == 2
    raw = tmp_path / "cache" / "ICT-FaceKit" / registry.commit / dl.MODEL_FOLDER
    assert not (raw / "mouthSmile_L.obj").exists()
    # a cached file that was damaged later is downloaded again
    mirror.corrupt.clear()
    _fetch(registry)
    with open(raw / "jawOpen.obj", "ab") as fh:
        fh.write(b"# edited\n")
    mirror.requests.clear()
    _fetch(registry)
    assert mirror.requests == [f"{dl.MODEL_FOLDER}/jawOpen.obj"]


def test_missing_file_names_the_file_and_the_status(mirror, registry):
    del mirror.files[f"{dl.MODEL_FOLDER}/identity001.obj"]
    with pytest.raises(DownloadError) as e:
        _fetch(registry)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"{dl.MODEL_FOLDER}/identity001.obj: the server answered 404")
    assert dl.URL_ENV_VAR in msg


def _closed_port_url() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    return f"http://127.0.0.1:{port}/"


def test_server_down_says_offline_and_how_to_build_locally(mirror, registry, monkeypatch):
    monkeypatch.setenv(dl.URL_ENV_VAR, _closed_port_url())
    with pytest.raises(DownloadError) as e:
        _fetch(registry)
    msg = str(e.value)
    assert "\n" not in msg and "Connection refused" in msg and "no network, or the server is down" in msg
    assert "facegeom data build PATH" in msg


def test_progress_counts_each_file_once_across_retries():
    class Bar:
        n = 0

        def update(self, k):
            self.n += k

    bar = Bar()
    p = dl._ByteProgress(bar)
    p.total = 100
    p.update(64)
    p.update(64)  # pooch counts whole chunks: clamped to the file
    assert bar.n == 100
    p.total = 100  # a retry starts: the failed attempt is taken back
    assert bar.n == 0
    p.update(64)
    p.reset()
    p.update(100)
    p.close()
    assert bar.n == 100


# --------------------------------------------------------------------------- build, lookup, registry


def test_build_from_a_local_folder_verifies_the_hashes(original, registry, tmp_path, monkeypatch):
    monkeypatch.setenv(fd.CACHE_ENV_VAR, str(tmp_path / "cache"))
    lines = []
    out = dl.build_bundle(original, identities=1, dest=tmp_path / "out", registry=registry, echo=lines.append,
                          partial=True)
    m = fd.load_face_model(out)
    assert (m.n_expressions, m.n_identities) == (3, 1) and "verified against" in m.source
    assert any("checking 6 files" in ln for ln in lines)
    copy = tmp_path / "FaceXModel"
    shutil.copytree(original, copy)
    with open(copy / "eyeBlink_R.obj", "ab") as fh:
        fh.write(b"# edited\n")
    with pytest.raises(InputError, match="eyeBlink_R.obj: SHA-256 mismatch.*pass verify=False"):
        dl.build_bundle(tmp_path, dest=tmp_path / "out2", registry=registry, echo=lines.append, partial=True)
    out = dl.build_bundle(copy, dest=tmp_path / "out2", registry=registry, verify=False, echo=lines.append,
                          partial=True)
    assert "not checked" in fd.load_face_model(out).source and fd.load_face_model(out).n_identities == 2
    with pytest.raises(InputError, match="not a folder"):
        dl.build_bundle(tmp_path / "nowhere", registry=registry)
    with pytest.raises(InputError, match="no identity002.obj"):
        dl.build_bundle(copy, identities=3, registry=registry, verify=False, partial=True)


def test_not_found_names_the_cache_and_the_fetch_command(tmp_path, monkeypatch):
    monkeypatch.setenv(fd.CACHE_ENV_VAR, str(tmp_path / "cache"))
    _no_lookup_but_cache(monkeypatch, tmp_path)
    with pytest.raises(DataNotFoundError) as e:
        fd.locate_data()
    msg = str(e.value)
    assert "\n" not in msg and "facegeom data fetch" in msg and str(tmp_path / "cache" / "ict-face-light") in msg
    places = fd.data_places()
    assert [w for _, w, _ in places][1:] == [None, tmp_path / "no-shared", tmp_path / "cache" / "ict-face-light"]


def test_shipped_registry():
    reg = dl.read_registry()
    assert reg.commit == "da5f95a607f5e6b37755b38d3385d7f2853732e5" and len(reg.files) == 159
    assert reg.default_base_url == f"https://raw.githubusercontent.com/ICT-VGL/ICT-FaceKit/{reg.commit}/"
    plan = dl.fetch_plan(reg, ["jawOpen", "notAShape"], 100)
    assert len(plan) == 103 and plan[2] == "FaceXModel/jawOpen.obj"
    # the neutral and the 53 expressions of vertex_indices.json (not PupilDilate_*, cheekRaiser_*)
    shapes = [Path(p).stem for p in reg.files if p.endswith(".obj") and not re.match(r".*/(identity|Pupil|cheekR)", p)]
    assert len(shapes) == 54
    assert 390e6 < reg.size(dl.fetch_plan(reg, shapes, 100)) < 400e6  # about 400 MB in all


def test_bad_registry(tmp_path):
    f = tmp_path / "r.txt"
    f.write_text("# no header\nFaceXModel/a.obj abc 12\n")
    with pytest.raises(InputError, match="line 2"):
        dl.read_registry(f)


# --------------------------------------------------------------------------- the command line


def _run(argv, capsys):
    from facegeom.cli.main import main

    try:
        main(argv)
        code = 0
    except SystemExit as exc:
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_offline_and_mismatch_are_one_line(mirror, monkeypatch, capsys):
    monkeypatch.setenv(dl.URL_ENV_VAR, _closed_port_url())
    code, _, err = _run(["data", "fetch", "--identities", "1", "--no-progress", "--no-models"], capsys)
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith("facegeom: error: cannot download the face data from 127.0.0.1:") and "data build" in err
    # the shipped registry against a mirror that serves a different vertex_indices.json
    monkeypatch.setenv(dl.URL_ENV_VAR, mirror.url)
    mirror.corrupt.add(f"{dl.MODEL_FOLDER}/vertex_indices.json")
    code, _out, err = _run(["data", "fetch", "--no-progress", "--no-models"], capsys)
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith(f"facegeom: error: {dl.MODEL_FOLDER}/vertex_indices.json: SHA-256 mismatch")


def test_cli_build_mismatch_names_the_flag(original, tmp_path, monkeypatch, capsys):
    copy = tmp_path / "FaceXModel"
    shutil.copytree(original, copy)
    (copy / "generic_neutral_mesh.obj").write_bytes(b"v 0 0 0\n")
    code, _out, err = _run(["data", "build", str(copy), "--dest", str(tmp_path / "out"), "--partial"], capsys)
    assert code == 2 and err.count("\n") == 1 and "pass --no-verify" in err and "verify=False" not in err


def test_build_refuses_a_folder_missing_expressions(original, tmp_path, capsys):
    """The seven-file folder lists 53 expressions and holds 3: refused, one line, nothing written; --partial builds."""
    copy = tmp_path / "FaceXModel"
    shutil.copytree(original, copy)
    out = tmp_path / "out"
    code, _out, err = _run(["data", "build", str(copy), "--dest", str(out)], capsys)
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err
    assert f"{copy}: holds 3 of the 53 expression OBJs" in err and "browDown_L.obj" in err and "--partial" in err
    assert not out.exists()
    code, _out, err = _run(["data", "build", str(copy), "--dest", str(out), "--partial", "--no-verify"], capsys)
    assert code == 0, err
    assert fd.load_face_model(out).n_expressions == 3


def test_cli_info_and_if_missing(mirror, registry, tmp_path, monkeypatch, capsys):
    _no_lookup_but_cache(monkeypatch, tmp_path)
    code, out, _ = _run(["data", "info"], capsys)
    assert code == 0 and "in use: none (run `facegeom data fetch`)" in out
    assert f"download address: {mirror.url}  (${dl.URL_ENV_VAR})" in out
    assert f"cache: {tmp_path / 'cache'}  (${fd.CACHE_ENV_VAR})" in out
    out_path, _ = _fetch(registry)
    code, out, _ = _run(["data", "info"], capsys)
    assert code == 0
    assert f"user cache           {out_path.parent}: {fd.BUNDLE_NAME}" in out and "<- in use" in out
    assert "3 expressions, 2 identities, 9409 vertices" in out and registry.commit in out
    code, out, _ = _run(["data", "fetch", "--if-missing", "--no-take", "--no-models"], capsys)
    assert code == 0 and out.strip() == f"face data: {out_path} (found; nothing to fetch)"
    code, out, _err = _run(["--data", str(tmp_path / "wrong"), "data", "info"], capsys)
    assert code == 0 and "--data               " in out and "in use: none" in out


# --------------------------------------------------------------------------- the public real take


def _takes_registry(tmp_path, files: dict[str, bytes], commit="6492a4a14721ed2c080ae739f453dc667d580f16") -> Path:
    import hashlib

    lines = [f"# a take, commit {commit}", "# raw file address pattern: https://example.invalid/<commit>/<path>"]
    lines += [f"{p} {hashlib.sha256(b).hexdigest()} {len(b)}" for p, b in files.items()]
    f = tmp_path / "takes-registry.txt"
    f.write_text("\n".join(lines) + "\n")
    return f


@pytest.fixture
def take_mirror(tmp_path, monkeypatch):
    """A mirror laid out like the takes' repository (``anim/<take>.csv``, ``LICENSE``), a small real-format take."""
    from facegeom.io.takes import write_livelink_csv

    src = tmp_path / "src.csv"
    t = np.linspace(0, 1, 40)[:, None]
    write_livelink_csv(src, np.clip(np.sin(6 * t + np.arange(4)), 0, 1),
                       ["jawOpen", "eyeBlinkLeft", "eyeBlinkRight", "mouthSmileLeft"], 30.0)
    files = {"anim/take_a.csv": src.read_bytes(), "LICENSE": b"MIT License\n(test copy)\n"}
    m = Mirror(files)
    monkeypatch.setattr(pooch.core, "time", types.SimpleNamespace(sleep=lambda s: None))
    monkeypatch.setenv(dl.TAKES_URL_ENV_VAR, m.url)
    monkeypatch.setenv(fd.CACHE_ENV_VAR, str(tmp_path / "cache"))
    monkeypatch.delenv(fd.TAKES_ENV_VAR, raising=False)
    monkeypatch.setattr(fd, "default_takes_path", lambda: tmp_path / "no-shared")
    m.registry = dl.read_registry(_takes_registry(tmp_path, files))
    yield m
    m.close()


def test_fetch_takes_puts_the_take_and_its_licence_in_the_cache_for_the_lookup(take_mirror, tmp_path):
    from facegeom.io.takes import find_takes, read_take

    lines = []
    folder = dl.fetch_takes(take_mirror.registry, echo=lines.append)
    assert folder == tmp_path / "cache" / "arkit-takes" == fd.takes_cache_folder()
    assert sorted(f.name for f in folder.iterdir()) == ["LICENSE", "take_a.csv"]  # flat, licence beside it
    assert (folder / "LICENSE").read_bytes() == take_mirror.files["LICENSE"]
    assert take_mirror.url in lines[0] and "MIT licence" in lines[0]
    assert sorted(take_mirror.requests) == ["LICENSE", "anim/take_a.csv"]
    assert fd.locate_takes() == folder and read_take(find_takes(folder)[0]).n_frames == 40
    assert not any(p.name.startswith(".") for p in folder.parent.iterdir())  # no download leftovers
    take_mirror.requests.clear()
    lines.clear()
    dl.fetch_takes(take_mirror.registry, echo=lines.append)  # a second fetch: nothing downloaded
    assert take_mirror.requests == [] and "already in" in lines[0]
    (folder / "take_a.csv").write_bytes(b"edited")  # a changed file is fetched again
    dl.fetch_takes(take_mirror.registry, echo=lines.append)
    assert take_mirror.requests == ["anim/take_a.csv"]
    assert (folder / "take_a.csv").read_bytes() == take_mirror.files["anim/take_a.csv"]


def test_fetch_takes_refuses_a_corrupt_file_and_writes_nothing(take_mirror, tmp_path):
    take_mirror.corrupt.add("anim/take_a.csv")
    with pytest.raises(DownloadError, match="anim/take_a.csv: SHA-256 mismatch"):
        dl.fetch_takes(take_mirror.registry, echo=lambda s: None)
    folder = fd.takes_cache_folder()
    assert not folder.exists() or not any(folder.iterdir())
    with pytest.raises(DataNotFoundError, match="facegeom data fetch"):
        fd.locate_takes()


def test_cli_fetch_if_missing_fetches_only_the_take(take_mirror, tmp_path, monkeypatch, capsys, face_model):
    monkeypatch.setenv(fd.ENV_VAR, face_model.path)  # the face data of this machine (the cache is a new one here)
    monkeypatch.setattr(dl, "read_registry", lambda path=None, shipped=dl.REGISTRY_FILE, _r=dl.read_registry:
                        take_mirror.registry if shipped == dl.TAKES_REGISTRY_FILE else _r(path, shipped))
    code, out, err = _run(["data", "fetch", "--if-missing", "--no-progress", "--no-models"], capsys)
    assert code == 0, err
    assert "(found; nothing to fetch)" in out.splitlines()[0]  # the face data of this machine
    assert f"real take: {fd.takes_cache_folder()}" in out
    code, out, _ = _run(["data", "fetch", "--if-missing", "--no-models"], capsys)
    assert code == 0 and out.splitlines()[-1] == f"takes: {fd.takes_cache_folder()} (found; nothing to fetch)"
    code, out, _ = _run(["data", "info"], capsys)
    assert code == 0 and f"user cache           {fd.takes_cache_folder()}: take_a.csv   <- in use" in out
    assert "takes                Live Link Face takes of alexdjulin" in out
    assert f"text: {fd.takes_cache_folder() / 'LICENSE'}" in out and "facegeom             MIT licence" in out


def test_no_take_anywhere_says_how_to_get_one(tmp_path, monkeypatch, capsys, face_model):
    monkeypatch.setenv(fd.ENV_VAR, face_model.path)
    monkeypatch.setenv(fd.CACHE_ENV_VAR, str(tmp_path / "cache"))
    monkeypatch.delenv(fd.TAKES_ENV_VAR, raising=False)
    monkeypatch.setattr(fd, "default_takes_path", lambda: tmp_path / "no-shared")
    from facegeom.errors import TakesNotFoundError

    with pytest.raises(TakesNotFoundError, match="facegeom data fetch.*Pass path=PATH"):
        fd.locate_takes()
    code, _out, err = _run(["animate", "--frames", "10", "-o", str(tmp_path / "a.npz")], capsys)
    assert code == 2 and err.count("\n") == 1
    assert "facegeom data fetch" in err and "--takes FOLDER" in err and "--take FILE" in err
    assert str(tmp_path / "cache" / "arkit-takes") in err and "path=PATH" not in err
    code, _out, err = _run(["bench", "retarget", "--sequences", "1", "--out", str(tmp_path / "b")], capsys)
    assert code == 2 and "--synthetic-only" in err and not (tmp_path / "b").exists()


def test_a_server_that_never_answers_is_given_up_on_in_bounded_time(tmp_path, monkeypatch):
    """It accepts the connection and says nothing: the address is named first, then one line within seconds."""
    import time

    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(8)
    held = []
    stop = threading.Event()

    def accept():
        listener.settimeout(0.1)
        while not stop.is_set():
            try:
                held.append(listener.accept()[0])
            except OSError:
                pass

    threading.Thread(target=accept, daemon=True).start()
    monkeypatch.setattr(dl, "READ_TIMEOUT_S", 1)
    monkeypatch.setattr(pooch.core, "time", types.SimpleNamespace(sleep=lambda s: None))
    monkeypatch.setenv(dl.URL_ENV_VAR, f"http://127.0.0.1:{listener.getsockname()[1]}/")
    monkeypatch.setenv(fd.CACHE_ENV_VAR, str(tmp_path / "cache"))
    lines = []
    t0 = time.monotonic()
    try:
        with pytest.raises(DownloadError, match=r"no answer within 1 s, twice"):
            dl.fetch_data(identities=0, echo=lines.append, progress=False)
    finally:
        stop.set()
        listener.close()
        for c in held:
            c.close()
    assert time.monotonic() - t0 < 10
    assert lines and "127.0.0.1" in lines[0]


# --------------------------------------------------------------------------- budgets: size, deadline, leftovers
class _RawServer:
    """Answers every GET with ``200``, no Content-Length, then ``body`` in pieces of ``piece`` bytes every ``pause`` s."""

    def __init__(self, body: bytes, piece: int, pause: float):
        self.listener = socket.socket()
        self.listener.bind(("127.0.0.1", 0))
        self.listener.listen(8)
        self.url = f"http://127.0.0.1:{self.listener.getsockname()[1]}/"
        self.stop = threading.Event()

        def serve(conn):
            with conn:
                conn.recv(4096)
                conn.sendall(b"HTTP/1.0 200 OK\r\nContent-Type: application/octet-stream\r\n\r\n")
                for i in range(0, len(body), piece):
                    if self.stop.is_set():
                        return
                    try:
                        conn.sendall(body[i:i + piece])
                    except OSError:
                        return
                    self.stop.wait(pause)

        def accept():
            self.listener.settimeout(0.1)
            while not self.stop.is_set():
                try:
                    conn, _ = self.listener.accept()
                except OSError:
                    continue
                threading.Thread(target=serve, args=(conn,), daemon=True).start()

        threading.Thread(target=accept, daemon=True).start()

    def close(self):
        self.stop.set()
        self.listener.close()


def _raw_fetch(server, tmp_path, monkeypatch):
    monkeypatch.setattr(pooch.core, "time", types.SimpleNamespace(sleep=lambda s: None))
    monkeypatch.setenv(dl.URL_ENV_VAR, server.url)
    monkeypatch.setenv(fd.CACHE_ENV_VAR, str(tmp_path / "cache"))
    return dl.fetch_data(identities=0, echo=lambda s: None, progress=False)


def test_a_server_sending_more_than_the_registry_says_is_stopped_at_that_size(tmp_path, monkeypatch):
    """An endless stream (a proxy's page, another file): stopped once past the registry's size, nothing kept."""
    size = dl.read_registry().files[f"{dl.MODEL_FOLDER}/vertex_indices.json"][1]
    server = _RawServer(b"x" * (size * 3), 1 << 16, 0.0)
    try:
        with pytest.raises(DownloadError, match=r"sent more than the .* the registry gives for it") as e:
            _raw_fetch(server, tmp_path, monkeypatch)
    finally:
        server.close()
    assert "\n" not in str(e.value) and str(e.value).startswith(f"{dl.MODEL_FOLDER}/vertex_indices.json: ")
    assert not [f for f in (tmp_path / "cache").rglob("*") if f.is_file()]  # no partial or temporary file


def test_an_announced_size_larger_than_the_registry_is_refused_before_reading(mirror, registry):
    name = f"{dl.MODEL_FOLDER}/vertex_indices.json"
    mirror.files[name] = mirror.files[name] * 50
    with pytest.raises(DownloadError, match=r"announced .* for a file of .*: it serves a different file"):
        _fetch(registry)
    assert mirror.requests.count(name) == 1  # not retried: another try gets the same file


def test_a_server_dripping_bytes_is_given_up_on_at_the_deadline(tmp_path, monkeypatch):
    import time

    monkeypatch.setattr(dl, "DEADLINE_BASE_S", 1.0)
    monkeypatch.setattr(dl, "MIN_RATE_BPS", 10 ** 12)
    server = _RawServer(b"{" * 1000, 1, 0.2)  # a byte every 0.2 s: never silent for a read timeout
    t0 = time.monotonic()
    try:
        with pytest.raises(DownloadError, match=r"not complete within 1 s .*: the server is too slow"):
            _raw_fetch(server, tmp_path, monkeypatch)
    finally:
        server.close()
    assert time.monotonic() - t0 < 6
    assert not [f for f in (tmp_path / "cache").rglob("*") if f.is_file()]


def test_what_a_killed_download_left_is_removed_by_the_next_fetch(mirror, registry, tmp_path):
    import time

    raw = tmp_path / "cache" / "ICT-FaceKit" / registry.commit / dl.MODEL_FOLDER
    raw.mkdir(parents=True)
    old, fresh = raw / "tmpk1ll3d", raw / "tmpl1v3"
    old.write_bytes(b"x" * 1000)
    fresh.write_bytes(b"y")  # another fetch may still be writing this one
    then = time.time() - 2 * dl.STALE_PART_S
    os.utime(old, (then, then))
    _fetch(registry)
    assert not old.exists() and fresh.exists()
