"""Shape-name mappings and key labels under hostile or careless input: bounded work, one clear line, no silent
wrong result (docs/security.md).

- a mapping CSV (``rig_shape,source_shape,gain``, facegeom/io/shape_names.py) is refused by its size before it
  is read, quotes at most ~80 characters of its text in an error, and has gains that are finite and bounded, also
  summed over the rows of one rig shape;
- a key-labels CSV (facegeom/io/key_labels.py) is refused by its size before it is read; a coordinate no real
  label has is one line naming the file, the line and the value (it was an IndexError deep in the retargeter);
  labels far outside the head, or squashed to a point or a line, are refused before any work;
- automatic name matching drives one rig shape per source name when a rig carries two spellings of a shape
  (Microsoft Rocketbox's ARKit ``AK_`` and Vive SRanipal ``SR_`` channels), and says which it left at 0.

Big files are never written: the caps are monkeypatched down and small files stand for big ones; one test pins
each real cap to the value its module states.
"""
from __future__ import annotations

import os
import subprocess
import sys
import threading
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from facegeom.errors import InputError
from facegeom.io import key_labels as kl_mod
from facegeom.io import shape_names as sn
from facegeom.io.key_labels import read_key_labels
from facegeom.io.shape_names import ARKIT_CAMEL_NAMES, ARKIT_NAMES, ICT_NAMES, ShapeMap, read_name_mapping

HEADER = "rig_shape,source_shape,gain\n"


def _one_line(exc, *words, path=None):
    msg = str(exc.value)
    assert "\n" not in msg and "Traceback" not in msg, msg
    if path is not None:
        assert msg.startswith(str(path)), msg
    for w in words:
        assert w in msg, msg
    return msg


def _no_read(*_args, **_kwargs):
    raise AssertionError("the file was read although its size is over the cap")


@pytest.fixture
def pipe(tmp_path):
    """A named pipe (its size says nothing) fed ``data`` by a thread: what ``--names <(generate)`` hands in."""
    made = []

    def make(data: bytes) -> Path:
        p = tmp_path / "pipe.csv"
        os.mkfifo(p)

        def write():
            try:
                with open(p, "wb") as f:
                    f.write(data)
            except BrokenPipeError:  # the reader stopped at its cap
                pass

        t = threading.Thread(target=write, daemon=True)
        t.start()
        made.append((p, t))
        return p

    yield make
    for p, t in made:
        if t.is_alive():  # nobody opened it: release the writer
            fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK)
            t.join(5)
            os.close(fd)


# ----------------------------------------------------------------------------- 1. the mapping's size, its quotes

def test_the_mapping_cap_is_the_one_the_module_states():
    assert sn.MAX_MAPPING_BYTES == 1 << 20
    assert "1 MiB" in sn.__doc__ and "MAX_MAPPING_BYTES" in sn.__doc__


def test_a_mapping_over_the_cap_is_refused_before_it_is_read(tmp_path, monkeypatch):
    p = tmp_path / "big_map.csv"
    p.write_text(HEADER + "jawOpen,jawOpen,1\n" * 20)  # 388 bytes standing for 100 MB
    monkeypatch.setattr(sn, "MAX_MAPPING_BYTES", 100)
    monkeypatch.setattr(Path, "read_text", _no_read)
    monkeypatch.setattr(Path, "read_bytes", _no_read)
    monkeypatch.setattr("builtins.open", _no_read)
    with pytest.raises(InputError) as e:
        read_name_mapping(p)
    msg = _one_line(e, "388 bytes", "100", path=p)
    assert len(msg) < 300


def test_a_mapping_at_the_cap_is_read(tmp_path, monkeypatch):
    text = HEADER + "jawOpen,jawOpen,1\n"
    p = tmp_path / "map.csv"
    p.write_text(text)
    monkeypatch.setattr(sn, "MAX_MAPPING_BYTES", len(text))
    assert len(read_name_mapping(p).rows) == 1


def test_a_mapping_that_is_a_pipe_is_read_no_further_than_the_cap(pipe, monkeypatch):
    """A file whose size says nothing (a pipe, a device) is read up to the cap and refused past it."""
    p = pipe((HEADER + "jawOpen,jawOpen,1\n" * 300).encode())
    monkeypatch.setattr(sn, "MAX_MAPPING_BYTES", 1000)
    with pytest.raises(InputError) as e:
        read_name_mapping(p)
    _one_line(e, "1,000", path=p)


