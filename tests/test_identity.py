"""Identity fitting (facegeom.methods.identity) and its command line, on the real ICT face model."""
import json
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from facegeom import registry
from facegeom.errors import InputError
from facegeom.io import write_mesh
from facegeom.methods.identity import IdentityFit, IdentityFitter
from facegeom.model import (
    FIT_LANDMARKS_23,
    BlendshapeRig,
    LandmarkTarget,
    MeshTarget,
    PinholeCamera,
    PointCloudTarget,
    look_at_camera,
)

FACE = 6706


def face_mm(A, B):
    return float(np.linalg.norm(A[:FACE] - B[:FACE], axis=1).mean() * 10)


def aligned_mm(A, B):
    """Face error after the best rigid alignment (a pose / gauge offset removed)."""
    X, Y = A[:FACE] - A[:FACE].mean(0), B[:FACE] - B[:FACE].mean(0)
    U, _, Vt = np.linalg.svd(X.T @ Y)
    R = Vt.T @ np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))]) @ U.T
    return float(np.linalg.norm(X @ R.T - Y, axis=1).mean() * 10)


@pytest.fixture(scope="module")
def person(face_model):
    rng = np.random.default_rng(11)
    a = face_model.random_identity(rng)
    w = np.zeros(face_model.n_expressions)
    w[[face_model.expression_index("jawOpen"), face_model.expression_index("mouthSmile_L")]] = [0.6, 0.4]
    return a, w


def unposed(V, ids, yaw, rng=None, noise=0.0, pitch=0.0):
    cam = look_at_camera(V, yaw=yaw, pitch=pitch)
    uv = cam.project(V[ids])
    if rng is not None:
        uv = uv + rng.normal(size=uv.shape) * noise
    return LandmarkTarget(uv, ids, PinholeCamera(cam.focal, cam.cx, cam.cy))


def test_mesh_exact_recovery(face_model, person):
    a, w = person
    V = face_model.face(a, w)
    fit = IdentityFitter(noise_mm=1e-3, rigid=False).fit(face_model, MeshTarget(V))
    assert isinstance(fit, IdentityFit)
    assert np.abs(fit.identity - a).max() < 1e-5
    assert np.abs(fit.weights[0] - w).max() < 1e-6
    assert face_mm(fit.vertices(), V) < 1e-4


def test_mesh_rigid_motion_recovered(face_model, person):
    a, w = person
    V = face_model.face(a, w)
    R = Rotation.from_rotvec([0.2, -0.4, 0.1]).as_matrix()
    fit = IdentityFitter(noise_mm=1e-3).fit(face_model, MeshTarget(V @ R.T + [1.0, -2.0, 3.0]))
    assert np.abs(fit.identity - a).max() < 1e-4 and np.abs(fit.weights[0] - w).max() < 1e-5
    assert np.allclose(fit.rotations[0], R, atol=1e-6)
    assert np.allclose(fit.posed_vertices(), V @ R.T + [1.0, -2.0, 3.0], atol=1e-5)


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(rotvec=st.lists(st.floats(-0.6, 0.6), min_size=3, max_size=3),
       shift=st.lists(st.floats(-20, 20), min_size=3, max_size=3))
def test_rigid_motion_leaves_the_identity_unchanged(face_model, person, rotvec, shift):
    """Property: moving a noisy mesh target rigidly changes the pose, not the identity or the expression."""
    a, w = person
    rng = np.random.default_rng(0)
    V = face_model.face(a, w) + rng.normal(size=(face_model.n_vertices, 3)) * 0.05
    fitter = IdentityFitter()
    ref = fitter.fit(face_model, MeshTarget(V))
    R = Rotation.from_rotvec(rotvec).as_matrix()
    moved = fitter.fit(face_model, MeshTarget(V @ R.T + shift))
    assert np.abs(moved.identity - ref.identity).max() < 1e-5
    assert np.abs(moved.weights - ref.weights).max() < 1e-6


def test_point_cloud(face_model, person):
    a, w = person
    V = face_model.face(a, w)
    rng = np.random.default_rng(2)
    P = V[:FACE][rng.choice(FACE, 5000, replace=False)] + [0.1, -0.05, 0.05]
    fit = IdentityFitter().fit(face_model, PointCloudTarget(P))
    start = face_mm(face_model.face(), V)  # the mean face: where the fit starts
    assert face_mm(fit.posed_vertices(), V + [0.1, -0.05, 0.05]) < 0.7 * start
    assert fit.info["rms"][0] < 1.5  # mm, closest-point distances
    assert fit.weights[0, face_model.expression_index("jawOpen")] > 0.3
    assert fit.kinds == ("points",)


