"""One name map (facegeom/io/shape_names.py): ICT, ARKit camelCase / PascalCase, exporter decorations, mapping CSVs."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from facegeom.errors import InputError
from facegeom.io import shape_names as sn
from facegeom.io.shape_names import (
    ARKIT_CAMEL_NAMES,
    ARKIT_NAMES,
    ICT_NAMES,
    ShapeMap,
    arkit_to_ict_name,
    ict_to_arkit_name,
    naming_convention,
    read_name_mapping,
    shape_key,
    undecorate,
)

BOTH = ("browInnerUp", "cheekPuff")


def test_ict_names_are_the_face_models(face_model):
    assert ICT_NAMES == tuple(face_model.expression_names)


def test_takes_keeps_its_public_names():
    from facegeom.io import takes

    assert takes.ARKIT_NAMES is sn.ARKIT_NAMES and takes.arkit_to_ict_name is sn.arkit_to_ict_name
    assert len(ARKIT_NAMES) == len(ARKIT_CAMEL_NAMES) == 52 and len(ICT_NAMES) == 53


@pytest.mark.parametrize("name, key", [
    ("eyeBlink_L", ("eyeblink", "L")),
    ("eyeBlinkLeft", ("eyeblink", "L")),
    ("EyeBlinkLeft", ("eyeblink", "L")),
    ("EYEBLINKLEFT", ("eyeblink", "L")),
    ("eyeBlink_left", ("eyeblink", "L")),
    ("blendShape1.eyeBlinkLeft", ("eyeblink", "L")),
    ("Face.eyeBlink_R.001", ("eyeblink", "R")),
    ("mesh_eyeBlinkRight", ("eyeblink", "R")),
    ("head_geo_mouthSmile_L", ("mouthsmile", "L")),
    ("Face:head|jawOpen", ("jawopen", None)),
    ("eyeBlink.L", ("eyeblink", "L")),
    ("browInnerUp", ("browinnerup", None)),
    ("browInnerUp_R", ("browinnerup", "R")),
    ("mouthLeft", ("mouthleft", None)),  # a shape of its own, not a sided "mouth"
    ("Mouth_Left", ("mouthleft", None)),
    ("JawRight", ("jawright", None)),
    ("cleft", ("cleft", None)),
    ("smirk_L", ("smirk", "L")),
])
def test_shape_keys(name, key):
    assert shape_key(name) == key


def test_undecorate_keeps_the_case_and_unknown_prefixes():
    assert undecorate("blendShape1.eyeBlinkLeft") == "eyeBlinkLeft"
    assert undecorate("Face_mesh_jawOpen.003") == "jawOpen"
    assert undecorate("rig_smirk") == "rig_smirk"  # not a known shape: nothing to strip it down to


def test_ict_to_arkit_name():
    assert ict_to_arkit_name("eyeBlink_L") == "EyeBlinkLeft" and ict_to_arkit_name("browInnerUp_R") == "BrowInnerUp"
    assert ict_to_arkit_name("mouthLeft") == "MouthLeft"
    with pytest.raises(InputError, match="not an ICT expression"):
        ict_to_arkit_name("eyeBlinkLeft")


@pytest.mark.parametrize("names, expected", [
    (ICT_NAMES, "ict"),
    (ARKIT_CAMEL_NAMES, "arkit"),
    (ARKIT_NAMES, "arkit-pascal"),
    ([f"blendShape1.{n}" for n in ARKIT_CAMEL_NAMES], "arkit"),
    (["jawOpen", "mouthClose"], "ict"),  # no sided shape to tell ICT from ARKit
    (["smirk", "sneer", "jawOpen"], "other"),
])
def test_naming_convention(names, expected):
    c = naming_convention(names)
    assert c.name == expected and c.total == len(names)
    assert str(c).startswith(sn.CONVENTIONS[expected])


def test_convention_counts_recognised_and_decorated():
    c = naming_convention(["blendShape1.eyeBlinkLeft", "EYEBLINKRIGHT", "smirk"])
    assert c.recognised == 2 and c.decorated == ("blendShape1.eyeBlinkLeft",)
    assert "blendShape1.eyeBlinkLeft" in str(c)


# ----------------------------------------------------------------------------- ICT <-> ARKit

def test_arkit_to_ict_map():
    m = ShapeMap.between(ICT_NAMES, ARKIT_CAMEL_NAMES)
    assert m.unmapped_rig == () and m.unmapped_source == ("tongueOut",)
    M = m.matrix
    for ict in ICT_NAMES:
        row = M[ICT_NAMES.index(ict)]
        assert np.count_nonzero(row) == 1 and row.sum() == 1.0
        assert ARKIT_CAMEL_NAMES[int(np.argmax(row))][0].upper() + ARKIT_CAMEL_NAMES[int(np.argmax(row))][1:] == \
            ict_to_arkit_name(ict)
    brow = ARKIT_CAMEL_NAMES.index("browInnerUp")
    assert M[:, brow].sum() == 2.0  # one ARKit weight, both ICT sides
    text = m.describe()
    assert "tongueOut" in text and "\n" not in text and "browInnerUp_L" in text


def test_ict_to_arkit_map():
    m = ShapeMap.between(ARKIT_NAMES, ICT_NAMES)
    assert m.unmapped_rig == ("TongueOut",) and m.unmapped_source == ()
    w = np.zeros(53)
    w[ICT_NAMES.index("browInnerUp_L")], w[ICT_NAMES.index("browInnerUp_R")] = 0.8, 0.2
    w[ICT_NAMES.index("eyeBlink_L")] = 0.7
    a = m.apply(w)
    assert a[ARKIT_NAMES.index("BrowInnerUp")] == pytest.approx(0.5) and a[ARKIT_NAMES.index("EyeBlinkLeft")] == 0.7
    assert "TongueOut" in m.describe() and "BrowInnerUp" in m.describe()


def test_the_inverse_agrees_with_the_other_direction():
    fwd = ShapeMap.between(ICT_NAMES, ARKIT_NAMES)
    inv = fwd.inverse()
    assert inv.rig_names == ARKIT_NAMES and inv.source_names == ICT_NAMES
    np.testing.assert_allclose(inv.matrix, ShapeMap.between(ARKIT_NAMES, ICT_NAMES).matrix, atol=1e-12)


def equal_sides(draw_w):
    w = np.array(draw_w, dtype=float)
    for b in BOTH:
        w[ICT_NAMES.index(b + "_R")] = w[ICT_NAMES.index(b + "_L")]
    return w


@settings(max_examples=60, deadline=None, derandomize=True)
@given(w=st.lists(st.floats(-0.2, 1.2, allow_nan=False), min_size=53, max_size=53),
       pascal=st.booleans())
def test_ict_arkit_ict_is_the_identity_when_the_sides_agree(w, pascal):
    W = equal_sides(w)
    arkit = ARKIT_NAMES if pascal else ARKIT_CAMEL_NAMES
    A = ShapeMap.between(arkit, ICT_NAMES).apply(W)
    back = ShapeMap.between(ICT_NAMES, arkit).apply(A)
    np.testing.assert_allclose(back, W, atol=1e-12)
    assert A[arkit.index("TongueOut" if pascal else "tongueOut")] == 0.0


@settings(max_examples=60, deadline=None, derandomize=True)
@given(name=st.sampled_from(ARKIT_NAMES), camel=st.booleans())
def test_every_arkit_name_maps(name, camel):
    spelled = name[0].lower() + name[1:] if camel else name
    m = ShapeMap.between(ICT_NAMES, [spelled])
    driven = [ICT_NAMES[i] for i in np.flatnonzero(m.matrix[:, 0])]
    assert driven == sorted(arkit_to_ict_name(name))
    other = ShapeMap.between(ARKIT_CAMEL_NAMES if not camel else ARKIT_NAMES, [spelled])
    assert other.matrix.sum() == 1.0 and other.unmapped_source == ()


PREFIXES = ("", "blendShape1.", "Face.", "mesh_", "head_geo_", "Face:", "|root|head|", "BS_")
SUFFIXES = ("", ".001", ".12")


def decorate(name: str, prefix: str, suffix: str, case: str, dot_side: bool) -> str:
    if dot_side and name.endswith(("_L", "_R")):
        name = name[:-2] + "." + name[-1]
    name = {"keep": name, "lower": name.lower(), "upper": name.upper()}[case]
    return prefix + name + suffix


@settings(max_examples=80, deadline=None, derandomize=True)
@given(source=st.sampled_from(["ict", "arkit", "pascal"]), prefix=st.sampled_from(PREFIXES),
       suffix=st.sampled_from(SUFFIXES), case=st.sampled_from(["keep", "lower", "upper"]), dot_side=st.booleans())
def test_decorated_names_map_like_plain_ones(source, prefix, suffix, case, dot_side):
    plain = {"ict": ICT_NAMES, "arkit": ARKIT_CAMEL_NAMES, "pascal": ARKIT_NAMES}[source]
    decorated = [decorate(n, prefix, suffix, case, dot_side) for n in plain]
    for rig in (ICT_NAMES, ARKIT_NAMES):
        np.testing.assert_array_equal(ShapeMap.between(rig, decorated).matrix, ShapeMap.between(rig, plain).matrix)
        np.testing.assert_array_equal(ShapeMap.between(decorated, rig).matrix, ShapeMap.between(plain, rig).matrix)


def test_apply_checks_the_shape():
    m = ShapeMap.between(["a", "b"], ["a", "b", "c"])
    assert m.apply(np.ones((4, 3))).shape == (4, 2) and m.unmapped_source == ("c",)
    with pytest.raises(InputError, match=r"shape \(T, 3\)"):
        m.apply(np.ones((4, 2)))
    with pytest.raises(InputError, match="repeats"):
        ShapeMap.between(["a", "a"], ["a"])


# ----------------------------------------------------------------------------- mapping files

def write(tmp_path, text, name="map.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_mapping_gains_sums_and_defaults(tmp_path):
    p = write(tmp_path, "rig_shape,source_shape,gain\n"
                        "# a comment\n"
                        "Smile,mouthSmileLeft,0.5\n"
                        "Smile,mouthSmileRight,0.5\n"
                        "Blink_Left_v2,eyeBlinkLeft\n"
                        "jawOpen,jawOpen,2\n"
                        "\n"
                        "Brow,browInnerUp,1\n"
                        "Nothing,tongueOut,1\n")
    rig = ["Smile", "Blink_Left_v2", "jawOpen", "Brow", "eyeBlink_R", "Nothing", "custom"]
    m = ShapeMap.between(rig, ICT_NAMES, p)  # the file speaks ARKit, the source is ICT
    W = np.zeros(53)
    for n, v in [("mouthSmile_L", 0.4), ("mouthSmile_R", 0.2), ("eyeBlink_L", 0.9), ("jawOpen", 0.25),
                 ("browInnerUp_L", 0.6), ("browInnerUp_R", 0.2), ("eyeBlink_R", 0.3)]:
        W[ICT_NAMES.index(n)] = v
    out = dict(zip(rig, m.apply(W)))
    assert out["Smile"] == pytest.approx(0.3) and out["Blink_Left_v2"] == 0.9 and out["jawOpen"] == 0.5
    assert out["Brow"] == pytest.approx(0.4)  # the mean of ICT's two sides
    assert out["eyeBlink_R"] == 0.3  # not in the file: matched by name
    assert m.from_mapping == ("Smile", "Blink_Left_v2", "jawOpen", "Brow", "Nothing")
    assert m.unmapped_rig == ("Nothing", "custom") and m.unresolved == (("tongueOut", 9),)
    text = m.describe()
    for name in ("Nothing", "custom", "tongueOut (line 9)", "map.csv"):
        assert name in text
    # the other way: the least-squares inverse gives source weights that reproduce the rig weights
    back = m.inverse().apply(m.apply(W))
    np.testing.assert_allclose(m.apply(back), m.apply(W), atol=1e-12)


def test_a_zero_gain_switches_a_shape_off(tmp_path):
    p = write(tmp_path, "rig_shape,source_shape\njawOpen,jawOpen,0\n")
    m = ShapeMap.between(["jawOpen", "mouthClose"], ARKIT_NAMES, p)
    assert m.unmapped_rig == ("jawOpen",)


@pytest.mark.parametrize("text, message", [
    ("", "empty"),
    ("rig,source\na,b\n", "line 1: the header must be rig_shape,source_shape,gain"),
    ("rig_shape,source_shape,gain\n", "no rows"),
    ("rig_shape,source_shape,gain\njawOpen\n", "line 2: expected rig_shape,source_shape"),
    ("rig_shape,source_shape,gain\njawOpen,jawOpen,lots\n", "line 2: gain 'lots' is not a finite number"),
    ("rig_shape,source_shape,gain\njawOpen,jawOpen,nan\n", "line 2: gain"),
    ("rig_shape,source_shape,gain\n,jawOpen,1\n", "line 2: the rig shape is empty"),
    ("rig_shape,source_shape,gain\njawOpen,jawOpen\n\njawOpen,jawOpen,2\n",
     "line 4: jawOpen,jawOpen is already on line 2"),
])
def test_mapping_errors_name_the_file_and_line(tmp_path, text, message):
    p = write(tmp_path, text)
    with pytest.raises(InputError, match=message) as exc:
        read_name_mapping(p)
    assert str(exc.value).startswith(str(p)) and "\n" not in str(exc.value)


def test_a_mapping_row_for_no_rig_shape_is_an_error(tmp_path):
    p = write(tmp_path, "rig_shape,source_shape,gain\njawOpen,jawOpen,1\njawOpn,jawOpen,1\n")
    with pytest.raises(InputError, match=r"map\.csv: line 3: 'jawOpn' is not a shape of the rig \(did you mean "
                                         r"'jawOpen'"):
        ShapeMap.between(["jawOpen", "mouthClose"], ARKIT_NAMES, p)
    with pytest.raises(InputError, match="file not found"):
        read_name_mapping(tmp_path / "none.csv")
