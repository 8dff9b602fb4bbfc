"""A user's own rig: OBJ folders with any neutral name, glTF, npz; ARKit names; units and up axis; the CLI options.

The rigs are made here from the ICT face data: its shapes renamed to ARKit's camelCase, the brow and puff pairs
merged into ARKit's one shape each, saved as ``Neutral.obj`` + ``eyeBlinkLeft.obj`` ... (and again in mm, Z-up).
"""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from facegeom.errors import InputError
from facegeom.io import read_mesh, write_mesh
from facegeom.io.markerseq import write_marker_sequence
from facegeom.io.shape_names import ARKIT_CAMEL_NAMES, ARKIT_NAMES, ICT_NAMES, arkit_to_ict_name
from facegeom.io.takes import read_take
from facegeom.model import BlendshapeRig, load_rig
from facegeom.model.layouts import ict80
from facegeom.model.rig import find_neutral
from facegeom.model.units import RigFrame, find_up, rig_frame

from .conftest import grid_mesh


def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "facegeom", *map(str, args)], capture_output=True, text=True,
                          timeout=300, cwd=cwd)


def arkit_rig(face_model) -> BlendshapeRig:
    """The ICT rig with ARKit names (camelCase): 51 shapes, browInnerUp / cheekPuff = the sum of ICT's two sides."""
    ict = BlendshapeRig.from_face_model(face_model)
    names, deltas = [], []
    for a in ARKIT_CAMEL_NAMES:
        parts = arkit_to_ict_name(a)
        if parts:
            names.append(a)
            deltas.append(sum(ict.deltas[ict.shape_index(n)] for n in parts))
    return BlendshapeRig(ict.neutral, np.array(deltas), names, ict.triangles, ict.landmark_ids)


def write_folder(folder, rig, frame=None, neutral="Neutral", rename=None):
    folder.mkdir(parents=True, exist_ok=True)
    to = (lambda X: X) if frame is None else frame.to_source
    write_mesh(folder / f"{neutral}.obj", to(rig.neutral), rig.triangles)
    for name, d in zip(rig.names, rig.deltas):
        write_mesh(folder / f"{(rename or {}).get(name, name)}.obj", to(rig.neutral + d), rig.triangles)
    return folder


MM_ZUP = RigFrame("mm", "z")


@pytest.fixture(scope="module")
def rigs(tmp_path_factory, face_model):
    """The ARKit rig in memory, as an OBJ folder (cm, Y-up) and as one in mm, Z-up; a capture of it."""
    d = tmp_path_factory.mktemp("rigs")
    rig = arkit_rig(face_model)
    write_folder(d / "arkit", rig)
    write_folder(d / "arkit_mm", rig, MM_ZUP)
    write_folder(d / "custom", rig, rename={"mouthSmileLeft": "Smile_L_v2"})
    ids = ict80(face_model)
    T = 30
    t = np.linspace(0, 1, T)
    W = np.zeros((T, rig.n_shapes))
    for name, curve in (("jawOpen", 0.6 * t), ("eyeBlinkLeft", 0.9 * t ** 2), ("browInnerUp", 0.5 * np.sin(3 * t)),
                        ("cheekPuff", 0.4 * t), ("mouthSmileLeft", 0.7 * (1 - t))):
        W[:, rig.shape_index(name)] = curve
    rng = np.random.default_rng(3)
    R = Rotation.from_rotvec(rng.normal(0, 0.2, (T, 3))).as_matrix()
    X = np.einsum("tij,tpj->tpi", R, rig.neutral[ids][None] + np.einsum("tb,bpi->tpi", W, rig.deltas[:, ids]))
    X = X + rng.normal(0, 3, (T, 3))[:, None]
    write_marker_sequence(d / "cap.npz", X, names=[f"v{i}" for i in ids])  # no unit: the rig's (cm)
    write_marker_sequence(d / "cap_mm.npz", MM_ZUP.to_source(X), names=[f"v{i}" for i in ids])  # the mm rig's own
    return d, rig, W


def by_rig_names(take, rig):
    """A Live Link take's columns in the rig's shape order (ARKit camelCase -> PascalCase)."""
    return take.weights[:, [ARKIT_NAMES.index(n[0].upper() + n[1:]) for n in rig.names]]


# ----------------------------------------------------------------------------- loading