def test_landmarks_one_image(face_model, person):
    a, w = person
    V = face_model.face(a, w)
    ids = face_model.landmarks
    tg = unposed(V, ids, yaw=15, rng=np.random.default_rng(1), noise=1.0)
    fit = IdentityFitter().fit(face_model, tg)
    generic = IdentityFitter(n_identities=0).fit(face_model, tg)
    assert face_mm(fit.vertices(), V) < 0.8 * face_mm(generic.vertices(), V)
    assert fit.info["rms"][0] < 1.5 and fit.cameras[0].posed
    assert fit.info["time_s"] < 1.0


def test_landmarks_several_images(face_model, person):
    """Neutral frames (the SEM protocol): more views, a better identity; free expressions: per-frame results."""
    a, _ = person
    ids = face_model.landmarks
    rng = np.random.default_rng(4)
    neutral = face_model.face(a)
    frames = [unposed(neutral, ids, yaw, rng, 0.2) for yaw in (-25, -10, 0, 10, 25)]
    fit = IdentityFitter(expressions=False).fit(face_model, frames)
    assert fit.weights.shape == (5, face_model.n_expressions) and len(fit.cameras) == 5
    assert np.abs(fit.weights).max() < 1e-6
    one = IdentityFitter(expressions=False).fit(face_model, frames[2])
    err_many = aligned_mm(fit.rig.neutral, neutral)
    assert err_many < 0.5 * aligned_mm(face_model.face(), neutral)
    assert err_many < aligned_mm(one.rig.neutral, neutral)
    free = IdentityFitter().fit(face_model, frames)
    assert free.weights.shape == (5, face_model.n_expressions) and max(free.info["rms"]) < 1.5


def test_rig_round_trip_and_every_fitter_accepts_it(face_model, person, tmp_path):
    a, w = person
    fit = IdentityFitter(noise_mm=1e-3, rigid=False).fit(face_model, MeshTarget(face_model.face(a, w)))
    rig = fit.rig
    assert np.allclose(rig.neutral, face_model.face(fit.identity), atol=1e-9)
    assert np.array_equal(rig.deltas, np.asarray(face_model.expression_deltas, dtype=np.float64))
    back = BlendshapeRig.from_npz(rig.save_npz(tmp_path / "rig.npz"))
    assert np.array_equal(back.neutral, rig.neutral) and back.names == rig.names
    (tmp_path / "objs").mkdir()
    objs = BlendshapeRig.from_obj_folder(rig.write_obj_folder(tmp_path / "objs"))
    assert np.abs(objs.neutral - rig.neutral).max() < 1e-5
    V = rig.evaluate(w)
    ids = face_model.landmarks
    for name in registry.available("fitters"):
        try:
            m = registry.create("fitters", name)
        except InputError:  # an optional peer that is not installed
            continue
        target = unposed(V, ids, 10) if name == "eos" else MeshTarget(V)
        r = m.fit(rig, target)
        assert r.weights.shape == (rig.n_shapes,)
        if name != "eos":
            assert face_mm(r.vertices, V) < 1.0, name


@pytest.mark.parametrize("make, message", [
    (lambda m: [], "no target"),
    (lambda m: ["x"], "must be a MeshTarget"),
    (lambda m: MeshTarget(np.zeros((10, 3))), "the mesh has 10 vertices"),
    (lambda m: LandmarkTarget([[0, 0], [100, 0], [0, 100]], [0, 1, 2], PinholeCamera(1000, 320, 240)), "at least 4 landmarks"),
    (lambda m: LandmarkTarget([[0, 0], [100, 0], [0, 100], [100, 100]], [0, 1, 2, 10 ** 6], PinholeCamera(1000, 320, 240)),
     "out of range"),
])
def test_bad_targets(face_model, make, message):
    with pytest.raises(InputError, match=message) as e:
        IdentityFitter().fit(face_model, make(face_model))
    assert "\n" not in str(e.value) and "--" not in str(e.value)


