"""Expression transfer onto a head of another topology (facegeom.methods.transfer, `facegeom transfer`).

The head with a known truth: an ICT identity (not the generic face) remeshed by
pymeshlab (another topology, ~9.6k vertices), in mm, turned 30 degrees about a
tilted axis and moved. Its true shapes are the identity's ICT expressions
resampled at the remeshed vertices (their closest points on the identity's
neutral, barycentric). Per shape: relative error |D - D_true| / |D_true|
(Frobenius over the head's vertices, in the head's units, so the scale is undone
by comparing like with like) and the cosine between the displacement fields.
"""
from __future__ import annotations

import time

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

pytest.importorskip("pymeshlab")

SEED = 3  # the identity
EDGE_CM = 0.3  # the remesh's target edge length (about 9,600 vertices)
AXIS = np.array([0.3, 1.0, 0.5])  # the turn's axis (tilted), 30 degrees
SHIFT_MM = np.array([12.0, -40.0, 300.0])


def _remesh(V, F, edge):
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(V, F))
    ms.meshing_isotropic_explicit_remeshing(targetlen=pymeshlab.PureValue(edge), iterations=5)
    m = ms.current_mesh()
    return m.vertex_matrix().astype(np.float64), m.face_matrix().astype(np.int64)


@pytest.fixture(scope="module")
def head(face_model):
    """``(V mm, F, true deltas (K, n, 3) mm in the head's frame, R, the identity's neutral cm)``."""
    import igl

    model = face_model
    a = model.random_identity(np.random.default_rng(SEED))
    V0 = model.identity_neutral(a)
    T = np.asarray(model.triangles, dtype=np.int64)
    Vr, Fr = _remesh(V0, T, EDGE_CM)
    _, tri, C = igl.point_mesh_squared_distance(Vr, V0, T)
    b = igl.barycentric_coordinates(C, V0[T[tri, 0]], V0[T[tri, 1]], V0[T[tri, 2]])
    D = np.asarray(model.expression_deltas, dtype=np.float64)
    truth = np.einsum("vj,kvjc->kvc", b, D[:, T[tri]])
    R = Rotation.from_rotvec(np.radians(30.0) * AXIS / np.linalg.norm(AXIS)).as_matrix()
    Vh = (Vr @ R.T) * 10.0 + SHIFT_MM
    return Vh, Fr, 10.0 * (truth @ R.T), R, V0


@pytest.fixture(scope="module")
def registered(face_model, head):
    from facegeom.methods.transfer import register_head

    Vh, Fh = head[0], head[1]
    lines = []
    t0 = time.perf_counter()
    reg = register_head(face_model, Vh, Fh, progress=lines.append)
    print(f"\nregistration {time.perf_counter() - t0:.1f} s")
    for line in lines:
        print(" ", line)
    return reg


def _scores(D, truth):
    n_true = np.linalg.norm(truth, axis=(1, 2))
    rel = np.linalg.norm(D - truth, axis=(1, 2)) / n_true
    cos = (D * truth).sum(axis=(1, 2)) / (np.linalg.norm(D, axis=(1, 2)) * n_true + 1e-300)
    return rel, cos


def test_registration_finds_units_pose_and_the_face(face_model, head, registered):
    reg = registered
    Vh, R, V0 = head[0], head[3], head[4]
    assert reg.units == pytest.approx(0.1)  # mm found
    assert reg.mm_per_unit == pytest.approx(1.0)
    rep = reg.report
    assert rep["nonrigid"]["median_mm"] < 0.2  # measured 0.031 mm (template -> head surface over the face area)
    assert rep["nonrigid"]["p95_mm"] < 1.5  # measured 0.46
    assert rep["identity"]["median_mm"] < 1.0  # measured 0.32
    # the correspondence itself: each template vertex against the identity's same vertex, posed as the head
    true_template = (V0 @ R.T) * 10.0 + SHIFT_MM
    err = np.linalg.norm(reg.template - true_template, axis=1)[:6706]
    print(f"\ncorrespondence error over the face area: median {np.median(err):.2f} mm, "
          f"95% {np.percentile(err, 95):.2f} mm")
    assert np.median(err) < 1.5  # measured 0.89 mm
    assert np.degrees(Rotation.from_matrix(reg.R @ R.T).magnitude()) < 5.0


