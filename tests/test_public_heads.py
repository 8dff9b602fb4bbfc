"""`facegeom transfer` on public heads no one here made: a validated .glb rig for each.

- ``lee_perry_smith.ply``: a scanned head and shoulders (Infinite-Realities, CC BY 3.0), metres, one closed surface;
- ``makehuman_arkit.npz``: the MakeHuman head (CC0) with eyes, teeth and tongue as parts;
- ``makehuman_stylised_arkit.npz``: the same pushed to a cartoon's proportions by MakeHuman's own modifiers.

Sources and licences: ``tests/data/heads/SOURCES.md``. Each head goes through the
command a user runs; the rig it writes is opened by the Khronos glTF-Validator
(no error, no warning) and read back; the shapes move the right places (the chin
down for ``jawOpen``, the left eye's lids for ``eyeBlink_L``).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.conftest import validate

HEADS = Path(__file__).parent / "data" / "heads"


@pytest.mark.parametrize("name,extra", [
    ("lee_perry_smith.ply", []),
    ("makehuman_arkit.npz", ["--arkit-names", "--piece", "tongue=stay"]),
    ("makehuman_stylised_arkit.npz", []),
])
def test_transfer_writes_a_valid_glb_rig(face_model, validator_env, tmp_path, capsys, name, extra):
    from facegeom.cli.main import main
    from facegeom.io.gltf import read_gltf_rig

    out = tmp_path / (Path(name).stem + ".glb")
    main(["transfer", str(HEADS / name), "-o", str(out), *extra])  # a user error would exit (SystemExit)
    text = capsys.readouterr().out
    print(text)
    issues = validate(validator_env, out)
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0
    rig = read_gltf_rig(out)
    names = list(rig.names)
    arkit = "--arkit-names" in extra
    assert len(names) == (51 if arkit else 53)
    if arkit:
        assert "tongueOut left out" in text and "tongue: stay (given" in text
    V = rig.neutral  # metres, Y up (glTF)
    jaw = rig.deltas[names.index("jawOpen")]
    blink = rig.deltas[names.index("eyeBlinkLeft" if arkit else "eyeBlink_L")]
    moved = np.linalg.norm(jaw, axis=1)
    low = V[moved > 0.5 * moved.max()]
    assert jaw[moved > 0.5 * moved.max(), 1].mean() < -0.004  # the chin goes down by more than 4 mm
    assert low[:, 1].mean() < np.median(V[:, 1])  # in the lower part of the head
    b = np.linalg.norm(blink, axis=1)
    lids = V[b > 0.5 * b.max()]
    assert 0.002 < b.max() < 0.03  # a lid's travel: millimetres, not the head's size
    # the left eye is the performer's left: +x in these files (each faces +z)
    assert lids[:, 0].mean() > V[:, 0].mean()


def test_a_second_head_is_refused_and_nothing_written(face_model, tmp_path, capsys):
    """Two heads side by side in one file: one line naming the file and the piece; no rig written."""
    from facegeom.cli.main import main
    from facegeom.io.mesh import read_mesh, write_mesh

    V, F = read_mesh(HEADS / "lee_perry_smith.ply")
    two = tmp_path / "two.obj"
    write_mesh(two, np.r_[V, V + [0.6, 0.0, 0.0]], np.r_[F, F + len(V)])
    with pytest.raises(SystemExit) as exc:
        main(["transfer", str(two), "-o", str(tmp_path / "rig.glb")])
    err = capsys.readouterr().err
    assert exc.value.code == 2, err
    assert "two.obj" in err and "a second head? 'piece 2'" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "rig.glb").exists()


def test_a_head_with_a_hole_and_a_non_manifold_fin_transfers(face_model, tmp_path, capsys):
    """Scans arrive with holes and stray faces: the skull opened at the back, a fin on a shared edge, a face twice."""
    from facegeom.cli.main import main
    from facegeom.io.mesh import read_mesh, write_mesh
    from facegeom.model.rig import BlendshapeRig

    V, F = read_mesh(HEADS / "lee_perry_smith.ply")
    c = V[F].mean(axis=1)
    F = F[~((c[:, 2] < -0.05) & (c[:, 1] > 0.0) & (np.abs(c[:, 0]) < 0.04))]
    e = F[0, :2]
    V = np.r_[V, [V[e].mean(axis=0) + [0.0, 0.01, 0.0]]]
    F = np.r_[F, [[e[0], e[1], len(V) - 1], [e[1], e[0], len(V) - 1]], F[:1]]
    path = tmp_path / "scan.obj"
    write_mesh(path, V, F)
    main(["transfer", str(path), "-o", str(tmp_path / "rig.npz")])
    text = capsys.readouterr().out
    assert "of the face on the mesh" in text
    rig = BlendshapeRig.from_npz(tmp_path / "rig.npz")
    assert rig.n_vertices == len(V) and np.isfinite(rig.deltas).all()
    jaw = rig.deltas[list(rig.names).index("jawOpen")]
    assert 1.0 < np.linalg.norm(jaw, axis=1).max() < 5.0  # centimetres: the rig file is in facegeom's cm
    np.testing.assert_allclose(rig.neutral, V * 100.0, atol=1e-9)  # the scan is metres, Y up, facing +Z