@pytest.mark.parametrize("kw", [{"noise_px": 0}, {"noise_mm": -1}, {"rounds": 0}, {"n_identities": -2},
                                {"rigid": "yes"}, {"expression_l1": -1}, {"region": []}, {"expressions": 1},
                                {"identity_scale": 0}, {"occam": "yes"}, {"identity_scale": "evidence"},
                                {"identity_scale": float("nan")},
                                {"expression_stats": (np.zeros(3), np.eye(2))}, {"expression_stats": 5},
                                {"expression_stats": (np.zeros(2), -np.eye(2))},
                                {"expression_stats": (np.zeros(2), np.full((2, 2), np.inf))}])
def test_bad_parameters(kw):
    with pytest.raises(InputError):
        IdentityFitter(**kw)


def test_dof_scale_rule(face_model):
    """One unposed landmark image: n / (n - p), p = 6 pose + B weights; capped; 1 when it does not apply."""
    from facegeom.methods.identity import DOF_SCALE_MAX, _dof_scale
    B = face_model.n_expressions
    ids = face_model.landmarks[:40]
    uv = np.random.default_rng(0).uniform(0.0, 200.0, (40, 2))  # where they lie does not enter the rule
    free = LandmarkTarget(uv, ids, PinholeCamera(1000, 320, 240))
    assert _dof_scale([free], B) == pytest.approx(80 / (80 - 6 - B))
    assert _dof_scale([free], 0) == 1.0  # expressions held: nothing to temper
    assert _dof_scale([free, free], B) == 1.0  # several images: the `temper` rule
    posed = LandmarkTarget(uv, ids, PinholeCamera(1000, 320, 240, np.eye(3), [0, 0, 50]))
    assert _dof_scale([posed], B) == 1.0
    few = LandmarkTarget(uv[:23], ids[:23], PinholeCamera(1000, 320, 240))
    assert _dof_scale([few], B) == DOF_SCALE_MAX


def test_identity_scale_shrinks_monotonically(face_model, person):
    """A stronger identity prior gives a smaller identity (ridge shrinkage); gcv picks a factor of its grid."""
    from facegeom.methods.identity import GCV_GRID
    a, w = person
    V = face_model.face(a, w)
    tg = unposed(V, face_model.landmarks[:40], 15.0, np.random.default_rng(3), 1.0)
    norms = [np.linalg.norm(IdentityFitter(identity_scale=s).fit(face_model, tg).identity) for s in (1.0, 4.0, 16.0)]
    assert norms[0] > norms[1] > norms[2] > 0
    fit = IdentityFitter(identity_scale="gcv").fit(face_model, tg)
    assert fit.info["identity_scale"] in GCV_GRID and np.isfinite(fit.identity).all()


def test_occam_undoes_the_joint_mode_shrinking_faces(face_model):
    """One image, pose free: the joint mode makes faces smaller (and closer); the Occam factor of the weights
    removes that bias. Mean size ratio fitted / true over a few people with dense random expressions."""
    rng = np.random.default_rng(21)
    ids = face_model.landmarks[:40]

    def size(V):
        F = V[:FACE]
        return np.linalg.norm(F - F.mean(0), axis=1).mean()

    ratios = {True: [], False: []}
    for _ in range(6):
        a = face_model.random_identity(rng)
        w = rng.uniform(0, 0.4, face_model.n_expressions) * (rng.random(face_model.n_expressions) < 0.6)
        tg = unposed(face_model.face(a, w), ids, rng.uniform(-30, 30), rng, 1.0)
        for occam in ratios:
            fit = IdentityFitter(occam=occam).fit(face_model, tg)
            assert fit.info["converged"]
            ratios[occam].append(size(face_model.face(fit.identity)) / size(face_model.face(a)))
    on, off = np.mean(ratios[True]), np.mean(ratios[False])
    assert off < on and abs(on - 1) < abs(off - 1)


