"""Registrations kept in the user cache: a hit is the same result and the same lines, every input is in the key,
what raised or cannot be read is never used, the cache stays bounded, and it can be turned off."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from facegeom.errors import InputError
from facegeom.methods import registration_cache as rc
from facegeom.methods import transfer as tr

HEAD = Path(__file__).parent / "data" / "heads" / "lee_perry_smith.ply"


@pytest.fixture
def fake(monkeypatch, tmp_path, face_model):
    """The registration itself replaced by a recorder (the cache's logic, not the 10 s of work), a private cache."""
    monkeypatch.setenv("FACEGEOM_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv(rc.ENV_VAR, raising=False)
    calls = []

    def register(model, V, F, landmarks, units, path, samples, fitter_params, say):
        calls.append(units)
        if units == "boom":
            raise InputError("not a head")
        say("units: cm (found; x1 to cm)")
        say(f"rigid fit: call {len(calls)}")
        rng = np.random.default_rng(len(calls))
        return tr.HeadRegistration(V, F, rng.normal(size=(face_model.n_vertices, 3)), 1.5, np.eye(3),
                                   rng.normal(size=3), 1.0, 10.0, rng.normal(size=face_model.n_identities),
                                   {"rigid": {"scale": 1.5, "time_s": 2.0}, "time_s": 9.0})

    monkeypatch.setattr(tr, "_register_head", register)
    V, F = np.asarray(face_model.neutral, dtype=np.float64), np.asarray(face_model.triangles, dtype=np.int64)
    return calls, V, F, tmp_path / "cache" / "registrations"


def _reg(face_model, V, F, **kw):
    lines = []
    return tr.register_head(face_model, V, F, progress=lines.append, **kw), lines


def test_a_hit_is_the_same_result_and_lines(fake, face_model):
    calls, V, F, folder = fake
    a, la = _reg(face_model, V, F)
    b, lb = _reg(face_model, V, F)
    assert len(calls) == 1 and len(list(folder.glob("*.npz"))) == 1
    for f in ("template", "R", "t", "identity"):
        assert np.array_equal(getattr(a, f), getattr(b, f))
    assert (a.scale, a.units, a.mm_per_unit) == (b.scale, b.units, b.mm_per_unit) and a.report == b.report
    assert lb[0].startswith("registration: reused from the cache") and lb[1:] == la
    assert b.head_vertices is not None and np.array_equal(b.head_vertices, V)


def test_every_input_is_in_the_key(fake, face_model, monkeypatch):
    calls, V, F, _ = fake
    _reg(face_model, V, F)
    V2 = V.copy()
    V2[0, 0] += 1e-9
    _reg(face_model, V2, F)  # one coordinate, one ulp-ish
    _reg(face_model, V, F[:, [0, 2, 1]])  # the triangles turned
    _reg(face_model, V, F, units="cm")
    _reg(face_model, V, F, samples=1000)
    _reg(face_model, V, F, fitter_params={"rounds": 3})
    lm = np.full(68, -1)
    lm[30] = 5
    _reg(face_model, V, F, landmarks=lm)
    assert len(calls) == 7
    monkeypatch.setattr(rc, "_CODE", ["another version of the code"])
    _reg(face_model, V, F)
    assert len(calls) == 8
    _reg(face_model, V, F)
    assert len(calls) == 8


def test_what_raised_is_not_kept_and_bad_entries_are_ignored(fake, face_model):
    calls, V, F, folder = fake
    for _ in range(2):
        with pytest.raises(InputError, match="not a head"):
            _reg(face_model, V, F, units="boom")
    assert len(calls) == 2 and not folder.exists()
    _reg(face_model, V, F)
    (entry,) = folder.glob("*.npz")
    entry.write_bytes(b"not a zip")  # damaged: computed again and replaced
    _, lines = _reg(face_model, V, F)
    assert len(calls) == 4 and not lines[0].startswith("registration: reused")
    _, lines = _reg(face_model, V, F)
    assert len(calls) == 4 and lines[0].startswith("registration: reused")
    entry.rename(folder / f"{'0' * 64}.npz")  # an entry under another key's name is not that key's
    key = rc.registration_key(face_model, V, F, None, "auto", tr.HEAD_SAMPLES, None)
    assert rc.load("0" * 64) is None and rc.load(key) is None


def test_the_cache_is_bounded_and_can_be_turned_off(fake, face_model, monkeypatch):
    calls, V, F, folder = fake
    monkeypatch.setattr(rc, "KEEP", 3)
    for i in range(5):
        V2 = V.copy()
        V2[0, 0] += i
        _reg(face_model, V2, F)
        os.utime(max(folder.glob("*.npz"), key=lambda p: p.stat().st_mtime_ns), (1e9 + i, 1e9 + i))
    assert len(list(folder.glob("*.npz"))) == 3
    monkeypatch.setenv(rc.ENV_VAR, "off")
    n = len(calls)
    _reg(face_model, V, F)
    _reg(face_model, V, F)
    assert len(calls) == n + 2


def test_an_unwritable_cache_is_not_an_error(fake, face_model, tmp_path, monkeypatch):
    calls, V, F, _ = fake
    (tmp_path / "file").write_text("")
    monkeypatch.setenv("FACEGEOM_CACHE", str(tmp_path / "file"))  # a file where the folder would be
    _reg(face_model, V, F)
    _reg(face_model, V, F)
    assert len(calls) == 2


def test_a_real_head_is_registered_once(tmp_path, monkeypatch, face_model):
    """End to end on a real scan (the registration itself, 10 s): the second registration of the head is the first's,
    byte for byte, in no time, with the same step lines after the one naming the cache."""
    import time

    from facegeom.io.mesh import read_mesh

    monkeypatch.setenv("FACEGEOM_CACHE", str(tmp_path / "cache"))  # the face data is found by the data lookup
    monkeypatch.delenv(rc.ENV_VAR, raising=False)
    V, F = read_mesh(HEAD)[:2]
    runs = []
    for _ in range(2):
        lines, t0 = [], time.process_time()
        reg = tr.register_head(face_model, V, F, progress=lines.append, path=HEAD)
        runs.append((reg, lines, time.process_time() - t0))
    (a, la, ta), (b, lb, tb) = runs
    assert "rigid fit:" in " ".join(la) and lb[0].startswith("registration: reused from the cache") and lb[1:] == la
    for f in ("template", "R", "t", "identity"):
        assert np.array_equal(getattr(a, f), getattr(b, f))
    assert tb < 0.05 * ta