def test_arkit_folder_loads_with_its_names_and_a_note(rigs):
    d, rig, _ = rigs
    notes = []
    got = load_rig(d / "arkit", notes=notes)
    assert got.names == tuple(sorted(rig.names))  # by file name
    order = [rig.shape_index(n) for n in got.names]
    assert np.abs(got.deltas - rig.deltas[order]).max() < 1e-5 and np.abs(got.neutral - rig.neutral).max() < 1e-5
    assert got.frame.units == "cm" and got.frame.up == "y" and got.frame.is_identity
    (line,) = notes
    for part in ("rig arkit: 51 shapes", "neutral Neutral.obj", "units cm (found", "up Y (found",
                 "ARKit camelCase", "51 of 51"):
        assert part in line, line
    assert "lacks" not in line and "no ICT expression drives" not in line


def test_mm_zup_rig_is_recognised_converted_and_reported(rigs):
    d, rig, _ = rigs
    notes = []
    got = load_rig(d / "arkit_mm", notes=notes)
    ref = load_rig(d / "arkit")
    assert got.frame.units == "mm" and got.frame.up == "z" and not got.frame.turned
    assert np.abs(got.neutral - ref.neutral).max() < 1e-4 and np.abs(got.deltas - ref.deltas).max() < 1e-4
    assert "units mm (found" in notes[0] and "up Z (found: the moving surface faces -Y)" in notes[0]
    assert "converted to cm, Y-up" in notes[0]
    # what is given wins over what is found
    notes = []
    given = load_rig(d / "arkit_mm", units="cm", up="z", notes=notes)
    assert given.frame.units_how == "given" and "units cm (given)" in notes[0]
    assert np.abs(given.neutral - 10 * ref.neutral).max() < 1e-3


@pytest.mark.parametrize("frame", [RigFrame("cm", "y"), RigFrame("m", "z"), RigFrame("mm", "y", turned=True),
                                   RigFrame("cm", "z", turned=True)])
def test_units_and_up_are_found(face_model, frame):
    rig = BlendshapeRig.from_face_model(face_model)
    V, D = frame.to_source(rig.neutral), frame.to_source(rig.deltas)
    found = rig_frame(V, rig.triangles, D)
    assert (found.units, found.up, found.turned) == (frame.units, frame.up, frame.turned)
    np.testing.assert_allclose(found.to_facegeom(V), rig.neutral, atol=1e-9)
    # without shapes, the up axis comes from the bounding box (and the facing is not told)
    up, why, facing = find_up(V)
    assert up == frame.up and "taller" in why and facing is None


def test_units_follow_the_stated_rule():
    """RMS radius 0.7-22 in the file's numbers: cm; above: mm; below: m (the reference 7 cm, log-nearest)."""
    base = np.random.default_rng(0).normal(size=(500, 3))
    base /= np.sqrt(((base - base.mean(0)) ** 2).sum(1).mean())  # RMS radius 1
    for size, unit in [(0.5, "m"), (0.9, "cm"), (7.0, "cm"), (20.0, "cm"), (25.0, "mm"), (600.0, "mm"), (0.08, "m")]:
        assert rig_frame(base * size).units == unit, size


def test_neutral_found_whatever_its_name(tmp_path):
    V, F = grid_mesh(5, 5, bump=0.2)
    for stem in ("neutral", "Neutral", "base", "Base", "neutral_mesh", "default", "BASIS"):
        folder = tmp_path / stem
        folder.mkdir()
        write_mesh(folder / f"{stem}.obj", V, F)
        write_mesh(folder / "jawOpen.obj", V + [0, -0.1, 0], F)
        assert find_neutral(folder).name == f"{stem}.obj"
        r = BlendshapeRig.from_obj_folder(folder)
        assert r.names == ("jawOpen",) and np.allclose(r.deltas[0], [0, -0.1, 0])
    folder = tmp_path / "named"
    folder.mkdir()
    write_mesh(folder / "Rest_Pose.obj", V, F)
    write_mesh(folder / "smile.obj", V + [0.1, 0, 0], F)
    with pytest.raises(InputError, match=r"named: no neutral mesh among its 2 OBJ files .*pass neutral=NAME\): "
                                         r"Rest_Pose\.obj, smile\.obj$"):
        BlendshapeRig.from_obj_folder(folder)
    assert BlendshapeRig.from_obj_folder(folder, "rest_pose").names == ("smile",)  # any case, with or without .obj
    assert load_rig(folder, neutral="Rest_Pose.obj").names == ("smile",)
    with pytest.raises(InputError, match=r"no neutral mesh 'Rest\.obj' in the folder \(its OBJ files: Rest_Pose\.obj, "
                                         r"smile\.obj\)"):
        load_rig(folder, neutral="Rest")
    write_mesh(folder / "Base.obj", V, F)
    write_mesh(folder / "neutral.obj", V, F)
    with pytest.raises(InputError, match=r"2 neutral candidates, Base\.obj, neutral\.obj; pass neutral=NAME"):
        load_rig(folder)
    write_mesh(folder / "small.obj", V[:10], F[:4])
    with pytest.raises(InputError, match=r"small\.obj: has 10 vertices but the neutral 'neutral\.obj' has 25$"):
        load_rig(folder, neutral="neutral")


