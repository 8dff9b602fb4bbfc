"""Live Link Face packets (facegeom.io.livelink): real recorded packets read, written back byte for byte, checked
against an independent decoder; every malformed datagram refused in one line."""
from __future__ import annotations

import gzip
import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from facegeom.errors import InputError
from facegeom.io.livelink import (
    MAX_PACKET,
    PACKET_NAMES,
    PacketError,
    encode_packet,
    parse_packet,
    read_recording,
    write_recording,
)

DATA = Path(__file__).parent / "data" / "livelink"


def independent_decode(data: bytes) -> dict:
    """The packet layout as Unreal's Live Link source and LLV read it, written out field by field here."""
    version = data[0]
    at = 1
    names = []
    for _ in range(2):
        n = int.from_bytes(data[at:at + 4], "big", signed=True)
        names.append(data[at + 4:at + 4 + n].decode())
        at += 4 + n
    frame, sub, num, den = struct.unpack(">ifii", data[at:at + 16])
    count = data[at + 16]
    values = struct.unpack(f">{count}f", data[at + 17:at + 17 + 4 * count])
    return {"version": version, "device": names[0], "subject": names[1], "frame": frame, "sub": sub,
            "rate": (num, den), "values": values}


@pytest.fixture(scope="module")
def dao():
    return read_recording(DATA / "dao.gesichter")


def test_a_real_performance_reads_and_writes_back_byte_for_byte(dao):
    assert len(dao) == 180
    packets = [parse_packet(p) for p in dao]
    frames = np.array([p.frame + p.sub_frame for p in packets])
    assert np.all(np.diff(frames) > 0)  # in time order
    assert {p.rate for p in packets} == {(60, 1)} and packets[0].fps == 60.0
    W = np.array([p.weights for p in packets])
    assert W.shape == (180, 52) and (W >= 0).all() and (W <= 1).all()
    assert W[:, PACKET_NAMES.index("EyeBlinkLeft")].max() > 0.9  # the actor blinks
    for raw, p in zip(dao, packets):
        assert encode_packet(p.values, p.device_id, p.subject, p.frame, p.sub_frame, p.rate) == raw


@pytest.mark.parametrize("name,field", [("jawleft", "JawLeft"), ("mouthleft", "MouthLeft"), ("headyaw", "HeadYaw"),
                                        ("lefteyeyaw", "LeftEyeYaw")])
def test_each_debug_recording_moves_its_one_value(name, field):
    """LLV's one-shape recordings sweep one value from -1 to 1: it lands on that name, nothing else moves."""
    V = np.array([parse_packet(p).values for p in read_recording(DATA / f"debug-{name}.gesichter")])
    k = PACKET_NAMES.index(field)
    assert V[:, k].min() == pytest.approx(-1.0) and V[:, k].max() == pytest.approx(1.0)
    assert np.abs(np.delete(V, k, axis=1)).max() == 0.0


def test_the_encoder_agrees_with_an_independent_decoder():
    rng = np.random.default_rng(0)
    v = rng.uniform(-1, 1, 61)
    data = encode_packet(v, "iPhone-ü", "Actor", 1234, 0.25, (60, 1))
    d = independent_decode(data)
    assert d["version"] == 6 and d["device"] == "iPhone-ü" and d["subject"] == "Actor"
    assert d["frame"] == 1234 and d["sub"] == 0.25 and d["rate"] == (60, 1)
    np.testing.assert_allclose(d["values"], v, atol=1e-7)
    assert len(data) == 1 + 4 + len("iPhone-ü".encode()) + 4 + 5 + 16 + 1 + 4 * 61
    # 52 weights alone: the rotations go out as 0
    assert independent_decode(encode_packet(v[:52]))["values"][52:] == (0.0,) * 9


@settings(max_examples=60, deadline=None)
@given(values=st.lists(st.floats(-50, 50, width=32), min_size=61, max_size=61),
       device=st.text(max_size=40), subject=st.text(max_size=40), frame=st.integers(-2**31, 2**31 - 1))
def test_what_is_written_reads_back(values, device, subject, frame):
    p = parse_packet(encode_packet(values, device, subject, frame, 0.5, (30, 1)))
    np.testing.assert_array_equal(p.values, np.float32(values).astype(np.float64))
    assert (p.device_id, p.subject, p.frame, p.rate) == (device, subject, frame, (30, 1))


def _with(data: bytes, at: int, fmt: str, value) -> bytes:
    return data[:at] + struct.pack(fmt, value) + data[at + struct.calcsize(fmt):]


def test_malformed_datagrams_are_refused_in_one_line(dao):
    good = dao[0]
    p = parse_packet(good)
    dev = len(p.device_id.encode())
    sub_at = 1 + 4 + dev
    head_at = sub_at + 4 + len(p.subject.encode())
    values_at = head_at + 17
    cases = {
        "empty": b"",
        "version": b"\x05" + good[1:],
        "name past the end": _with(good, 1, ">i", 10_000),
        "negative name": _with(good, 1, ">i", -1),
        "subject past the end": _with(good, sub_at, ">i", len(good)),
        "count": good[:head_at + 16] + b"\x3c" + good[head_at + 17:],
        "count past the data": good[:head_at + 16] + b"\xff" + good[head_at + 17:],
        "NaN": _with(good, values_at + 4 * 17, ">f", float("nan")),
        "inf": _with(good, values_at, ">f", float("inf")),
        "huge": _with(good, values_at + 4 * 52, ">f", 1e30),
        "trailing byte": good + b"\x00",
        "64 KB": good + bytes(65536 - len(good)),
        "negative rate": _with(good, head_at + 8, ">i", -60),
    }
    for name, data in cases.items():
        with pytest.raises(PacketError) as exc:
            parse_packet(data)
        assert len(str(exc.value).splitlines()) == 1, name
    for n in range(len(good)):  # cut at every length
        with pytest.raises(PacketError):
            parse_packet(good[:n])
    assert len(good) < MAX_PACKET


def test_recordings_round_trip_and_bad_files_are_one_line(tmp_path, dao):
    out = write_recording(tmp_path / "r.gesichter", dao[:10])
    assert read_recording(out) == dao[:10]
    raw = gzip.decompress((DATA / "dao.gesichter").read_bytes())
    cases = {
        "plain.gesichter": raw,  # not gzip
        "cut.gesichter": gzip.compress(raw[:-100]),
        "version.gesichter": gzip.compress(b"\x01" + raw[1:]),
        "count.gesichter": gzip.compress(raw[:1] + struct.pack(">I", 10_000) + raw[5:]),
        "extra.gesichter": gzip.compress(raw + b"\x00"),
        "short.gesichter": gzip.compress(b"\x06"),
        "broken.gesichter": (DATA / "dao.gesichter").read_bytes()[:500],
    }
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
        with pytest.raises(InputError) as exc:
            read_recording(tmp_path / name)
        text = str(exc.value)
        assert len(text.splitlines()) == 1 and name in text, (name, text)
    with pytest.raises(InputError, match="no such file"):
        read_recording(tmp_path / "none.gesichter")