LONG = "x" * 5000


@pytest.mark.parametrize("text", [
    f"{LONG},source_shape,gain\njawOpen,jawOpen\n",  # a wrong header
    f"{HEADER}jawOpen,jawOpen,{LONG}\n",  # a gain that is no number
    f"{HEADER}jawOpen,{LONG}\njawOpen,{LONG}\n",  # a pair given twice
])
def test_a_mapping_error_quotes_at_most_80_characters(tmp_path, text):
    p = tmp_path / "map.csv"
    p.write_text(text)
    with pytest.raises(InputError) as e:
        read_name_mapping(p)
    msg = _one_line(e, "…", path=p)
    assert LONG[:81] not in msg and len(msg) < len(str(p)) + 250, msg


def test_a_rig_shape_the_rig_lacks_is_quoted_short(tmp_path):
    p = tmp_path / "map.csv"
    p.write_text(f"{HEADER}{LONG},jawOpen,1\n")
    with pytest.raises(InputError) as e:
        ShapeMap.between(["jawOpen", "y" * 500], ARKIT_NAMES, p)
    msg = _one_line(e, "line 2", "…", path=p)
    assert LONG[:81] not in msg and "y" * 81 not in msg and len(msg) < len(str(p)) + 400, msg


# ----------------------------------------------------------------------------- 2. gains

def test_the_gain_bound_is_the_one_the_module_states():
    assert sn.MAX_GAIN == 10.0
    assert "MAX_GAIN" in sn.__doc__ and "|gain| <= 10" in sn.__doc__


@pytest.mark.parametrize("gain", ["1e308", "-1e308", "10.5", "-11", "1e39"])
def test_a_gain_beyond_the_bound_is_refused_naming_the_file_and_line(tmp_path, gain):
    p = tmp_path / "map.csv"
    p.write_text(f"{HEADER}mouthClose,mouthClose,1\njawOpen,jawOpen,{gain}\n")
    with pytest.raises(InputError) as e:
        read_name_mapping(p)
    _one_line(e, "line 3", gain, "10", path=p)


@pytest.mark.parametrize("gain", ["10", "-10", "0", "2.5", "-0.5"])
def test_gains_within_the_bound_are_read(tmp_path, gain):
    p = tmp_path / "map.csv"
    p.write_text(f"{HEADER}jawOpen,jawOpen,{gain}\n")
    assert read_name_mapping(p).rows[0].gain == float(gain)


def test_rows_of_one_rig_shape_cannot_add_past_the_bound(tmp_path):
    """Two spellings of one pair (each row within the bound) land on one rig shape and one source column."""
    p = tmp_path / "map.csv"
    p.write_text(f"{HEADER}jawOpen,jawOpen,6\nmouthClose,mouthClose,1\nJawOpen,JawOpen,6\n")
    read_name_mapping(p)  # each row alone is fine
    with pytest.raises(InputError) as e:
        ShapeMap.between(["jawOpen", "mouthClose"], ARKIT_NAMES, p)
    _one_line(e, "line 4", "jawOpen", "12", "10", path=p)


def test_a_mapping_held_in_a_rig_file_is_bounded_too():
    """A rig ``.npz`` carries its mapping's rows as arrays (not read by read_name_mapping): the rig refuses them."""
    from facegeom.io.shape_names import MappingRow, NameMapping
    from facegeom.model.rig import BlendshapeRig

    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    D = np.zeros((1, 3, 3))
    D[0, 2, 2] = 1.0
    mapping = NameMapping((MappingRow("jawOpen", "jawOpen", 1e308, 2),), "m.csv")
    with pytest.raises(InputError) as e:
        BlendshapeRig(V, D, ["jawOpen"], [[0, 1, 2]], name_map=mapping)
    _one_line(e, "m.csv", "line 2", "1e+308")


def test_a_rig_loaded_with_a_huge_gain_is_refused_before_any_weight(tmp_path):
    """The audit's case: ``names=MAP.csv`` with gain 1e308 used to write inf weights into the .glb."""
    from facegeom.model.inputs import load_rig
    from facegeom.model.rig import BlendshapeRig

    rig = tmp_path / "rig.npz"
    V = np.array([[0.0, 0, 0], [10, 0, 0], [0, 10, 0]])
    D = np.zeros((1, 3, 3))
    D[0, 2, 2] = 1.0
    BlendshapeRig(V, D, ["jawOpen"], [[0, 1, 2]]).save_npz(rig)
    p = tmp_path / "map.csv"
    p.write_text(f"{HEADER}jawOpen,jawOpen,1e308\n")
    with pytest.raises(InputError) as e:
        load_rig(rig, names=p)
    _one_line(e, "map.csv", "line 2")