def test_options_that_need_a_rig_file(tmp_path, face_model):
    with pytest.raises(InputError, match=r"neutral=NAME and units=mm\|cm\|m describe a rig file or folder"):
        load_rig(None, lambda: face_model, neutral="base", units="mm")
    rig = BlendshapeRig.from_face_model(face_model)
    rig.save_npz(tmp_path / "r.npz")
    with pytest.raises(InputError, match=r"r\.npz: units must be auto, mm, cm or m, got 'inch'"):
        load_rig(tmp_path / "r.npz", units="inch")
    with pytest.raises(InputError, match=r"r\.npz: neutral=NAME names the neutral OBJ of a rig folder"):
        load_rig(tmp_path / "r.npz", neutral="base")
    with pytest.raises(InputError, match=r"up axis must be auto, y or z"):
        load_rig(tmp_path / "r.npz", up="x")


def test_npz_round_trip_keeps_frame_parts_and_mapping(tmp_path, rigs):
    from facegeom.io.gltf import RigPart
    from facegeom.io.shape_names import read_name_mapping

    d, rig, _ = rigs
    (tmp_path / "map.csv").write_text("rig_shape,source_shape,gain\njawOpen,jawOpen,0.5\n")
    parts = [RigPart("face", 0, 6706, 0, 10000, True), RigPart("rest", 6706, rig.n_vertices, 10000,
                                                                 rig.triangles.shape[0], False)]
    r = BlendshapeRig(rig.neutral, rig.deltas, rig.names, rig.triangles, parts=parts,
                      name_map=read_name_mapping(tmp_path / "map.csv"), frame=RigFrame("mm", "z"))
    r.save_npz(tmp_path / "r.npz")
    back = BlendshapeRig.from_npz(tmp_path / "r.npz")
    assert back.parts == tuple(parts) and back.name_map == r.name_map
    assert (back.frame.units, back.frame.up) == ("cm", "y")  # the arrays are stored in facegeom's frame
    assert np.array_equal(back.deltas, r.deltas)
    notes = []
    load_rig(tmp_path / "r.npz", notes=notes)
    assert "units cm (stated by the file)" in notes[0] and "2 parts (face, rest)" in notes[0]
    # every rig file states facegeom's frame; one of an earlier release (no such keys) is read in it too
    BlendshapeRig(rig.neutral, rig.deltas, rig.names, rig.triangles).save_npz(tmp_path / "plain.npz")
    with np.load(tmp_path / "plain.npz") as z:
        assert str(z["units"]) == "cm" and "part_names" not in z.files
        old = {k: z[k] for k in z.files if k not in ("units", "up")}
    np.savez(tmp_path / "old.npz", **old)
    for f in ("plain.npz", "old.npz"):
        loaded = load_rig(tmp_path / f)
        assert (loaded.frame.units, loaded.frame.up) == ("cm", "y") and np.array_equal(loaded.neutral, rig.neutral)
    with pytest.raises(InputError, match=r"part 'x': vertices \[0, 99999\)"):
        BlendshapeRig(rig.neutral, rig.deltas, rig.names, rig.triangles, parts=[RigPart("x", 0, 99999, 0, 1, True)])


def test_gltf_rig_loads_with_its_parts(tmp_path, rigs):
    from facegeom.io import gltf

    d, rig, _ = rigs
    gltf.write_rig_glb(tmp_path / "rig.glb", rig.neutral * 0.01, rig.triangles, rig.deltas * 0.01, rig.names,
                       np.zeros((2, rig.n_shapes)), 30.0)
    notes = []
    got = load_rig(tmp_path / "rig.glb", notes=notes)
    assert got.names == rig.names and np.abs(got.neutral - rig.neutral).max() < 1e-4  # metres -> cm
    assert got.frame.units == "m" and "units m (stated by the file), up Y (stated by the file)" in notes[0]
    assert got.parts and got.parts[0].vertex_stop == rig.n_vertices
    got.save_npz(tmp_path / "rig.npz")
    assert load_rig(tmp_path / "rig.npz").parts == got.parts


