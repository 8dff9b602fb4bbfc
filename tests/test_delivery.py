"""What is delivered is what was solved: USD wherever .glb is written, the head's motion played by the viewer, a
character placed where its rig puts it, takes keeping their timecode."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

CHARACTER = Path(__file__).parent / "data" / "heads" / "makehuman_arkit.npz"


@pytest.fixture(scope="module")
def capture(tmp_path_factory, face_model):
    """An actor's 80-marker capture: jaw and smile, the head turning, 160 cm up and facing sideways."""
    from facegeom.io.markerseq import write_marker_sequence
    from facegeom.model import BlendshapeRig
    from facegeom.model.layouts import ict80

    d = tmp_path_factory.mktemp("delivery")
    rig = BlendshapeRig.from_face_model(face_model)
    ids = ict80(face_model)
    T = 24
    W = np.zeros((T, rig.n_shapes))
    W[:, rig.shape_index("jawOpen")] = 0.5 + 0.4 * np.sin(np.linspace(0, 3, T))
    W[:, rig.shape_index("mouthSmile_L")] = np.linspace(0, 0.8, T)
    R = (Rotation.from_euler("y", 90, degrees=True)
         * Rotation.from_euler("xy", np.c_[np.linspace(-10, 10, T), np.linspace(0, 25, T)], degrees=True)).as_matrix()
    t = np.c_[np.linspace(0, 4, T), np.zeros(T), np.zeros(T)] + (200.0, 160.0, -50.0)
    X = np.einsum("tij,tpj->tpi", R, rig.neutral[ids][None] + np.einsum("tb,bpi->tpi", W, rig.deltas[:, ids]))
    write_marker_sequence(d / "cap.npz", X + t[:, None], names=[f"v{i}" for i in ids])
    from facegeom.io.c3d import write_c3d

    write_c3d(d / "cap.c3d", (X + t[:, None]) * 10.0, [f"v{i}" for i in ids], fps=60.0, unit="mm")  # states its unit
    return d, rig, W


def test_the_viewer_plays_the_head_motion_of_a_glb(capture, tmp_path):
    """``view animate --input c.glb`` plays frames through :func:`read_animation`: the node's rotation and
    translation are applied, as Blender and three.js apply them."""
    from facegeom.cli.main import main
    from facegeom.io.gltf import read_glb_animation
    from facegeom.pipelines.solve import GLB_SCALE, read_animation

    d, _, _ = capture
    main(["solve", str(d / "cap.npz"), "--character", str(CHARACTER), "--smooth", "off", "-o", str(tmp_path / "c.glb")])
    z_out = tmp_path / "c.npz"
    main(["solve", str(d / "cap.npz"), "--character", str(CHARACTER), "--smooth", "off", "-o", str(z_out)])
    z = np.load(z_out)
    g = read_glb_animation(tmp_path / "c.glb")
    assert g.rotations is not None and g.rotations.shape == (24, 3, 3)
    np.testing.assert_allclose(g.rotations, z["rotations"], atol=1e-5)
    np.testing.assert_allclose(g.translations / GLB_SCALE, z["translations"], atol=1e-3)
    anim = read_animation(tmp_path / "c.glb")
    yaw = [Rotation.from_matrix(anim.rotations[i]).as_euler("YXZ", degrees=True)[0] for i in (0, 23)]
    assert yaw[1] - yaw[0] > 20  # the head turns 25 degrees over the take
    for i in (0, 12, 23):
        still = anim.neutral + np.tensordot(anim.weights[i], anim.deltas, axes=1)
        np.testing.assert_allclose(anim.frame(i), still @ anim.rotations[i].T + anim.translations[i], atol=1e-9)
    # placed where its rig puts it: the played face stays within a head's size of the rig's own neutral
    centre = anim.neutral.mean(axis=0)
    assert max(np.linalg.norm(anim.frame(i).mean(axis=0) - centre) for i in range(24)) < 15.0  # cm


@pytest.mark.parametrize("suffix", [".usda", ".usdc", ".usdz"])
def test_solve_writes_usd_that_plays_as_the_glb(capture, tmp_path, suffix):
    pytest.importorskip("pxr", reason="USD needs usd-core: pip install 'facegeom[usd]'")
    from facegeom.cli.main import main
    from facegeom.io.usd import read_usd_rig, usd_validation_errors
    from facegeom.pipelines.solve import read_animation

    d, _, _ = capture
    for out in ("c.glb", f"c{suffix}"):
        main(["solve", str(d / "cap.npz"), "--character", str(CHARACTER), "--smooth", "off", "-o",
              str(tmp_path / out)])
    errors, _ = usd_validation_errors(tmp_path / f"c{suffix}")
    assert errors == []
    u = read_usd_rig(tmp_path / f"c{suffix}")
    assert u.meters_per_unit == 1.0 and u.up_axis == "Y" and u.normal_deltas is not None
    a, b = read_animation(tmp_path / "c.glb"), read_animation(tmp_path / f"c{suffix}")
    assert a.names == b.names and a.fps == pytest.approx(b.fps)
    for i in (0, 11, 23):
        np.testing.assert_allclose(b.frame(i), a.frame(i), atol=2e-4)  # cm: both float32 in metres


