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

NAMES = ("vertex_indices.json", "generic_neutral_mesh.obj", "jawOpen.obj", "mouthSmile_L.obj", "eyeBlink_R.obj",
         "identity000.obj", "identity001.obj")
PREFIX = "/mirror/"


def _original_folder() -> Path | None:
    """The seven original files: ``original/`` next to the bundle found, else the cache's downloads."""
    places = []
    try:
        places.append(fd.locate_data().parent / "original")
    except DataNotFoundError:
        pass
    places.append(dl.raw_folder(dl.read_registry()) / dl.MODEL_FOLDER)
    return next((p for p in places if all((p / n).is_file() for n in NAMES)), None)


@pytest.fixture(scope="module")
def original(tmp_path_factory):
    """A miniature ICT-FaceKit checkout: ``FaceXModel/`` with the seven files, and ``LICENSE`` when found."""
    folder = _original_folder()
    if folder is None:
        pytest.skip("the original ICT-FaceKit files are not present (run `facegeom data fetch` or use ../shared)")
    root = tmp_path_factory.mktemp("ict-mini")
    mini = root / dl.MODEL_FOLDER
    mini.mkdir()
    for n in NAMES:
        shutil.copyfile(folder / n, mini / n)
    lic = next((p for p in (folder.parent / dl.LICENSE_COPY, folder.parent / dl.LICENSE_PATH) if p.is_file()), None)
    if lic is not None:
        shutil.copyfile(lic, root / dl.LICENSE_PATH)
    return mini


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
    assert f"7 files, {size / 1e6:.1f} MB" in lines[0] and "3 expressions, 2 identities" in lines[0]
    assert mirror.url in lines[1]
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
    assert mirror.requests == [] and "7 files" in lines[0].split("),")[-1]
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
    out = dl.build_bundle(original, identities=1, dest=tmp_path / "out", registry=registry, echo=lines.append)
    m = fd.load_face_model(out)
    assert (m.n_expressions, m.n_identities) == (3, 1) and "verified against" in m.source
    assert any("checking 6 files" in ln for ln in lines)
    copy = tmp_path / "FaceXModel"
    shutil.copytree(original, copy)
    with open(copy / "eyeBlink_R.obj", "ab") as fh:
        fh.write(b"# edited\n")
    with pytest.raises(InputError, match="eyeBlink_R.obj: SHA-256 mismatch.*pass verify=False"):
        dl.build_bundle(tmp_path, dest=tmp_path / "out2", registry=registry, echo=lines.append)  # the checkout
    out = dl.build_bundle(copy, dest=tmp_path / "out2", registry=registry, verify=False, echo=lines.append)
    assert "not checked" in fd.load_face_model(out).source and fd.load_face_model(out).n_identities == 2
    with pytest.raises(InputError, match="not a folder"):
        dl.build_bundle(tmp_path / "nowhere", registry=registry)
    with pytest.raises(InputError, match="no identity002.obj"):
        dl.build_bundle(copy, identities=3, registry=registry, verify=False)


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
    code, _, err = _run(["data", "fetch", "--identities", "1", "--no-progress"], capsys)
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith("facegeom: error: cannot download the face data from 127.0.0.1:") and "data build" in err
    # the shipped registry against a mirror that serves a different vertex_indices.json
    monkeypatch.setenv(dl.URL_ENV_VAR, mirror.url)
    mirror.corrupt.add(f"{dl.MODEL_FOLDER}/vertex_indices.json")
    code, _out, err = _run(["data", "fetch", "--no-progress"], capsys)
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith(f"facegeom: error: {dl.MODEL_FOLDER}/vertex_indices.json: SHA-256 mismatch")


def test_cli_build_mismatch_names_the_flag(original, tmp_path, monkeypatch, capsys):
    copy = tmp_path / "FaceXModel"
    shutil.copytree(original, copy)
    (copy / "generic_neutral_mesh.obj").write_bytes(b"v 0 0 0\n")
    code, _out, err = _run(["data", "build", str(copy), "--dest", str(tmp_path / "out")], capsys)
    assert code == 2 and err.count("\n") == 1 and "pass --no-verify" in err and "verify=False" not in err


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
    code, out, _ = _run(["data", "fetch", "--if-missing"], capsys)
    assert code == 0 and out.strip() == f"face data: {out_path} (found; nothing to fetch)"
    code, out, _err = _run(["--data", str(tmp_path / "wrong"), "data", "info"], capsys)
    assert code == 0 and "--data               " in out and "in use: none" in out