def test_arkit_rig_reproduces_the_ict_face_through_its_map(rigs, face_model):
    d, rig, _ = rigs
    ict = BlendshapeRig.from_face_model(face_model)
    w = np.random.default_rng(1).uniform(0, 1, 53)
    for b in ("browInnerUp", "cheekPuff"):
        w[ICT_NAMES.index(b + "_R")] = w[ICT_NAMES.index(b + "_L")]
    mine = rig.map_from(ICT_NAMES).apply(w)
    np.testing.assert_allclose(rig.evaluate(mine), ict.evaluate(w), atol=1e-9)
    np.testing.assert_allclose(rig.map_to(ICT_NAMES).apply(mine), w, atol=1e-12)
    assert rig.map_to(ARKIT_NAMES).unmapped_rig == ("TongueOut",)


def test_names_mapping_on_load(tmp_path, rigs):
    d, rig, _ = rigs
    (tmp_path / "map.csv").write_text("rig_shape,source_shape,gain\nSmile_L_v2,mouthSmileLeft,\n")
    notes = []
    plain = load_rig(d / "custom", notes=notes)
    assert "its shapes no ICT expression drives: Smile_L_v2" in notes[0]
    assert "ICT expressions it lacks: mouthSmile_L" in notes[0]
    notes = []
    mapped = load_rig(d / "custom", names=tmp_path / "map.csv", notes=notes)
    assert mapped.names == plain.names and "1 shape mapped by map.csv" in notes[0]
    assert "no ICT expression drives" not in notes[0] and "lacks" not in notes[0]
    (tmp_path / "bad.csv").write_text("rig_shape,source_shape,gain\nSmile_L_v3,mouthSmileLeft,1\n")
    with pytest.raises(InputError, match=r"bad\.csv: line 2: 'Smile_L_v3' is not a shape of the rig"):
        load_rig(d / "custom", names=tmp_path / "bad.csv")


# ----------------------------------------------------------------------------- the command line


def test_solve_with_an_arkit_folder_writes_right_live_link_columns(rigs):
    d, rig, W = rigs
    r = run("solve", d / "cap.npz", "--rig", d / "arkit", "-o", d / "take.csv", "--smooth", "off")
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0].startswith("rig arkit: 51 shapes") and "ARKit camelCase" in lines[0]
    assert "take.csv: ARKit columns no shape of the rig reaches, written as 0: TongueOut" in r.stdout
    take = read_take(d / "take.csv")
    assert np.abs(by_rig_names(take, rig) - W).max() < 1e-6
    assert (take.weights[:, ARKIT_NAMES.index("TongueOut")] == 0).all()
    assert np.abs(take.weights[:, ARKIT_NAMES.index("BrowInnerUp")] - W[:, rig.shape_index("browInnerUp")]).max() < 1e-6
    r = run("solve", d / "cap.npz", "--rig", d / "arkit", "-o", d / "c.glb", "--smooth", "off")
    assert r.returncode == 0, r.stderr
    from facegeom.io.gltf import read_glb_animation

    g = read_glb_animation(d / "c.glb")
    assert g.names == tuple(sorted(rig.names))  # the rig's own names as morph targets


def test_solve_with_a_mapping_with_gains(rigs, tmp_path):
    d, rig, W = rigs
    (tmp_path / "map.csv").write_text("rig_shape,source_shape,gain\nSmile_L_v2,mouthSmileLeft\njawOpen,jawOpen,0.5\n")
    r = run("solve", d / "cap.npz", "--rig", d / "custom", "--names", tmp_path / "map.csv", "-o", tmp_path / "t.csv",
            "--smooth", "off")
    assert r.returncode == 0, r.stderr
    assert "2 shapes mapped by map.csv" in r.stdout
    take = read_take(tmp_path / "t.csv")
    smile, jaw = W[:, rig.shape_index("mouthSmileLeft")], W[:, rig.shape_index("jawOpen")]
    assert np.abs(take.weights[:, ARKIT_NAMES.index("MouthSmileLeft")] - smile).max() < 1e-6
    assert np.abs(take.weights[:, ARKIT_NAMES.index("JawOpen")] - 2 * jaw).max() < 1e-6  # rig = 0.5 x ARKit
    # without the mapping the renamed shape reaches no column, and the note says so by name
    r = run("solve", d / "cap.npz", "--rig", d / "custom", "-o", tmp_path / "u.csv", "--smooth", "off")
    assert r.returncode == 0, r.stderr
    assert "its shapes no ICT expression drives: Smile_L_v2" in r.stdout
    assert "rig shapes a Live Link take has no column for (not written): Smile_L_v2" in r.stdout
    assert (read_take(tmp_path / "u.csv").weights[:, ARKIT_NAMES.index("MouthSmileLeft")] == 0).all()