# ----------------------------------------------------------------------------- 3. the key labels' size

def test_the_key_label_cap_is_the_one_the_module_states():
    assert kl_mod.MAX_KEY_LABEL_BYTES == 8 << 20
    assert "8 MiB" in kl_mod.__doc__ and "MAX_KEY_LABEL_BYTES" in kl_mod.__doc__


def test_key_labels_over_the_cap_are_refused_before_they_are_read(tmp_path, monkeypatch):
    p = tmp_path / "big_labels.csv"
    p.write_text("frame,marker,x,y,z\n" + "".join(f"{f},0,1,2,3\n" for f in range(40)))
    size = p.stat().st_size
    monkeypatch.setattr(kl_mod, "MAX_KEY_LABEL_BYTES", 100)
    monkeypatch.setattr(Path, "read_text", _no_read)
    monkeypatch.setattr(Path, "read_bytes", _no_read)
    monkeypatch.setattr("builtins.open", _no_read)
    with pytest.raises(InputError) as e:
        read_key_labels(p, 4)
    _one_line(e, f"{size:,} bytes", "100", path=p)


def test_key_labels_that_are_a_pipe_are_read_no_further_than_the_cap(pipe, monkeypatch):
    p = pipe(("frame,marker,x,y,z\n" + "".join(f"{f},0,1,2,3\n" for f in range(300))).encode())
    monkeypatch.setattr(kl_mod, "MAX_KEY_LABEL_BYTES", 1000)
    with pytest.raises(InputError) as e:
        read_key_labels(p, 4)
    _one_line(e, "1,000", path=p)


# ----------------------------------------------------------------------------- 4. a label no real head has

@pytest.mark.parametrize("value", ["1e308", "-1e308", "1e13", "1" + "0" * 200])
def test_a_huge_label_coordinate_is_one_line_naming_the_file_line_and_value(tmp_path, value):
    p = tmp_path / "labels.csv"
    p.write_text(f"frame,marker,x,y,z\n10,0,1,2,3\n30,1,4,{value},6\n")
    with pytest.raises(InputError) as e:
        read_key_labels(p, 4)
    msg = _one_line(e, "line 3", path=p)
    assert value[:20] in msg and len(msg) < len(str(p)) + 200, msg