def test_expression_statistics_and_prior(face_model, person):
    from facegeom.methods.identity import STATS_FLOOR, expression_statistics
    rng = np.random.default_rng(5)
    B = face_model.n_expressions
    W = rng.uniform(0, 0.5, size=(200, B))
    mean, cov = expression_statistics(W)
    assert np.allclose(mean, W.mean(0)) and np.allclose(cov, np.cov(W.T) + STATS_FLOOR * np.eye(B))
    for bad in (np.zeros((1, B)), np.zeros(B), np.full((3, B), np.nan)):
        with pytest.raises(InputError):
            expression_statistics(bad)
    # a very tight prior holds every weight at its mean, whatever the image shows
    a, w = person
    tg = unposed(face_model.face(a, w), face_model.landmarks[:40], 10.0)
    mu = rng.uniform(0.1, 0.3, B)
    fit = IdentityFitter(expression_stats=(mu, 1e-10 * np.eye(B))).fit(face_model, tg)
    assert np.abs(fit.weights[0] - mu).max() < 1e-4
    f = IdentityFitter(expression_stats=(mu, np.eye(B)))
    assert np.array_equal(f.get_params()["expression_stats"][1], np.eye(B))
    with pytest.raises(InputError, match="weights"):
        IdentityFitter(expression_stats=(mu[:5], np.eye(5))).fit(face_model, tg)


def test_not_a_model():
    with pytest.raises(InputError, match="FaceModel"):
        IdentityFitter().fit(object(), MeshTarget(np.zeros((4, 3))))


# --------------------------------------------------------------------------- command line
def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "facegeom", *args], check=False, capture_output=True, text=True,
                          timeout=300, cwd=cwd)


def write_landmarks(path, ids, uv):
    path.write_text("vertex_id,u,v\n" + "".join(f"{i},{float(u)!r},{float(v)!r}\n" for i, (u, v) in zip(ids, uv)))


def test_cli_identity_then_fit_on_the_rig(face_model, person, tmp_path):
    a, w = person
    ids = face_model.landmarks
    neutral = face_model.face(a)
    files = []
    for k, yaw in enumerate((-20, 0, 20)):
        cam = look_at_camera(neutral, yaw=yaw)
        write_landmarks(tmp_path / f"n{k}.csv", ids, cam.project(neutral[ids]))
        files.append(str(tmp_path / f"n{k}.csv"))
    cam = look_at_camera(neutral)
    intr = ["--focal", str(cam.focal), "--cx", str(cam.cx), "--cy", str(cam.cy)]
    r = run("identity", *files, *intr, "-o", str(tmp_path / "rig.npz"), "--coefficients", str(tmp_path / "c.json"))
    assert r.returncode == 0, r.stderr
    rig = BlendshapeRig.from_npz(tmp_path / "rig.npz")
    assert face_mm(rig.neutral, neutral) < 0.5 * face_mm(face_model.face(), neutral)
    c = json.loads((tmp_path / "c.json").read_text())
    assert len(c["identity"]) == face_model.n_identities and len(c["targets"]) == 3
    # expressions on the user's rig
    V = face_model.face(a, w)
    fit_ids = ids[list(FIT_LANDMARKS_23)]
    write_landmarks(tmp_path / "e.csv", fit_ids, look_at_camera(V, yaw=10).project(V[fit_ids]))
    r = run("fit", str(tmp_path / "e.csv"), *intr, "--rig", str(tmp_path / "rig.npz"), "-m", "l1reg",
            "-o", str(tmp_path / "w.json"))
    assert r.returncode == 0, r.stderr
    got = json.loads((tmp_path / "w.json").read_text())["weights"]
    assert abs(got["jawOpen"] - 0.6) < 0.15
    # identity and expression in one go, rig as an OBJ folder
    r = run("fit", str(tmp_path / "e.csv"), *intr, "--identity", "-o", str(tmp_path / "w2.json"),
            "--rig-out", str(tmp_path / "objs"), "--id-param", "noise_px=1.5")
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "objs" / "neutral.obj").is_file() and (tmp_path / "objs" / "jawOpen.obj").is_file()
    assert set(json.loads((tmp_path / "w2.json").read_text())["weights"]) == set(face_model.expression_names)


def test_cli_fit_identity_mesh(face_model, person, tmp_path):
    a, w = person
    write_mesh(tmp_path / "t.obj", face_model.face(a, w), face_model.triangles)
    r = run("fit", str(tmp_path / "t.obj"), "--identity", "-m", "l2reg", "-o", str(tmp_path / "w.json"),
            "--rig-out", str(tmp_path / "r.npz"))
    assert r.returncode == 0, r.stderr
    got = json.loads((tmp_path / "w.json").read_text())["weights"]
    assert abs(got["jawOpen"] - 0.6) < 0.02 and abs(got["mouthSmile_L"] - 0.4) < 0.02
    assert face_mm(BlendshapeRig.from_npz(tmp_path / "r.npz").neutral, face_model.face(a)) < 0.05