def test_both_engines_beat_zero_and_deformation_is_not_worse(face_model, head, registered):
    from facegeom.methods.transfer import transfer_expressions

    truth = head[2]
    med = {}
    for engine in ("deformation", "nearest"):
        res = transfer_expressions(face_model, registered, engine)
        assert res.deltas.shape == truth.shape and np.isfinite(res.deltas).all()
        rel, cos = _scores(res.deltas, truth)
        med[engine] = float(np.median(rel))
        print(f"\n{engine}: median relative error {np.median(rel):.3f} (mean {rel.mean():.3f}, max {rel.max():.3f}), "
              f"median cosine {np.median(cos):.4f}, {res.time_s:.2f} s")
        assert np.median(rel) < 0.2  # zero deltas: 1.0; measured 0.075 (deformation), 0.10 (nearest)
        assert np.median(cos) > 0.98  # measured 0.997 / 0.995
        assert rel.max() < 0.5
    assert med["deformation"] <= med["nearest"]


def test_tangent_engine_beats_zero(face_model, head, registered):
    from facegeom.methods.transfer import transfer_expressions

    res = transfer_expressions(face_model, registered, "tangent")
    rel, cos = _scores(res.deltas, head[2])
    print(f"\ntangent: median relative error {np.median(rel):.3f}, median cosine {np.median(cos):.4f}, "
          f"{res.time_s:.2f} s")
    assert np.median(rel) < 0.3  # measured 0.103 with 1,000 markers


def test_face_region_only_is_worse_on_the_jaw(face_model, head, registered):
    """The face area alone misses the jaw line and neck that move with the jaw (why the default is the template)."""
    from facegeom.methods.transfer import transfer_expressions

    truth = head[2]
    k = face_model.expression_names.index("jawOpen")
    whole = _scores(transfer_expressions(face_model, registered, "nearest").deltas, truth)[0][k]
    face = _scores(transfer_expressions(face_model, registered, "nearest", region="face").deltas, truth)[0][k]
    assert whole < face


def test_a_sphere_is_refused(face_model):
    import pymeshlab

    from facegeom.errors import InputError
    from facegeom.methods.transfer import register_head

    ms = pymeshlab.MeshSet()
    ms.create_sphere(radius=90.0, subdiv=4)
    V, F = ms.current_mesh().vertex_matrix().astype(np.float64), ms.current_mesh().face_matrix().astype(np.int64)
    with pytest.raises(InputError, match="ball.ply: not a head"):
        register_head(face_model, V, F, path="ball.ply")


@pytest.mark.parametrize("V, F, match", [
    (np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), "no vertices"),
    (np.eye(3), np.zeros((0, 3), dtype=np.int64), "no triangles"),
    (np.array([[0.0, 0, 0], [1, 0, 0], [np.nan, 1, 0]]), np.array([[0, 1, 2]]), "NaN"),
    (np.eye(3), np.array([[0, 1, 3]]), "index past"),
])
def test_bad_meshes_are_refused_in_one_line(face_model, V, F, match):
    from facegeom.errors import InputError
    from facegeom.methods.transfer import register_head

    with pytest.raises(InputError, match=match) as exc:
        register_head(face_model, V, F, path="h.obj")
    assert "\n" not in str(exc.value) and str(exc.value).startswith("h.obj: ")


def test_landmark_csv(tmp_path):
    from facegeom.errors import InputError
    from facegeom.methods.transfer import read_head_landmarks

    p = tmp_path / "lm.csv"
    p.write_text("landmark,vertex_id\n" + "".join(f"{k},{10 + k}\n" for k in range(0, 68, 8)))
    lm = read_head_landmarks(p, 100)
    assert lm.shape == (68,) and lm[8] == 18 and lm[1] == -1
    p.write_text("landmark,vertex_id\n70,1\n1,2\n2,3\n3,4\n")
    with pytest.raises(InputError, match="out of range"):
        read_head_landmarks(p, 100)


