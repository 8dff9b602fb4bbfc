
import numpy as np
import pytest

from facegeom.errors import DataNotFoundError, InputError
from facegeom.model import face as fd



def test_locate_order(tmp_path, monkeypatch, face_model):
    real = fd.locate_data()
    # explicit path wins, and may be the folder or the file
    assert fd.locate_data(real.parent) == real
    assert fd.locate_data(real) == real
    # env var is used when no path is given
    monkeypatch.setenv(fd.ENV_VAR, str(real.parent))
    assert fd.locate_data() == real
    # a wrong explicit path is an error even though env/default would work
    with pytest.raises(DataNotFoundError, match="given path"):
        fd.locate_data(tmp_path)


def test_not_found_names_all_three_places(tmp_path, monkeypatch):
    monkeypatch.setenv(fd.ENV_VAR, str(tmp_path / "nowhere"))
    monkeypatch.setattr(fd, "default_data_path", lambda: tmp_path / "also-nowhere")
    monkeypatch.setenv(fd.CACHE_ENV_VAR, str(tmp_path / "empty-cache"))  # the last place: the user cache
    with pytest.raises(DataNotFoundError) as e:
        fd.locate_data()
    msg = str(e.value)
    assert "path=PATH" in msg and "FACEGEOM_DATA" in msg and "also-nowhere" in msg
    assert "--data" not in msg  # the library names its argument; the CLI shows the flag (tests/test_interfaces.py)


def test_bundle_with_missing_key_or_bad_shape(tmp_path, face_model):
    good = fd.load_bundle()
    arrays = {k: v for k, v in good.items() if not k.startswith("_")}
    broken = dict(arrays)
    del broken["identity_modes"]
    np.savez(tmp_path / "a.npz", **broken)
    with pytest.raises(InputError, match="lacks the keys identity_modes"):
        fd.load_bundle(tmp_path / "a.npz")
    broken = dict(arrays)
    broken["expression_deltas"] = arrays["expression_deltas"][:, :100]
    np.savez(tmp_path / "b.npz", **broken)
    with pytest.raises(InputError, match="expression_deltas"):
        fd.load_bundle(tmp_path / "b.npz")
    (tmp_path / "c.npz").write_bytes(b"not a zip")
    with pytest.raises(InputError, match="c.npz"):
        fd.load_bundle(tmp_path / "c.npz")


def test_face_model_composition(face_model):
    m = face_model
    assert m.neutral.shape == (9409, 3) and m.triangles.shape == (18460, 3)
    assert m.n_expressions == 53 and m.n_identities == 100 and m.landmarks.shape == (68,)
    j = m.expression_index("jawOpen")
    V = m.face(identity=[1.0, -0.5], expression={"jawOpen": 0.5})
    ref = (m.neutral + 1.0 * m.identity_modes[0] - 0.5 * m.identity_modes[1]
           + 0.5 * m.expression_deltas[j])
    np.testing.assert_allclose(V, ref, atol=1e-5)
    np.testing.assert_array_equal(m.face(), m.neutral)
    np.testing.assert_allclose(m.landmark_positions(V), V[m.landmarks])
    # the jaw opens downwards: the chin landmark (8) moves down in y
    assert m.face(expression={"jawOpen": 1.0})[m.landmarks[8], 1] < m.neutral[m.landmarks[8], 1] - 0.5


def test_face_model_errors(face_model):
    with pytest.raises(InputError, match="unknown expression 'smile'"):
        face_model.face(expression={"smile": 1.0})
    with pytest.raises(InputError, match="at most 100"):
        face_model.face(identity=np.zeros(101))
    with pytest.raises(InputError, match="shape"):
        face_model.face(expression=np.zeros(3))
    with pytest.raises(InputError, match="NaN"):
        face_model.face(expression={"jawOpen": float("nan")})


def test_random_identity_is_seeded(face_model):
    a = face_model.random_identity(7)
    np.testing.assert_array_equal(a, face_model.random_identity(7))
    assert not np.array_equal(a, face_model.random_identity(8))


def test_import_ict_folder_matches_bundle(face_model, original):
    a = fd.import_ict_folder(original)
    m = face_model
    np.testing.assert_allclose(a["neutral"], m.neutral, atol=1e-6)
    np.testing.assert_array_equal(a["quads"], m.quads)
    np.testing.assert_array_equal(a["triangles"], m.triangles)
    np.testing.assert_array_equal(a["landmarks_multipie68"], m.landmarks)
    assert set(a["expression_names"]) == {"jawOpen", "mouthSmile_L", "eyeBlink_R"}
    for name, d in zip(a["expression_names"], a["expression_deltas"]):
        np.testing.assert_allclose(d, m.expression_deltas[m.expression_index(name)], atol=1e-5)
    for name, d in zip(a["identity_names"], a["identity_modes"]):
        np.testing.assert_allclose(d, m.identity_modes[m.identity_names.index(name)], atol=1e-5)


def test_import_ict_folder_errors(tmp_path):
    with pytest.raises(InputError, match="not a folder"):
        fd.import_ict_folder(tmp_path / "nope")
    with pytest.raises(InputError, match="generic_neutral_mesh.obj: file not found"):
        fd.import_ict_folder(tmp_path)
    (tmp_path / "generic_neutral_mesh.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (tmp_path / "vertex_indices.json").write_text("{not json")
    with pytest.raises(InputError, match="malformed JSON"):
        fd.import_ict_folder(tmp_path)


def test_bundle_that_is_not_an_npz_is_named_as_such(tmp_path):
    """A mesh or a pickle given as the bundle: one line saying it is not a bundle (never unpickled)."""
    import pickle

    obj = tmp_path / "face.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    pkl = tmp_path / "evil.npz"
    pkl.write_bytes(pickle.dumps({"neutral": 1}))
    for p in (obj, pkl):
        with pytest.raises(InputError, match="not a face data bundle") as e:
            fd.load_bundle(p)
        assert "pickle" not in str(e.value)


def test_bundle_with_fractional_ids_is_refused(tmp_path):
    arrays = {k: v for k, v in fd.load_bundle().items() if not k.startswith("_")}
    lm = arrays["landmarks_multipie68"].astype(float)
    lm[5] += 0.5
    np.savez(tmp_path / "frac.npz", **{**arrays, "landmarks_multipie68": lm})
    with pytest.raises(InputError, match="landmarks_multipie68 must hold integer vertex ids"):
        fd.load_bundle(tmp_path / "frac.npz")
    np.savez(tmp_path / "whole.npz", **{**arrays, "landmarks_multipie68": np.round(lm)})  # integral floats are ids
    fd.load_bundle(tmp_path / "whole.npz")
