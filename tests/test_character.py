"""A performance on the user's own character through the rig: `animate --take --character`, `solve --character`.

The character: the MakeHuman head with its 52 ARKit face units (CC0, ``tests/data/heads/``), an
artist's ARKit-named rig in another topology. Its shapes are driven by name (ICT and ARKit meet
through the one name map), the head's rotation and (scaled) translation carried over, the Live
Link output's head and eye columns filled, every ``.glb`` opened by the Khronos validator.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from facegeom.errors import InputError
from tests.conftest import validate

GENERIC = ("--identity", "off")
"""These captures are made from the generic face itself: solved on it as it is (no actor's identity to fit), the
solve is exact."""

CHARACTER = Path(__file__).parent / "data" / "heads" / "makehuman_arkit.npz"


@pytest.fixture(scope="module")
def character():
    from facegeom.model.rig import BlendshapeRig

    return BlendshapeRig.from_npz(CHARACTER)


def _glb_motion(path):
    """The node's rotation and translation keyframes of a .glb written by facegeom -> (quats (T, 4), t (T, 3))."""
    import pygltflib

    doc = pygltflib.GLTF2().load_binary(str(path))
    blob = doc.binary_blob()
    out = {}
    for ch in doc.animations[0].channels:
        acc = doc.accessors[doc.animations[0].samplers[ch.sampler].output]
        view = doc.bufferViews[acc.bufferView]
        width = {"VEC4": 4, "VEC3": 3, "SCALAR": 1}[acc.type]
        data = np.frombuffer(blob, dtype=np.float32, count=acc.count * width,
                             offset=view.byteOffset + (acc.byteOffset or 0))
        out[ch.target.path] = data.reshape(acc.count, width)
    return out


def test_take_on_the_character(character, real_takes, tmp_path, capsys, validator_env):
    from facegeom.cli.main import main
    from facegeom.io.gltf import read_glb_animation
    from facegeom.io.takes import read_take

    take = real_takes[0]
    main(["animate", "--take", str(take), "--character", str(CHARACTER), "--frames", "120", "-o",
          str(tmp_path / "on.glb")])
    out = capsys.readouterr().out
    assert "frames 0..119" in out and "wrote" in out
    issues = validate(validator_env, tmp_path / "on.glb")
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0
    anim = read_glb_animation(tmp_path / "on.glb")
    tk = read_take(take)
    names = list(anim.names) if hasattr(anim, "names") else list(character.names)
    W = np.asarray(anim.weights)
    assert W.shape == (120, 52)
    # ARKit names on both sides: the take's weights play one to one (float32 in the file)
    for k, n in enumerate(names):
        col = tk.names.index(n[0].upper() + n[1:])
        np.testing.assert_allclose(W[:, k], tk.weights[:120, col], atol=1e-6)
    # the Live Link take of the character: same weights, the take's eye rotations carried over
    main(["animate", "--take", str(take), "--character", str(CHARACTER), "--frames", "120", "-o",
          str(tmp_path / "on.csv")])
    back = read_take(tmp_path / "on.csv")
    np.testing.assert_allclose(back.weights, tk.weights[:120], atol=1e-3)
    if tk.rotations is not None:
        np.testing.assert_allclose(back.rotations[:, 3:], tk.rotations[:120, 3:], atol=1e-3)


def test_character_names_map_gains(character, real_takes, tmp_path):
    from facegeom.cli.main import main
    from facegeom.io.takes import read_take

    m = tmp_path / "map.csv"
    m.write_text("rig_shape,source_shape,gain\njawOpen,jawOpen,0.5\nmouthSmileLeft,mouthSmileLeft,0\n")
    main(["animate", "--take", str(real_takes[0]), "--character", str(CHARACTER), "--character-names", str(m),
          "--frames", "60", "-o", str(tmp_path / "c.npz")])
    z = np.load(tmp_path / "c.npz")
    tk = read_take(real_takes[0])
    names = list(z["names"])
    jaw, blink = tk.names.index("JawOpen"), tk.names.index("EyeBlinkLeft")
    np.testing.assert_allclose(z["weights"][:, names.index("jawOpen")], 0.5 * tk.weights[:60, jaw])
    assert np.abs(z["weights"][:, names.index("mouthSmileLeft")]).max() == 0.0
    np.testing.assert_allclose(z["weights"][:, names.index("eyeBlinkLeft")], tk.weights[:60, blink])


@pytest.fixture(scope="module")
def capture(tmp_path_factory, face_model):
    """30 frames of the ICT face's 80 markers, jawOpen and a smile, the head turning and moving (cm)."""
    from facegeom.io.markerseq import write_marker_sequence
    from facegeom.model import BlendshapeRig
    from facegeom.model.layouts import ict80

    d = tmp_path_factory.mktemp("character")
    rig = BlendshapeRig.from_face_model(face_model)
    ids = ict80(face_model)
    rng = np.random.default_rng(1)
    T = 30
    W = np.zeros((T, rig.n_shapes))
    W[:, rig.shape_index("jawOpen")] = 0.5 + 0.4 * np.sin(np.linspace(0, 3, T))
    W[:, rig.shape_index("mouthSmile_L")] = np.linspace(0, 0.8, T)
    F = rig.neutral[ids][None] + np.einsum("tb,bpi->tpi", W, rig.deltas[:, ids])
    # the actor faces sideways, 160 cm up and 2 m off the volume's centre, and moves about there
    R = (Rotation.from_euler("y", 90, degrees=True) * Rotation.from_rotvec(rng.normal(0, 0.2, (T, 3)))).as_matrix()
    t = rng.normal(0, 3, (T, 3)) + (200.0, 160.0, -50.0)
    X = np.einsum("tij,tpj->tpi", R, F) + t[:, None]
    write_marker_sequence(d / "cap.npz", X, names=[f"v{i}" for i in ids])
    return d, rig, W, R, t


def test_solve_onto_the_character(capture, character, tmp_path, capsys, validator_env):
    from facegeom.cli.main import main
    from facegeom.pipelines.character import size_ratio

    d, rig, W, R, t = capture
    main(["solve", str(d / "cap.npz"), *GENERIC, "--character", str(CHARACTER), "--smooth", "off", "-o",
          str(tmp_path / "c.npz")])
    out = capsys.readouterr().out
    assert "the head's motion about the performance's mean pose, its translations x" in out
    z = np.load(tmp_path / "c.npz")
    names = list(z["names"])
    assert names == list(character.names)
    # the actor's ICT weights drive the character's ARKit shapes by name
    np.testing.assert_allclose(z["weights"][:, names.index("jawOpen")], W[:, rig.shape_index("jawOpen")], atol=1e-3)
    np.testing.assert_allclose(z["weights"][:, names.index("mouthSmileLeft")], W[:, rig.shape_index("mouthSmile_L")],
                               atol=1e-3)
    assert np.abs(z["weights"][:, names.index("tongueOut")]).max() == 0.0  # no ICT shape drives it
    # the head: the same turns and moves about the performance's mean pose, translations scaled to the character;
    # at that pose the character stands where its rig puts it (not 160 cm up, facing sideways)
    k = size_ratio(character, rig)
    assert 0.5 < k < 2.0 and abs(k - 1.0) > 0.01
    ref = Rotation.from_matrix(R).mean().as_matrix()
    np.testing.assert_allclose(z["rotations"], np.einsum("ji,tjk->tik", ref, R), atol=1e-4)
    np.testing.assert_allclose(z["translations"], k * (t - np.median(t, axis=0)) @ ref, atol=1e-3)
    assert np.abs(np.median(z["translations"], axis=0)).max() < 0.1  # cm: at home, not 2.6 m away
    assert Rotation.from_matrix(z["rotations"]).mean().magnitude() < 1e-6
    rel = np.einsum("tij,tkj->tik", z["rotations"][1:], z["rotations"][:-1])  # frame-to-frame turns kept
    np.testing.assert_allclose(rel, np.einsum("tij,tkj->tik", np.einsum("ji,tjk->tik", ref, R)[1:],
                                              np.einsum("ji,tjk->tik", ref, R)[:-1]), atol=1e-4)
    # the .glb: the character's mesh and shapes, its node turning and moving as the actor's head (metres)
    main(["solve", str(d / "cap.npz"), *GENERIC, "--character", str(CHARACTER), "--smooth", "off", "-o",
          str(tmp_path / "c.glb")])
    issues = validate(validator_env, tmp_path / "c.glb")
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0
    motion = _glb_motion(tmp_path / "c.glb")
    q = Rotation.from_matrix(z["rotations"]).as_quat()
    dots = np.abs((motion["rotation"] * q).sum(axis=1))
    assert dots.min() > 1 - 1e-5
    np.testing.assert_allclose(motion["translation"], z["translations"] * 0.01, atol=1e-5)
    assert ((motion["rotation"][1:] * motion["rotation"][:-1]).sum(axis=1) > 0).all()  # slerp the short way


def test_solve_onto_the_character_reports_the_smoothing_it_applied(capture, tmp_path, capsys):
    from facegeom.cli.main import main

    d, rig, W, R, t = capture
    main(["solve", str(d / "cap.npz"), "--smooth", "30", "-o", str(tmp_path / "a.npz")])
    actor_line = capsys.readouterr().out
    main(["solve", str(d / "cap.npz"), "--character", str(CHARACTER), "--smooth", "30", "-o",
          str(tmp_path / "c.npz")])
    out = capsys.readouterr().out
    assert "smoothing off" not in out and "smoothing off" not in actor_line
    a, c = np.load(tmp_path / "a.npz"), np.load(tmp_path / "c.npz")
    names = list(c["names"])
    # a character curve driven by one actor curve carries that curve's strength; an undriven one none
    assert c["smoothing"][names.index("jawOpen")] == a["smoothing"][list(a["names"]).index("jawOpen")] > 0
    assert c["smoothing"][names.index("tongueOut")] == 0.0


def test_livelink_out_fills_head_and_eye_columns(capture, tmp_path):
    """A solve's Live Link take has the head's yaw, pitch and roll and the eyes' rotations from their looks."""
    from facegeom.cli.main import main
    from facegeom.io.takes import EYE_YAW_PER_WEIGHT, head_angles, read_take

    d, rig, W, R, t = capture
    main(["solve", str(d / "cap.npz"), *GENERIC, "--smooth", "off", "-o", str(tmp_path / "s.csv")])
    tk = read_take(tmp_path / "s.csv")
    np.testing.assert_allclose(tk.rotations[:, :3], head_angles(R), atol=1e-3)
    assert np.abs(tk.rotations[:, 3:]).max() < 1e-6  # no eye look in this capture: straight ahead
    from facegeom.io.takes import eye_rotations

    look = np.zeros((2, 52))
    names = list(tk.names)
    look[0, names.index("EyeLookOutLeft")] = 1.0
    look[1, names.index("EyeLookInRight")] = 1.0
    e = eye_rotations(look, names)
    assert e[0, 0] == pytest.approx(-EYE_YAW_PER_WEIGHT) and e[1, 3] == pytest.approx(-EYE_YAW_PER_WEIGHT)


def test_character_mistakes_are_one_line(tmp_path, capsys, real_takes):
    from facegeom.cli.main import main

    for args, words in (
        (["animate", "--take", str(real_takes[0]), "--character", str(tmp_path / "none.npz"), "-o",
          str(tmp_path / "x.glb")], "not found"),
        (["animate", "--take", str(real_takes[0]), "--character", str(CHARACTER), "--obj-dir", str(tmp_path / "o"),
          "-o", str(tmp_path / "x.glb")], "--obj-dir"),
        (["animate", "--take", str(real_takes[0]), "--character-names", str(CHARACTER), "-o",
          str(tmp_path / "x.glb")], "--character-names goes with --character"),
        (["animate", "--take", str(real_takes[0]), "--character", str(CHARACTER), "--start", "999999", "-o",
          str(tmp_path / "x.glb")], "start 999999"),
    ):
        with pytest.raises(SystemExit) as exc:
            main(args)
        err = capsys.readouterr().err
        assert exc.value.code == 2 and words in err and len(err.strip().splitlines()) == 1, err
        assert not (tmp_path / "x.glb").exists()


def test_bench_character_orders_the_routes(face_model, real_takes, tmp_path, capsys):
    """Where the truth is known: the actor's rig with deformation transfer beats the generic solve and the
    nearest-copy baseline by far, and the transfer alone (true weights) is the smallest error; the actor's
    identity fitted to a neutral scan (what a user has) lies between the true identity and the generic face."""
    import csv

    from facegeom.bench import character as bc

    r = bc.run(face_model, real_takes[:1], tmp_path, cases=1, frames=60)
    assert [x["route"] for x in r["rows"]] == list(bc.ROUTES)
    err = {x["route"]: x["face_median_mm"] for x in r["rows"]}
    print(err)
    ours, fitted, generic, copy = err[bc.OWN], err[bc.FITTED], err[bc.GENERIC], err[bc.COPY]
    transfer_only, markers = err[bc.TRUE_WEIGHTS], err[bc.PROPOSED]
    assert transfer_only < ours < 0.5 * min(generic, copy)
    assert ours < 1.0  # mm, at the character's size
    assert ours < fitted < 0.75 * generic  # a fitted identity: worse than the true one, better than none
    assert markers < min(generic, copy)  # the marker route needs no actor identity: its labels carry the character
    identity = {x["route"]: x["identity_rms_mm"] for x in r["rows"]}
    assert 0.0 < identity[bc.FITTED] < 2.0  # mm: the scan fit is close to the actor's neutral, not exact
    assert all(np.isnan(v) for k, v in identity.items() if k != bc.FITTED)
    assert set(bc.MARKER_ROUTES) <= set(bc.ROUTES)
    with open(tmp_path / "character.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [x["route"] for x in rows] == list(bc.ROUTES) and "identity_rms_mm" in rows[0]
    summary = (tmp_path / "character-summary.md").read_text()
    assert bc.FITTED in summary and "neutral scan" in summary


def test_marker_route_onto_a_bare_head_with_edited_key_labels(face_model, real_takes, tmp_path, capsys,
                                                              validator_env, scanned_head_rig):
    """No rig needed: a scanned head, transferred once (its registration stored with the rig), driven through
    markers retargeted from listed key frames; the labels saved, one edited, read back: the character follows."""
    from facegeom.cli.main import main
    from facegeom.io.gltf import read_glb_animation
    from facegeom.io.key_labels import read_key_labels, write_key_labels

    rig = scanned_head_rig  # lee_perry_smith.ply after `facegeom transfer` (the registration stored with it)
    capsys.readouterr()
    take = str(real_takes[0])
    base = ["animate", "--take", take, "--character", str(rig), "--route", "markers", "--frames", "60", "--start",
            "10"]
    main([*base, "--keys", "10,30,50,69", "--save-key-labels", str(tmp_path / "k.csv"), "-o", str(tmp_path / "a.glb")])
    out = capsys.readouterr().out
    assert "stored with the rig" in out and "4 key frames (0, 20, 40, 59)" in out and "every vertex within" in out
    issues = validate(validator_env, tmp_path / "a.glb")
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0

    def played(name):
        anim = read_glb_animation(tmp_path / name)
        K, n = anim.deltas.shape[:2]
        return anim.neutral[None] + (anim.weights @ anim.deltas.reshape(K, -1)).reshape(-1, n, 3)

    a = played("a.glb")
    assert a.shape == (60, 8844, 3)
    motion = np.linalg.norm(a - a.mean(axis=0), axis=2).max()  # metres
    assert 0.001 < motion < 0.05  # the face moves by millimetres to centimetres, not by the head's size
    kl = read_key_labels(tmp_path / "k.csv", 80)
    assert kl.frames.tolist() == [10, 30, 50, 69] and np.isfinite(kl.labels).all()
    m = 40  # a marker of the layout, moved 3 mm up (the rig file is in cm) at take frame 30 only
    edited = kl.labels.copy()
    edited[:] = np.nan
    edited[1, m] = kl.labels[1, m] + [0.0, 0.3, 0.0]
    write_key_labels(tmp_path / "k2.csv", kl.frames, edited, kl.vertices)
    main([*base, "--keys", "10,50,69", "--key-labels", str(tmp_path / "k2.csv"), "-o", str(tmp_path / "b.glb")])
    assert "4 key frames (0, 20, 40, 59)" in capsys.readouterr().out
    b = played("b.glb")
    v = int(kl.vertices[m])
    moved = (b - a)[:, v]  # metres, per frame
    # the edited key: the marker's vertex follows the new label, in part: the default deformer takes markers as
    # noisy (self-tuned soft labels), and one marker moved alone is partly smoothed away (about 40% kept)
    assert 0.0009 < moved[20, 1] < 0.0045 and np.abs(moved[20, [0, 2]]).max() < 0.3 * moved[20, 1]
    assert np.abs(moved[[0, 59], 1]).max() < 0.3 * moved[20, 1]  # the other keys keep their labels
    # the retargeted markers themselves carry the edit exactly at its key, and not at the others
    from facegeom.pipelines.character import read_head, stored_registration
    from facegeom.pipelines.character_markers import markers_onto_character, take_markers

    X, X0, ids = take_markers(face_model, take, 10, 60)
    V, F, _ = read_head(rig)
    route = markers_onto_character(face_model, X, X0, ids, V, F, keys=np.array([0, 20, 40, 59]),
                                   character=stored_registration(face_model, rig, V, F))
    np.testing.assert_allclose(route.labels, kl.labels, atol=1e-9)  # what was saved is what it proposes
    labels = np.full_like(route.labels, np.nan)
    labels[1, m] = edited[1, m]
    dY = route.relabel(labels).markers - route.markers
    np.testing.assert_allclose(dY[20, m], [0.0, 0.3, 0.0], atol=1e-6)
    assert np.abs(dY[[0, 40, 59]]).max() < 1e-6
    # edited labels (the viewer's) meet the head as a file's do: squashed to a point or a plane, or far off, refused
    for change, words in ((lambda L: L.__setitem__(1, route.labels[1].mean(axis=0)), "one point"),
                          (lambda L: L.__setitem__(1, route.labels[1] * [1.0, 1.0, 0.0]), "one plane"),
                          (lambda L: L[1, m].__setitem__(slice(None), 1e6), "outside the head")):
        bad = np.full_like(route.labels, np.nan)
        change(bad)
        with pytest.raises(InputError, match=f"key frame 20: .*{words}"):
            route.relabel(bad)
    for args, words in ((["-o", str(tmp_path / "m.csv")], "animated .glb"),
                        (["--rig", str(CHARACTER), "-o", str(tmp_path / "x.glb")], "--rig"),
                        (["--keys", "12,90", "-o", str(tmp_path / "x.glb")], "outside the window"),
                        (["--keys", "10,x", "-o", str(tmp_path / "x.glb")], "--keys"),
                        (["--key-labels", str(tmp_path / "none.csv"), "-o", str(tmp_path / "x.glb")], "not found")):
        with pytest.raises(SystemExit) as exc:
            main([*base, *args])
        err = capsys.readouterr().err
        assert exc.value.code == 2 and words in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "x.glb").exists()


def test_key_frames_cover_the_performance():
    from facegeom.pipelines.character_markers import key_frames

    t = np.linspace(0, 1, 200)
    X = np.zeros((200, 3, 3))
    X[:, 0, 0] = np.sin(6 * t)  # extremes near 26, 78, 130, 183
    X[:, 1, 1] = (t > 0.9) * 2.0  # a late pose, far from all others
    k = key_frames(X, 4)
    assert k.size == 4 and np.all(np.diff(k) > 0)
    assert np.any(k >= 180)  # the late pose is a key
    assert np.abs(X[k[0]] - np.median(X, axis=0)).max() < 0.1  # the first key is the rest pose


def test_marker_route_onto_a_head_in_pieces(real_takes, tmp_path, capsys):
    """The MakeHuman head has eyes, teeth and a tongue as parts, no marker on them: the skin is driven, the lower
    teeth and tongue follow the jaw rigidly, the eyes and upper teeth the skull (this stopped with '5 connected
    part(s) of the data have no label')."""
    from facegeom.cli.main import main
    from facegeom.io import ict_weights
    from facegeom.io.gltf import read_glb_animation
    from facegeom.io.takes import read_take
    from facegeom.methods.pieces import split_pieces
    from facegeom.model import load_face_model
    from facegeom.pipelines.character import read_head
    from facegeom.registration import kabsch

    take = real_takes[0]
    names = list(load_face_model(None).expression_names)
    jaw_open = ict_weights(read_take(take), names)[:, names.index("jawOpen")]
    start = int(np.clip(np.argmax(jaw_open) - 60, 0, jaw_open.size - 120))  # a window where the jaw opens
    jaw_open = jaw_open[start:start + 120]
    main(["animate", "--take", str(take), "--character", str(CHARACTER), "--route", "markers", "--frames", "120",
          "--start", str(start), "-o", str(tmp_path / "m.glb")])
    out = capsys.readouterr().out
    assert "teeth_lower: jaw" in out and "eye_L: eye" in out and "every vertex within" in out
    anim = read_glb_animation(tmp_path / "m.glb")
    K, n = anim.deltas.shape[:2]
    X = anim.neutral[None] + (anim.weights @ anim.deltas.reshape(K, -1)).reshape(-1, n, 3)  # metres
    V, F, parts = read_head(CHARACTER)
    assert X.shape == (120, V.shape[0], 3)
    np.testing.assert_allclose(anim.neutral, V / 100.0, atol=1e-6)  # cm -> m, at rest
    pieces = {p.name: p for p in split_pieces(V, F, parts)}
    for name in ("teeth_upper", "teeth_lower", "tongue", "eye_L", "eye_R"):
        ids = pieces[name].vertices
        for t in range(0, 120, 10):  # rigid, within the .glb's 0.1 mm encoding bound
            R, tt = kabsch(V[ids] / 100.0, X[t, ids])
            assert np.abs(V[ids] / 100.0 @ R.T + tt - X[t, ids]).max() < 2e-4, (name, t)
    drop = -(X[:, pieces["teeth_lower"].vertices, 1] - V[pieces["teeth_lower"].vertices, 1] / 100.0).mean(axis=1)
    assert np.corrcoef(drop, jaw_open)[0, 1] > 0.8  # the lower teeth come down as the jaw opens
    upper = np.linalg.norm(X[:, pieces["teeth_upper"].vertices] - V[pieces["teeth_upper"].vertices] / 100.0, axis=2)
    assert upper.max() < 0.5 * np.abs(drop).max() + 1e-4  # the upper teeth stay with the skull