def test_usd_rigs_are_read_wherever_rigs_are(face_model, capture, tmp_path, capsys):
    """A rig written as USD is a rig for ``solve --rig`` (and a head for ``transfer``)."""
    pytest.importorskip("pxr", reason="USD needs usd-core: pip install 'facegeom[usd]'")
    from facegeom.cli.main import main
    from facegeom.io.delivery import write_rig_animation
    from facegeom.pipelines.character import read_head

    d, rig, W = capture
    usd = write_rig_animation(tmp_path / "ict.usdc", rig.neutral * 0.01, rig.triangles, rig.deltas * 0.01,
                              rig.names, np.zeros((1, rig.n_shapes)), 30.0)
    main(["solve", str(d / "cap.c3d"), "--rig", str(usd), "--smooth", "off", "-o", str(tmp_path / "w.npz")])
    out = capsys.readouterr().out
    assert "units m (stated by the file)" in out
    w = np.load(tmp_path / "w.npz")
    np.testing.assert_allclose(w["weights"][:, list(w["names"]).index("jawOpen")], W[:, rig.shape_index("jawOpen")],
                               atol=1e-3)
    V, F, _ = read_head(usd)
    np.testing.assert_allclose(V, rig.neutral * 0.01, atol=1e-6)


def test_live_records_the_character_as_usd(tmp_path):
    pytest.importorskip("pxr", reason="USD needs usd-core: pip install 'facegeom[usd]'")
    from facegeom.cli.main import main
    from facegeom.io.usd import read_usd_rig

    rec = Path(__file__).parent / "data" / "livelink" / "debug-jawleft.gesichter"
    main(["live", "--replay", str(rec), "--character", str(CHARACTER), "--record", str(tmp_path / "c.usda"),
          "--quiet"])
    u = read_usd_rig(tmp_path / "c.usda")
    assert u.weights.shape == (66, 52) and u.weights[:, list(u.names).index("jawLeft")].max() == pytest.approx(1.0)


def test_takes_keep_their_timecode(face_model, tmp_path):
    """A take starting at 10:17:23:12 played on a character, and replayed live and recorded, starts there too."""
    from facegeom.cli.main import main
    from facegeom.io.takes import ARKIT_NAMES, read_take, write_livelink_csv

    T, fps = 90, 60.0
    W = np.zeros((T, len(ARKIT_NAMES)))
    W[:, ARKIT_NAMES.index("JawOpen")] = np.linspace(0, 1, T)
    start = 10 * 3600 + 17 * 60 + 23 + 12 / fps
    take = write_livelink_csv(tmp_path / "take.csv", W, ARKIT_NAMES, fps, start=start)
    assert read_take(take).start_s == pytest.approx(start, abs=1e-6)
    main(["animate", "--take", str(take), "--character", str(CHARACTER), "--start", "30", "--frames", "40", "-o",
          str(tmp_path / "out.csv")])
    back = read_take(tmp_path / "out.csv")
    assert back.start_s == pytest.approx(start + 30 / fps, abs=1e-6) and back.n_frames == 40
    main(["live", "--replay", str(take), "--record", str(tmp_path / "live.csv"), "--quiet"])
    live = read_take(tmp_path / "live.csv")
    assert live.start_s == pytest.approx(start, abs=1e-6)


def test_a_take_on_the_character_as_usd(tmp_path):
    pytest.importorskip("pxr", reason="USD needs usd-core: pip install 'facegeom[usd]'")
    from facegeom.cli.main import main
    from facegeom.io.takes import ARKIT_NAMES, write_livelink_csv
    from facegeom.pipelines.solve import read_animation

    W = np.zeros((20, len(ARKIT_NAMES)))
    W[:, ARKIT_NAMES.index("JawOpen")] = np.linspace(0, 1, 20)
    take = write_livelink_csv(tmp_path / "take.csv", W, ARKIT_NAMES, 30.0)
    main(["animate", "--take", str(take), "--character", str(CHARACTER), "-o", str(tmp_path / "a.usdz")])
    a = read_animation(tmp_path / "a.usdz")
    assert a.n_frames == 20 and a.fps == pytest.approx(30.0)
    np.testing.assert_allclose(a.weights[:, a.names.index("jawOpen")], np.linspace(0, 1, 20), atol=1e-6)