def test_cli_writes_npz_and_glb(face_model, head, tmp_path):
    from facegeom.cli.main import cli
    from facegeom.io.mesh import write_mesh
    from facegeom.model import BlendshapeRig

    Vh, Fh = head[0], head[1]
    src = tmp_path / "head.ply"
    write_mesh(src, Vh, Fh)
    # the 68 landmarks: the head vertices nearest to the identity's landmark vertices, posed as the head
    R, V0 = head[3], head[4]
    _, ids = cKDTree(Vh).query((V0[face_model.landmarks] @ R.T) * 10.0 + SHIFT_MM)
    lm = tmp_path / "landmarks.csv"
    first = np.unique(ids, return_index=True)[1]  # closed lips: two landmarks may share a head vertex
    lm.write_text("landmark,vertex_id\n" + "".join(f"{k},{ids[k]}\n" for k in sorted(first)))
    runner = CliRunner()
    out = runner.invoke(cli, ["transfer", str(src), "-o", str(tmp_path / "rig.npz"), "--engine", "nearest",
                              "--units", "mm", "--landmarks", str(lm)])
    assert out.exit_code == 0, out.output
    print(out.output)
    for word in ("units: mm", "rigid fit", "identity fit", "non-rigid fit", "transfer (nearest)", "wrote"):
        assert word in out.output
    rig = BlendshapeRig.from_npz(tmp_path / "rig.npz")
    assert rig.n_vertices == Vh.shape[0] and rig.n_shapes == 53
    # the .npz is in facegeom's rig frame: centimetres, the head's axes turned by a signed axis permutation
    S = np.linalg.lstsq(Vh * 0.1, rig.neutral, rcond=None)[0].T
    assert np.allclose(np.abs(S).sum(axis=1), 1.0) and np.allclose(np.abs(S).max(axis=1), 1.0)
    np.testing.assert_allclose(rig.neutral, Vh @ S.T * 0.1, atol=1e-9)
    rel, _ = _scores(rig.deltas, head[2] @ S.T * 0.1)
    assert np.median(rel) < 0.2
    out = runner.invoke(cli, ["transfer", str(src), "-o", str(tmp_path / "rig.glb")])
    assert out.exit_code == 0, out.output
    assert (tmp_path / "rig.glb").stat().st_size > 0
    import facegeom.io as fio

    if hasattr(fio, "read_gltf_rig"):
        g = fio.read_gltf_rig(tmp_path / "rig.glb")
        assert g.neutral.shape == Vh.shape and g.deltas.shape == (53, *Vh.shape)
        np.testing.assert_allclose(g.neutral, Vh / 1000.0, atol=1e-6)  # metres


def test_rig_writers_by_suffix(tmp_path):
    from facegeom.cli.transfer import write_transfer_rig
    from facegeom.io import read_gltf_rig
    from facegeom.model import BlendshapeRig

    V = np.array([[0.0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10]])
    F = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])
    D = np.zeros((2, 4, 3))
    D[0, 3, 2], D[1, 1, 0] = 1.0, 2.0
    rig = BlendshapeRig(V, D, ("a", "b"), F)
    write_transfer_rig(rig, tmp_path / "r.npz", 0.001)
    np.testing.assert_allclose(BlendshapeRig.from_npz(tmp_path / "r.npz").deltas, D)
    write_transfer_rig(rig, tmp_path / "r.glb", 0.001)
    g = read_gltf_rig(tmp_path / "r.glb")
    np.testing.assert_allclose(g.neutral, V / 1000.0, atol=1e-7)
    np.testing.assert_allclose(g.deltas, D / 1000.0, atol=1e-7)
    write_transfer_rig(rig, tmp_path / "objs", 0.001)
    assert sorted(p.name for p in (tmp_path / "objs").iterdir()) == ["a.obj", "b.obj", "neutral.obj"]


def test_unknown_engine_and_region(face_model, registered):
    from facegeom.errors import InputError
    from facegeom.methods.transfer import transfer_expressions

    with pytest.raises(InputError, match="unknown transfer engine"):
        transfer_expressions(face_model, registered, "magic")
    with pytest.raises(InputError, match="unknown region"):
        transfer_expressions(face_model, registered, "nearest", region="ears")


@pytest.mark.parametrize("output, name, words", [
    ("rig.txt", "h.obj", "unsupported rig format"),
    ("rig.npz", "missing.obj", "not found"),
])
def test_cli_user_mistakes_exit_2(tmp_path, capsys, output, name, words):
    from facegeom.cli.main import main

    (tmp_path / "h.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(SystemExit) as exc:
        main(["transfer", str(tmp_path / name), "-o", str(tmp_path / output)])
    err = capsys.readouterr().err
    assert exc.value.code == 2, err
    assert words in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / output).exists()