def _fake_character(n=300, seed=0):
    """A head of ``n`` vertices on an ellipsoid (cm, a face's size), 'registered' as itself: no registration runs."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(n, 3))
    V = u / np.linalg.norm(u, axis=1, keepdims=True) * [8.0, 11.0, 9.0]
    F = np.array([[0, 1, 2], [1, 2, 3]])
    reg = SimpleNamespace(template=V, delta_in_head=lambda d: np.asarray(d, dtype=np.float64))
    ch = SimpleNamespace(registration=reg, pieces=[SimpleNamespace(vertices=np.arange(n))], vertices=V, faces=F)
    return V, F, ch


class _Recorder:
    """A retargeter and deformer that record they were fitted (the route's work) and do nothing."""

    def __init__(self):
        self.fitted = False

    def fit(self, *args, **kwargs):
        self.fitted = True
        self.X = args[0]
        return self

    def transform(self):
        return self.X


def _route(labels, keys=(0, 2, 4), **kwargs):
    from facegeom.pipelines.character_markers import markers_onto_character

    V, F, ch = _fake_character()
    ids = np.arange(0, 200, 5)  # 40 markers, spread over the head
    X0 = V[ids]
    X = X0[None] + 0.1 * np.sin(np.arange(6))[:, None, None]  # 6 frames of a little motion
    rt, de = _Recorder(), _Recorder()
    mr = markers_onto_character(None, X, X0, ids, V, F, keys=np.array(keys), labels=labels, character=ch,
                                retargeter=rt, deformer=de, **kwargs)
    return mr, rt


def test_a_label_far_outside_the_head_is_refused_before_any_work():
    labels = np.full((3, 40, 3), np.nan)
    labels[1, 7] = [1e6, 0.0, 0.0]
    with pytest.raises(InputError) as e:
        _route(labels, labels_path="labels.csv", first_frame=100)
    _one_line(e, "labels.csv", "frame 102", "marker 7", "1e+06")


def test_a_label_within_the_head_is_taken():
    labels = np.full((3, 40, 3), np.nan)
    mr, rt = _route(None)
    labels[1, 7] = mr.proposed[1, 7] + [0.0, 0.3, 0.0]  # a marker moved 3 mm
    mr, rt = _route(labels)
    assert rt.fitted and np.allclose(mr.labels[1, 7], labels[1, 7])


def test_the_audit_label_value_through_the_command_line_is_one_line(real_takes, tmp_path):
    """``animate --route markers --key-labels`` with 1e308 in a label: was an IndexError traceback from the
    retargeter (facegeom/methods/tangent_retarget.py, label_noise_estimate) after ~20 s of registration."""
    k = tmp_path / "k.csv"
    k.write_text("frame,marker,x,y,z\n10,0,1e308,0,0\n30,0,1,2,3\n")
    head = Path(__file__).parent / "data" / "heads" / "lee_perry_smith.ply"
    r = subprocess.run([sys.executable, "-m", "facegeom", "animate", "--take", str(real_takes[0]), "--character",
                        str(head), "--route", "markers", "--frames", "40", "--start", "10", "--key-labels", str(k),
                        "-o", str(tmp_path / "a.glb")], capture_output=True, text=True, timeout=300, check=False)
    assert r.returncode == 2, r.stderr[-2000:]
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr[-2000:]
    assert "k.csv" in lines[0] and "line 2" in lines[0] and "1e308" in lines[0], lines[0]
    assert not (tmp_path / "a.glb").exists()


# ----------------------------------------------------------------------------- 5. degenerate labels

def test_labels_all_at_one_point_are_refused():
    labels = np.full((3, 40, 3), np.nan)
    labels[1] = [0.5, 1.0, 2.0]  # every marker of key frame 2 at one point: the head squashed
    with pytest.raises(InputError) as e:
        _route(labels, labels_path="labels.csv", first_frame=10)
    _one_line(e, "labels.csv", "frame 12", "one point")


def test_labels_on_one_line_are_refused():
    mr, _ = _route(None)
    labels = np.full((3, 40, 3), np.nan)
    labels[2] = mr.proposed[2]
    labels[2, :, 1:] = 0.0  # every marker of key frame 4 on the x axis
    with pytest.raises(InputError) as e:
        _route(labels, labels_path="labels.csv")
    _one_line(e, "labels.csv", "frame 4", "one line")


def test_labels_in_one_plane_are_refused():
    """2-D labels (x, y of a photo, z = 0) flatten the face."""
    mr, _ = _route(None)
    labels = mr.proposed.copy()
    labels[1, :, 2] = 0.0
    with pytest.raises(InputError) as e:
        _route(labels)
    _one_line(e, "frame 2", "one plane")


def test_labels_shrunk_far_below_the_face_are_refused():
    """Labels written in metres for a head in centimetres: the face a hundredth of its size."""
    mr, _ = _route(None)
    labels = mr.proposed / 100.0
    with pytest.raises(InputError) as e:
        _route(labels)
    _one_line(e, "frame 0", "spread")


def test_a_few_markers_edited_together_are_not_degenerate():
    """Markers not given keep the proposal: three mouth markers moved to one spot is an edit, not a squashed head."""
    mr, _ = _route(None)
    labels = np.full((3, 40, 3), np.nan)
    labels[1, [3, 4, 5]] = mr.proposed[1, 3]
    mr, rt = _route(labels)
    assert rt.fitted


# ----------------------------------------------------------------------------- 6. rigs with two spellings of a shape

ROCKETBOX_LIKE = ["AK_25_JawOpen", "SR_21_Jaw_Open", "AK_46_CheekPuff", "SR_33_Cheek_Puff_Left",
                  "SR_34_Cheek_Puff_Right", "AK_01_EyeBlinkLeft", "SR_01_Eye_Left_Blink", "AK_24_MouthSmileLeft",
                  "SR_20_Mouth_Smile_Left", "SR_40_Mouth_Ape_Shape"]
LEFT_AT_0 = ("SR_21_Jaw_Open", "SR_33_Cheek_Puff_Left", "SR_34_Cheek_Puff_Right", "SR_20_Mouth_Smile_Left")


@pytest.mark.parametrize("order", [1, -1])
@pytest.mark.parametrize("source", [ARKIT_CAMEL_NAMES, ARKIT_NAMES])
def test_one_rig_shape_per_source_name_the_arkit_spelling_preferred(order, source):
    rig = ROCKETBOX_LIKE[::order]
    m = ShapeMap.between(rig, source)
    col = {n: m.matrix[:, i] for i, n in enumerate(source)}
    drives = {n: [rig[r] for r in np.flatnonzero(c)] for n, c in col.items() if c.any()}
    camel = {n[0].lower() + n[1:]: v for n, v in drives.items()}
    assert camel == {"jawOpen": ["AK_25_JawOpen"], "cheekPuff": ["AK_46_CheekPuff"],
                     "eyeBlinkLeft": ["AK_01_EyeBlinkLeft"], "mouthSmileLeft": ["AK_24_MouthSmileLeft"]}
    assert set(m.ambiguous) == set(LEFT_AT_0)
    text = m.describe()
    assert "4 shapes of the rig match no source name uniquely" in text and "left at 0" in text
    assert "give a mapping CSV to drive them" in text
    for name in LEFT_AT_0:
        assert name in text
    W = np.zeros(len(source))
    W[[i for i, n in enumerate(source) if n.lower() == "jawopen"]] = 1.0
    assert m.apply(W).sum() == 1.0  # the jaw opens once


def test_the_other_spelling_alone_is_still_driven():
    rig = ["SR_21_Jaw_Open", "SR_33_Cheek_Puff_Left", "SR_34_Cheek_Puff_Right", "SR_20_Mouth_Smile_Left"]
    m = ShapeMap.between(rig, ARKIT_CAMEL_NAMES)
    assert m.unmapped_rig == () and m.ambiguous == ()
    assert "uniquely" not in m.describe()


def test_an_ict_rig_keeps_both_sides_of_one_arkit_shape():
    m = ShapeMap.between(ICT_NAMES, ARKIT_NAMES)
    assert m.ambiguous == ()
    puff = m.matrix[:, ARKIT_NAMES.index("CheekPuff")]
    assert sorted(ICT_NAMES[i] for i in np.flatnonzero(puff)) == ["cheekPuff_L", "cheekPuff_R"]


def test_the_load_note_says_which_shapes_are_left_at_0():
    from facegeom.model.inputs import rig_note
    from facegeom.model.rig import BlendshapeRig

    K = len(ROCKETBOX_LIKE)
    V = np.array([[0.0, 0, 0], [10, 0, 0], [0, 10, 0]])
    D = np.zeros((K, 3, 3))
    D[:, 2, 2] = 1.0
    note = rig_note(BlendshapeRig(V, D, ROCKETBOX_LIKE, [[0, 1, 2]]), "rocketbox.npz")
    assert "4 shapes of the rig match no source name uniquely" in note, note
    assert "left at 0; give a mapping CSV to drive them" in note, note
    shown = note.split("uniquely")[1]
    for name in LEFT_AT_0:
        assert name in shown and note.count(name) == 1  # listed once, not also as "no ICT expression drives"


def test_a_mapping_row_claims_its_source_for_that_shape(tmp_path):
    """A shape driven by hand claims its source: the automatic match of another spelling of it is left at 0."""
    p = tmp_path / "map.csv"
    p.write_text(f"{HEADER}SR_21_Jaw_Open,jawOpen,1\n")
    m = ShapeMap.between(ROCKETBOX_LIKE, ARKIT_CAMEL_NAMES, p)
    jaw = m.matrix[:, ARKIT_CAMEL_NAMES.index("jawOpen")]
    assert [ROCKETBOX_LIKE[i] for i in np.flatnonzero(jaw)] == ["SR_21_Jaw_Open"]
    assert "AK_25_JawOpen" in m.ambiguous


def test_the_way_back_reads_the_arkit_spelling():
    """Weights of a Rocketbox-like rig as ARKit columns (a Live Link take written from a solve): each column from
    the one shape spelled as ARKit spells it."""
    m = ShapeMap.between(ARKIT_CAMEL_NAMES, ROCKETBOX_LIKE[::-1])
    row = m.matrix[ARKIT_CAMEL_NAMES.index("jawOpen")]
    assert [ROCKETBOX_LIKE[::-1][i] for i in np.flatnonzero(row)] == ["AK_25_JawOpen"]