def test_solve_and_fit_on_the_mm_zup_rig(rigs, tmp_path):
    d, rig, W = rigs
    r = run("solve", d / "cap_mm.npz", "--rig", d / "arkit_mm", "-o", tmp_path / "c.npz", "--smooth", "off")
    assert r.returncode == 0, r.stderr
    assert "units mm (found" in r.stdout and "up Z (found" in r.stdout
    assert "cap_mm.npz: states no length unit; read in the rig's own unit, mm" in r.stdout
    z = np.load(tmp_path / "c.npz")
    order = [rig.shape_index(str(n)) for n in z["names"]]
    assert str(z["units"]) == "cm" and np.abs(z["weights"] - W[:, order]).max() < 1e-6
    # a fit: the target in the rig's own frame; the fitted mesh comes back in it, the weights also as ARKit's
    ref = load_rig(d / "arkit")
    face = ref.evaluate(ref.weights_from_dict({"jawOpen": 0.5, "eyeBlinkLeft": 0.8, "browInnerUp": 0.3}))
    write_mesh(tmp_path / "target.obj", MM_ZUP.to_source(face), ref.triangles)
    r = run("fit", tmp_path / "target.obj", "--rig", d / "arkit_mm", "-o", tmp_path / "w.json", "--mesh-out",
            tmp_path / "fitted.obj")
    assert r.returncode == 0, r.stderr
    assert "(the rig's own units and axes: mm, Z-up)" in r.stdout
    fitted, _ = read_mesh(tmp_path / "fitted.obj")
    assert np.abs(fitted - MM_ZUP.to_source(face)).max() < 0.05  # mm
    out = json.loads((tmp_path / "w.json").read_text())
    assert out["weights"]["browInnerUp"] == pytest.approx(0.3, abs=1e-3)
    assert out["arkit_weights"]["BrowInnerUp"] == pytest.approx(0.3, abs=1e-3)
    assert out["arkit_weights"]["JawOpen"] == pytest.approx(0.5, abs=1e-3) and out["units"] == "cm"


def test_units_up_and_neutral_options(rigs, tmp_path):
    d, rig, W = rigs
    r = run("solve", d / "cap_mm.npz", "--rig", d / "arkit_mm", "--units", "mm", "--up", "z", "--neutral", "neutral",
            "-o", tmp_path / "c.npz", "--smooth", "off")
    assert r.returncode == 0, r.stderr
    assert "units mm (given), up Z (given)" in r.stdout
    r = run("solve", d / "cap.npz", "--rig", d / "arkit", "--neutral", "rest", "-o", tmp_path / "d.npz")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert "no neutral mesh 'rest.obj'" in r.stderr and "eyeBlinkLeft.obj" in r.stderr
    r = run("fit", tmp_path / "t.obj", "--identity", "--units", "mm", "-o", tmp_path / "w.json")
    assert r.returncode == 2 and "--neutral, --names, --units and --up describe --rig" in r.stderr
    r = run("solve", d / "cap.npz", "--units", "mm", "-o", tmp_path / "e.npz")
    assert r.returncode == 2 and "--units mm|cm|m describes a rig file or folder (--rig)" in r.stderr


def test_animate_on_an_arkit_rig(rigs, tmp_path, real_takes):
    d, rig, _ = rigs
    out = tmp_path / "curves.npz"
    r = run("animate", "--rig", d / "arkit", "--frames", "40", "--labels", "5", "-o", out)
    assert r.returncode == 0, r.stderr
    assert "rig arkit: 51 shapes" in r.stdout and "weight error vs the take" in r.stdout  # the take speaks ICT
    z = np.load(out)
    assert sorted(map(str, z["names"])) == sorted(rig.names) and z["weights"].shape == (40, 51)


@pytest.mark.parametrize("suffix, name", [(".fbx", "FBX"), (".blend", "Blender"), (".ma", "Maya")])
def test_a_scene_format_not_read_is_named_not_called_an_npz(tmp_path, suffix, name):
    """An FBX (the Rocketbox avatars' format), a .blend or a Maya scene: refused with what it is and what to
    export, not as a broken npz."""
    path = tmp_path / f"face{suffix}"
    path.write_bytes(b"Kaydara FBX Binary  \x00\x1a\x00" + bytes(64))
    with pytest.raises(InputError) as info:
        load_rig(path)
    text = str(info.value)
    assert str(path) in text and f"{name} files are not read as rigs" in text and "glTF" in text
    assert "npz" not in text