@pytest.mark.parametrize("args, problem", [
    (["identity", "missing.obj", "-o", "r.npz"], "file not found"),
    (["identity", "lm.csv", "-o", "r.npz"], "need the camera"),
    (["identity", "t.obj", "-o", "r.txt"], "unsupported rig format"),
    (["identity", "t.obj", "-o", "r.npz", "-p", "noise_mm=0"], "noise_mm must be a number in (0, 10000]"),
    (["identity", "t.obj", "-o", "r.npz", "--coefficients", "c.txt"], "must be .json"),
    (["fit", "t.obj", "-o", "w.json", "--rig-out", "r.npz"], "go with --identity"),
    (["fit", "t.obj", "-o", "w.json", "--identity", "--rig", "t.obj"], "drop --rig"),
])
def test_cli_bad_input_one_line(face_model, tmp_path, args, problem):
    write_mesh(tmp_path / "t.obj", face_model.neutral, face_model.triangles)
    (tmp_path / "lm.csv").write_text("vertex_id,u,v\n1,2,3\n4,5,6\n7,8,9\n10,11,12\n")
    r = run(*args, cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert problem in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not (tmp_path / "r.npz").exists()


# --------------------------------------------------------------------------- the eos peer
def _eos_peer():
    from importlib.metadata import entry_points

    eps = {ep.name: ep for ep in entry_points(group="facegeom.identity")}
    assert {"facegeom", "eos"} <= set(eps)
    try:
        return eps["eos"].load()()
    except InputError as exc:  # pragma: no cover - eos-py is a test dependency
        pytest.skip(str(exc))


def test_eos_identity_peer(face_model, person):
    a, w = person
    V = face_model.face(a, w)
    ids = face_model.landmarks
    fit = _eos_peer().fit(face_model, unposed(V, ids, 10))
    assert isinstance(fit, IdentityFit) and fit.identity.shape == (face_model.n_identities,)
    assert fit.weights.shape == (1, face_model.n_expressions) and fit.cameras == [None]
    assert fit.info["rms"][0] < 5.0 and fit.info["affine_camera"].shape == (3, 4)
    assert fit.rig.n_shapes == face_model.n_expressions


def test_eos_identity_peer_refuses_meshes(face_model):
    peer = _eos_peer()
    with pytest.raises(InputError, match="landmarks only"):
        peer.fit(face_model, MeshTarget(face_model.neutral))
    with pytest.raises(InputError, match="one image"):
        peer.fit(face_model, [MeshTarget(face_model.neutral)] * 2)


def test_bench_identity_small(face_model, tmp_path):
    from facegeom.bench import identity as bi

    rows, _ = bi.main(face_model, ("landmarks", "neutral", "mesh"), 1, 3, tmp_path, frames=2, echo=lambda s: None,
                      progress=False)
    conds = {(r["protocol"], r["condition"]) for r in rows}
    assert {("landmarks", "identity"), ("neutral", "oracle"), ("mesh", "generic")} <= conds
    assert (tmp_path / "identity.csv").is_file() and "| neutral" in (tmp_path / "identity-summary.md").read_text()
    mesh = {r["condition"]: r["vertex_mm"] for r in rows if r["protocol"] == "mesh"}
    assert mesh["identity"] < 0.2 < mesh["generic"]


def test_estimate_noise_follows_the_residual(face_model, person):
    """One image, pose free: the re-estimated sigma lies between noise_px and the true noise, grows with it,
    is floored at noise_px / 2 on clean landmarks, and is noise_px when switched off."""
    a, w = person
    V = face_model.face(a, w)
    ids = face_model.landmarks
    cam = look_at_camera(V, yaw=20.0)
    e = np.random.default_rng(5).normal(size=(ids.size, 2))
    sig = []
    for true in (0.0, 1.5, 3.0):
        tg = LandmarkTarget(cam.project(V[ids]) + true * e, ids, PinholeCamera(cam.focal, cam.cx, cam.cy))
        sig.append(IdentityFitter(noise_px=1.0).fit(face_model, tg).info["noise"][0])
        if true == 3.0:
            assert IdentityFitter(noise_px=1.0, estimate_noise=False).fit(face_model, tg).info["noise"] == [1.0]
    assert 0.5 <= sig[0] < 1.0 < sig[1] < 1.5 < sig[2] < 3.0
    with pytest.raises(InputError, match="estimate_noise"):
        IdentityFitter(estimate_noise="yes")


@settings(max_examples=5, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(noise=st.floats(0.0, 4.0), noise_px=st.floats(0.3, 3.0), yaw=st.floats(-30, 30))
def test_estimate_noise_is_floored_and_finite(face_model, person, noise, noise_px, yaw):
    a, w = person
    V = face_model.face(a, w)
    ids = face_model.landmarks[:40]
    tg = unposed(V, ids, yaw, np.random.default_rng(0), noise)
    fit = IdentityFitter(noise_px=noise_px).fit(face_model, tg)
    s = fit.info["noise"][0]
    assert np.isfinite(s) and s >= 0.5 * noise_px - 1e-12
    assert np.isfinite(fit.identity).all() and np.isfinite(fit.info["energy"])


# ----------------------------------------------------------------------------- extreme views: the fit stays valid
def _posed_view(V, ids, yaw, dist, focal, off=0.0):
    """A camera ``dist`` cm from the landmarks' centre, the face turned by ``yaw`` and seen ``off`` degrees off the
    optical axis (towards the image's right edge) -> ``(pixels, unposed camera of the same intrinsics)``."""
    turn = Rotation.from_euler("y", yaw, degrees=True).as_matrix()
    aside = Rotation.from_euler("y", -off, degrees=True).as_matrix()
    R = aside @ turn
    t = aside @ (np.array([0.0, 0.0, -dist]) - turn @ V[ids].mean(axis=0))
    cam = PinholeCamera(focal, 320.0, 240.0, R, t)
    return cam.project(V[ids]), PinholeCamera(focal, 320.0, 240.0)


def _checked_steps(monkeypatch):
    """Every controlled Gauss-Newton step of the identity fits: taken only when it keeps each landmark in front of
    its camera and does not raise the energy; returns the list of the steps' energies (before, after)."""
    from facegeom.methods import identity as mi

    seen = []
    step = mi._State.step

    def spy(self, x, x_new, p):
        before = self.energy(x)
        out = step(self, x, x_new, p)
        assert self.valid(out)
        seen.append((before, self.energy(out)))
        return out

    monkeypatch.setattr(mi._State, "step", spy)
    return seen


@pytest.mark.parametrize("yaw, dist, focal, off, n", [
    (75.0, 8.0, 200.0, 0.0, 68),  # turned far and near the lens: the first pose once put landmarks behind the camera
    (-80.0, 7.0, 150.0, 0.0, 68),
    (60.0, 12.0, 150.0, 45.0, 68),  # a wide lens, the face near the image's edge
    (70.0, 40.0, 1000.0, 0.0, 23),
    (0.0, 400.0, 5000.0, 0.0, 23),  # a small face far away (~35 px wide)
])
def test_neutral_landmark_fit_holds_on_extreme_views(face_model, person, monkeypatch, yaw, dist, focal, off, n):
    a, _ = person
    V = face_model.face(a)
    lm = np.asarray(face_model.landmarks)
    ids = lm if n == 68 else lm[list(FIT_LANDMARKS_23)]
    uv, cam = _posed_view(V, ids, yaw, dist, focal, off)
    uv = uv + np.random.default_rng(2).normal(size=uv.shape) * 0.5
    steps = _checked_steps(monkeypatch)
    fit = IdentityFitter(expressions=False).fit(face_model, LandmarkTarget(uv, ids, cam))
    assert steps and all(after <= before * (1 + 1e-9) for before, after in steps)
    depth = -fit.cameras[0].to_camera(fit.vertices(0)[ids])[:, 2]
    assert (depth > 0).all() and np.isfinite(fit.info["energy"])
    assert fit.info["rms"][0] < 1.0  # px: the data's noise (0.5 px per coordinate), not a wrong pose


def test_identical_landmarks_are_still_an_input_error(face_model):
    """The one landmark input no pose fits: every point at one pixel (refused as the target is made, before any
    fitter sees it)."""
    ids = face_model.landmarks
    with pytest.raises(InputError, match="no face to fit"):
        LandmarkTarget(np.full((68, 2), 100.0), ids, PinholeCamera(1000, 320, 240))
