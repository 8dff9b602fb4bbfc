"""Video files (facegeom.io.video): frames streamed in order with their times, rotation as phones record it,
variable frame rates, damaged and cut files, non-videos, frames too large to decode, and the preview writer.

Every video is made here with PyAV: 64 x 48 frames with a red square moving right one step per frame, so a
frame's content says which frame it is.
"""
from __future__ import annotations

import os
import struct
import subprocess
import sys
import textwrap
import time
import tracemalloc
import weakref
from fractions import Fraction

import numpy as np
import pytest

from facegeom.errors import InputError

av = pytest.importorskip("av")

from facegeom.io.video import MAX_FRAME_PIXELS, VideoWriter, open_video, writer_codec

W, H, N, FPS = 64, 48, 30, 30


def square_x(i: int, n: int = N, w: int = W) -> int:
    """Left edge of the square in frame ``i``."""
    return i * (w - 16) // max(n - 1, 1)


def picture(i: int, n: int = N, w: int = W, h: int = H, noise: bool = False) -> np.ndarray:
    """Frame ``i``: black (or noise), a green 8 x 8 block at the top-left corner, the red 16 x 16 square."""
    a = np.zeros((h, w, 3), np.uint8)
    if noise:  # incompressible: packets of a few kB, so byte offsets in a test land inside frames
        a[:] = np.random.default_rng(i).integers(0, 256, a.shape, dtype=np.uint8)
    a[:8, :8] = (0, 255, 0)
    x = square_x(i, n, w)
    a[h // 2 - 8:h // 2 + 8, x:x + 16] = (255, 0, 0)
    return a


def make_video(path, n=N, fps=FPS, w=W, h=H, codec="libx264", rotation=None, times_ms=None, noise=False,
               container_options=None, options=None):
    """Encode ``n`` frames of :func:`picture` to ``path`` with PyAV (not with facegeom's writer)."""
    with av.open(str(path), "w", options=container_options or {}) as c:
        s = c.add_stream(codec, rate=fps, options=options or {})
        s.width, s.height, s.pix_fmt = w, h, "yuv420p"
        if rotation is not None:
            s.set_display_rotation(rotation)  # PyAV's angle: counter-clockwise
        if times_ms is not None:
            s.codec_context.time_base = Fraction(1, 1000)
        for i in range(n):
            f = av.VideoFrame.from_ndarray(picture(i, n, w, h, noise), format="rgb24")
            if times_ms is not None:
                f.pts, f.time_base = times_ms[i], Fraction(1, 1000)
            for p in s.encode(f):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    return path


def red_x(image: np.ndarray) -> float:
    """Left edge of the red square found in ``image`` (stored orientation)."""
    r, g, b = (image[..., k].astype(int) for k in range(3))
    cols = np.flatnonzero(((r > 150) & (g < 100) & (b < 100)).sum(axis=0) >= 8)
    return float(cols.min())


def one_line_naming(exc: InputError, path) -> str:
    text = str(exc)
    assert len(text.splitlines()) == 1 and str(path) in text, text
    return text


# ----------------------------------------------------------------------------- reading


@pytest.mark.parametrize("suffix,codec", [(".mp4", "libx264"), (".mkv", "libx264"), (".mp4", "mpeg4")])
def test_frames_come_in_order_with_their_times_and_colours(tmp_path, suffix, codec):
    path = make_video(tmp_path / f"clip{suffix}", codec=codec)
    with open_video(path) as r:
        assert (r.width, r.height, r.rotation, r.fps) == (W, H, 0, 30.0)
        assert r.n_frames == N and r.n_frames_exact == (suffix == ".mp4")  # Matroska: an estimate
        assert r.duration_s == pytest.approx(1.0, abs=0.04)
        assert r.codec == ("h264" if codec == "libx264" else "mpeg4")
        frames = list(r)
        assert not r.variable_rate and r.damaged == 0 and not r.truncated and r.problem is None
    assert [f.index for f in frames] == list(range(N))
    assert np.allclose([f.time_s for f in frames], np.arange(N) / FPS, atol=1e-3)
    for i, f in enumerate(frames):
        assert f.image.shape == (H, W, 3) and f.image.dtype == np.uint8
        assert abs(red_x(f.image) - square_x(i)) <= 1, i
        assert np.all(np.abs(f.image[H // 2, square_x(i) + 8].astype(int) - (255, 0, 0)) < 60)  # red after coding
        assert np.all(np.abs(f.image[3, 3].astype(int) - (0, 255, 0)) < 60)  # the green corner
        assert f.image[2:6, 20:30].max() < 40 if square_x(i) > 32 else True  # black background


def test_frames_subsample_and_each_iteration_starts_over(tmp_path):
    path = make_video(tmp_path / "clip.mp4")
    with open_video(path) as r:
        part = list(r.frames(step=3, start=2, stop=20))
        assert [f.index for f in part] == list(range(2, 20, 3))
        assert all(abs(red_x(f.image) - square_x(f.index)) <= 1 for f in part)
        assert [f.index for f in r] == list(range(N))  # a new pass from the start
        assert len(list(r.frames(step=10))) == 3
        with pytest.raises(InputError, match="step must be"):
            r.frames(step=0)
    with pytest.raises(InputError, match="closed"):
        r.frames()


def _tkhd_matrix(data: bytes) -> tuple[float, float, float, float]:
    """``(a, b, c, d)`` of the first track header's matrix (16.16 fixed point; ISO/IEC 14496-12, 8.3.2)."""
    at = data.find(b"tkhd")
    version = data[at + 4]
    start = at + 4 + 4 + (32 if version == 1 else 20) + 8 + 8  # times / ids, reserved, layer .. volume
    a, b, _, c, d = struct.unpack(">5i", data[start:start + 20])
    return a / 65536, b / 65536, c / 65536, d / 65536


@pytest.mark.parametrize("pyav_degrees,shown", [(-90, 90), (180, 180), (90, 270)])
def test_rotation_metadata_turns_frames_as_players_do(tmp_path, pyav_degrees, shown):
    # PyAV 18 writes FFmpeg's display matrix (VideoStream.set_display_rotation, counter-clockwise degrees); the
    # mp4 muxer stores it as the track header's matrix, where phones put it
    path = make_video(tmp_path / "phone.mp4", rotation=pyav_degrees)
    if shown == 90:  # the matrix an iPhone held upright writes: a=0 b=1 c=-1 d=0, a quarter turn clockwise
        assert _tkhd_matrix(path.read_bytes()) == (0.0, 1.0, -1.0, 0.0)
    stored = picture(7)
    expected = np.rot90(stored, k=-shown // 90)  # clockwise
    with open_video(path) as r:
        assert r.rotation == shown
        assert (r.width, r.height) == ((H, W) if shown in (90, 270) else (W, H))
        f = next(f for f in r if f.index == 7)
    assert f.image.shape == expected.shape
    assert np.abs(f.image.astype(int) - expected.astype(int)).mean() < 12


def test_a_hand_written_track_header_matrix_is_honoured(tmp_path):
    """The phone's matrix patched into a plain MP4's track header (same bytes, no other change), PyAV not
    involved in writing it: the video reads as portrait, the stored top-left corner at the top right."""
    path = make_video(tmp_path / "plain.mp4")
    data = bytearray(path.read_bytes())
    at = data.find(b"tkhd")
    assert data[at + 4] == 0  # version 0
    start = at + 4 + 4 + 20 + 8 + 8
    iphone = (0, 0x10000, 0, -0x10000, 0, 0, H << 16, 0, 0x40000000)  # a b u / c d v / tx ty w, tx = height
    data[start:start + 36] = struct.pack(">9i", *iphone)
    path.write_bytes(bytes(data))
    with open_video(path) as r:
        assert (r.rotation, r.width, r.height) == (90, H, W)
        f = next(iter(r))
    assert f.image.shape == (W, H, 3)
    assert f.image[3, H - 4, 1] > 200 and f.image[3, 3, 1] < 60  # green corner: top right now


def test_variable_frame_rate_is_detected(tmp_path):
    times = np.cumsum([0] + [33, 50] * 10)[:20].tolist()  # 30 and 20 fps alternating, as phones do in low light
    mp4 = make_video(tmp_path / "vfr.mp4", n=20, times_ms=times)
    with open_video(mp4) as r:
        assert r.variable_rate  # from the MP4's sample table, before reading
        got = [f.time_s for f in r]
    assert np.allclose(got, np.array(times) / 1000, atol=1e-3)
    mkv = make_video(tmp_path / "vfr.mkv", n=20, times_ms=times)
    with open_video(mkv) as r:
        assert not r.variable_rate  # Matroska's cues list key frames only: not known before reading
        got = [f.time_s for f in r]
        assert r.variable_rate
    assert np.allclose(got, np.array(times) / 1000, atol=1e-3)
    even = make_video(tmp_path / "cfr.mkv", n=20, fps=24)  # 1 ms ticks: steps of 41 and 42 ms are one rate
    with open_video(even) as r:
        list(r)
        assert not r.variable_rate


def test_a_file_cut_short_yields_the_frames_before_the_cut(tmp_path):
    path = make_video(tmp_path / "full.mp4", noise=True, container_options={"movflags": "+faststart"})
    data = path.read_bytes()
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(data[:int(len(data) * 0.6)])
    with open_video(cut) as r:
        frames = list(r)
        assert 5 <= len(frames) < N and r.truncated
        problem = r.problem
    assert str(cut) in problem and "cut short" in problem and len(problem.splitlines()) == 1
    assert all(abs(red_x(f.image) - square_x(f.index)) <= 1 for f in frames[:-2])  # the good frames are right
    got = []
    with pytest.raises(InputError, match="cut short after frame") as e:
        with open_video(cut, strict=True) as r:
            for f in r:
                got.append(f.index)
    one_line_naming(e.value, cut)
    assert got == [f.index for f in frames]  # strict: the same frames first, then the error
    # an MP4 whose index is written last (the usual recording) cut before it: nothing to read
    plain = make_video(tmp_path / "rec.mp4", noise=True)
    cut.write_bytes(plain.read_bytes()[:int(plain.stat().st_size * 0.6)])
    with pytest.raises(InputError, match="cannot read as a video") as e:
        open_video(cut)
    one_line_naming(e.value, cut)


def _damage_packet(path, k: int):
    """Overwrite packet ``k``'s bytes (found by demuxing) with random bytes."""
    with av.open(str(path)) as c:
        packets = [p for p in c.demux(c.streams.video[0]) if p.size]
        pos, size = packets[k].pos, packets[k].size
    data = bytearray(path.read_bytes())
    data[pos:pos + size] = np.random.default_rng(1).integers(0, 256, size, dtype=np.uint8).tobytes()
    path.write_bytes(bytes(data))


def test_damaged_frames_are_skipped_and_counted_or_refused_in_strict_mode(tmp_path):
    path = make_video(tmp_path / "damaged.mp4", noise=True, options={"g": "1"})  # every frame a key frame
    _damage_packet(path, 12)
    with open_video(path) as r:
        frames = list(r)
        assert r.damaged >= 1 and not r.truncated
        assert "frame 12" in r.problem and str(path) in r.problem
    assert len(frames) == N - r.damaged
    times = [f.time_s for f in frames]
    assert 12 / FPS not in times and np.allclose(times[:12], np.arange(12) / FPS, atol=1e-3)
    assert all(abs(red_x(f.image) - square_x(round(f.time_s * FPS))) <= 1 for f in frames)
    with pytest.raises(InputError, match="frame 12 does not decode") as e:
        with open_video(path, strict=True) as r:
            for _ in r:
                pass
    one_line_naming(e.value, path)


def _audio_only(path):
    with av.open(str(path), "w") as c:
        s = c.add_stream("aac", rate=44100)
        frame = av.AudioFrame.from_ndarray(np.zeros((1, 1024), np.float32), format="fltp", layout="mono")
        frame.sample_rate = 44100
        for i in range(4):
            frame.pts = i * 1024
            for p in s.encode(frame):
                c.mux(p)
        for p in s.encode():
            c.mux(p)


def _zero_frames(path):
    with av.open(str(path), "w") as c:
        s = c.add_stream("libx264", rate=30)
        s.width, s.height, s.pix_fmt = W, H, "yuv420p"
        c.start_encoding()


def test_what_is_not_a_video_is_one_line_naming_the_file(tmp_path):
    from PIL import Image

    cases = {}
    (tmp_path / "notes.mp4").write_text("not a video\n")
    cases["notes.mp4"] = "cannot read as a video"
    (tmp_path / "noise.mp4").write_bytes(np.random.default_rng(0).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    cases["noise.mp4"] = "cannot read as a video"
    Image.fromarray(picture(0)).save(tmp_path / "photo.png")
    cases["photo.png"] = r"is an image \(PNG\)"
    Image.fromarray(picture(0)).save(tmp_path / "photo.jpg")
    cases["photo.jpg"] = r"is an image \(JPEG\)"
    (tmp_path / "empty.mp4").write_bytes(b"")
    cases["empty.mp4"] = "empty file"
    cases["missing.mp4"] = "file not found"
    (tmp_path / "folder.mp4").mkdir()
    cases["folder.mp4"] = "is a folder"
    _audio_only(tmp_path / "voice.m4a")
    cases["voice.m4a"] = r"no video stream \(audio only\)"
    _zero_frames(tmp_path / "nothing.mp4")
    cases["nothing.mp4"] = "no frames"
    # a playlist would make FFmpeg open the files (or addresses) it lists: refused, the listed file never read
    make_video(tmp_path / "real.mp4", n=3)
    (tmp_path / "list.m3u8").write_text(f"#EXTM3U\n#EXT-X-TARGETDURATION:1\n#EXTINF:1,\n{tmp_path / 'real.mp4'}\n"
                                        "#EXT-X-ENDLIST\n")
    cases["list.m3u8"] = "cannot read as a video"
    for name, message in cases.items():
        with pytest.raises(InputError, match=message) as e:
            open_video(tmp_path / name)
        one_line_naming(e.value, tmp_path / name)


def _ebsp_to_rbsp(b: bytes) -> bytes:
    out, zeros = bytearray(), 0
    for x in b:
        if zeros >= 2 and x == 3:
            zeros = 0
            continue
        out.append(x)
        zeros = zeros + 1 if x == 0 else 0
    return bytes(out)


def _rbsp_to_ebsp(b: bytes) -> bytes:
    out, zeros = bytearray(), 0
    for x in b:
        if zeros >= 2 and x <= 3:
            out.append(3)
            zeros = 0
        out.append(x)
        zeros = zeros + 1 if x == 0 else 0
    return bytes(out)


def _ue(v: int) -> str:
    """Exp-Golomb code of ``v`` as a bit string."""
    v += 1
    return "0" * (v.bit_length() - 1) + format(v, "b")


def _sps_with_size(nal: bytes, width: int, height: int) -> bytes:
    """An H.264 baseline sequence parameter set NAL (ITU-T H.264, 7.3.2.1.1) declaring ``width x height``."""
    bits = "".join(f"{x:08b}" for x in _ebsp_to_rbsp(nal[1:]))
    pos = 0

    def u(n):
        nonlocal pos
        pos += n
        return int(bits[pos - n:pos], 2)

    def ue():
        nonlocal pos
        z = bits.index("1", pos) - pos
        pos += z + 1 + z
        return (1 << z) - 1 + (int(bits[pos - z:pos], 2) if z else 0)

    assert u(8) == 66  # baseline: no chroma / scaling fields
    u(16)
    ue()  # seq_parameter_set_id
    ue()  # log2_max_frame_num_minus4
    poc = ue()
    assert poc in (0, 2)
    if poc == 0:
        ue()
    ue()  # max_num_ref_frames
    u(1)
    start = pos
    ue(), ue()  # pic_width_in_mbs_minus1, pic_height_in_map_units_minus1 (frame_mbs_only: map units = MBs)
    out = bits[:start] + _ue(width // 16 - 1) + _ue(height // 16 - 1) + bits[pos:]
    out = out.rstrip("0")  # the stop bit ends the SPS; pad again to whole bytes
    out += "0" * (-len(out) % 8)
    return nal[:1] + _rbsp_to_ebsp(int(out, 2).to_bytes(len(out) // 8, "big"))


def declared_size_video(folder, width: int, height: int):
    """A 3-frame 64 x 48 H.264 video (in MP4) whose sequence parameter set says ``width x height``: the size
    FFmpeg's decoder would allocate frames for; a few kB on disk."""
    raw = folder / "small.h264"
    with av.open(str(raw), "w", format="h264") as c:
        s = c.add_stream("libx264", rate=30, options={"profile": "baseline", "preset": "ultrafast"})
        s.width, s.height, s.pix_fmt = W, H, "yuv420p"
        for i in range(3):
            for p in s.encode(av.VideoFrame.from_ndarray(picture(i), format="rgb24")):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    data = raw.read_bytes()
    at = data.find(b"\x00\x00\x00\x01\x67") + 4
    end = data.find(b"\x00\x00\x00\x01", at)
    raw.write_bytes(data[:at] + _sps_with_size(data[at:end], width, height) + data[end:])
    out = folder / f"declared_{width}x{height}.mp4"
    # remuxed as it is (no decoding: the probe's decoders get a tiny max_pixels)
    with av.open(str(raw), options={"max_pixels": "1000"}) as src, av.open(str(out), "w") as dst:
        ist = src.streams.video[0]
        ost = dst.add_stream_from_template(ist)
        for k, p in enumerate(q for q in src.demux(ist) if q.size):
            p.stream = ost
            p.pts = p.dts = k
            p.time_base = Fraction(1, 30)
            dst.mux(p)
    return out


PEAK_SCRIPT = textwrap.dedent("""
    import resource, sys, time
    import av  # noqa: F401 - loaded before the baseline
    from facegeom.errors import InputError
    from facegeom.io.video import open_video
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    start = time.perf_counter()
    try:
        open_video(sys.argv[1])
        outcome = "opened"
    except InputError as exc:
        outcome = str(exc)
    seconds = time.perf_counter() - start
    grew = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
    print(f"{grew:.1f} {seconds:.3f} {outcome}")
""")


def test_frames_larger_than_the_limit_are_refused_from_the_header(tmp_path):
    big = declared_size_video(tmp_path, 8192, 8192)  # 67 megapixels: FFmpeg would decode it (~200 MB a frame)
    assert big.stat().st_size < 5000
    with av.open(str(big), options={"max_pixels": "1000"}) as c:
        assert (c.streams.video[0].width, c.streams.video[0].height) == (8192, 8192)
    out = subprocess.run([sys.executable, "-c", PEAK_SCRIPT, str(big)], capture_output=True, text=True, timeout=120,
                         cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    assert out.returncode == 0, out.stderr
    grew_mb, seconds, message = out.stdout.strip().split(" ", 2)
    assert "8192 x 8192 pixels (67.1 megapixels)" in message and "refused before decoding" in message
    assert str(big) in message
    # decoding one such frame while probing (what FFmpeg does unless told the limit) grows the peak by ~190 MB
    assert float(grew_mb) < 60, f"the peak memory grew by {grew_mb} MB"
    assert float(seconds) < 0.3, f"{seconds} s"
    # any limit: a 64 x 48 video under a 1000-pixel limit
    small = make_video(tmp_path / "small.mp4", n=3)
    with pytest.raises(InputError, match=r"64 x 48 pixels .* over the limit of 0.0 megapixels") as e:
        open_video(small, max_pixels=1000)
    one_line_naming(e.value, small)
    assert MAX_FRAME_PIXELS == 8192 * 4320


def test_a_16k_header_is_one_line(tmp_path):
    """A raw H.264 stream whose SPS says 16384 x 16384: past FFmpeg's own limit (``av_image_check_size``: under
    2^28 pixels with padding) its parser rejects the size, so the header shows none; nothing is allocated, no
    frame decodes, and that is one line, quickly."""
    raw = tmp_path / "huge.h264"
    with av.open(str(raw), "w", format="h264") as c:
        s = c.add_stream("libx264", rate=30, options={"profile": "baseline", "preset": "ultrafast"})
        s.width, s.height, s.pix_fmt = W, H, "yuv420p"
        for p in s.encode(av.VideoFrame.from_ndarray(picture(0), format="rgb24")):
            c.mux(p)
        for p in s.encode():
            c.mux(p)
    data = raw.read_bytes()
    at = data.find(b"\x00\x00\x00\x01\x67") + 4
    end = data.find(b"\x00\x00\x00\x01", at)
    raw.write_bytes(data[:at] + _sps_with_size(data[at:end], 16384, 16384) + data[end:])
    start = time.perf_counter()
    with pytest.raises(InputError, match=r"no frame of the video decodes \(\d+ packets read") as e:
        open_video(raw)
    assert time.perf_counter() - start < 1.0
    one_line_naming(e.value, raw)


def _rss() -> int:
    """This process's resident memory in bytes (Linux), else 0."""
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


def test_memory_stays_flat_however_long_the_video(tmp_path):
    w, h, n = 160, 120, 300  # 17 MB of RGB frames in all
    path = make_video(tmp_path / "long.mp4", n=n, w=w, h=h, options={"preset": "ultrafast"})
    alive = []
    tracemalloc.start()
    try:
        with open_video(path) as r:
            for k, f in enumerate(r):
                assert f.image.shape == (h, w, 3) and f.index == k
                alive.append(weakref.ref(f.image))  # the frame's pixels live in FFmpeg's buffer, not traced
                if k == 20:
                    rss = _rss()
            grew = _rss() - rss
            peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    del f
    assert len(alive) == n
    assert sum(ref() is not None for ref in alive) == 0  # the reader keeps no frame
    assert peak < 1 << 20, f"{peak / 1e6:.1f} MB of Python objects traced while reading"
    assert grew < 8 << 20, f"resident memory grew by {grew / 1e6:.1f} MB over {n - 20} frames"


def test_without_pyav_the_message_says_how_to_install_it(tmp_path, monkeypatch):
    from facegeom.io.extras import require_detector_runtime

    path = make_video(tmp_path / "clip.mp4", n=2)
    monkeypatch.setitem(sys.modules, "av", None)  # import av -> ImportError
    monkeypatch.setitem(sys.modules, "ai_edge_litert", None)
    with pytest.raises(InputError) as e:
        open_video(path)
    assert str(e.value) == f"{path}: reading video needs PyAV: pip install 'facegeom[video]'"
    with pytest.raises(InputError, match=r"writing video needs PyAV: pip install 'facegeom\[video\]'"):
        VideoWriter(tmp_path / "out.mp4", 30, W, H)
    assert not (tmp_path / "out.mp4").exists()
    with pytest.raises(InputError, match=r"face detector needs LiteRT .*pip install 'facegeom\[video\]'"):
        require_detector_runtime(path)


# ----------------------------------------------------------------------------- writing


def test_the_writer_round_trips_through_the_reader(tmp_path):
    assert writer_codec() == ("libx264" if "libx264" in av.codec.codecs_available else "mpeg4")
    out = tmp_path / "preview.mp4"
    with VideoWriter(out, FPS, W, H) as w:
        for i in range(N):
            w.write(picture(i))
    assert w.frames_written == N and out.is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["preview.mp4"]  # no temporary file left
    with open_video(out) as r:
        assert (r.width, r.height, r.n_frames, r.fps) == (W, H, N, 30.0)
        assert r.codec == ("h264" if w.codec == "libx264" else "mpeg4")
        frames = list(r)
    assert [abs(red_x(f.image) - square_x(f.index)) <= 1 for f in frames] == [True] * N


def test_the_writer_falls_back_to_mpeg4_and_pads_odd_sizes(tmp_path):
    out = tmp_path / "odd.mkv"
    with VideoWriter(out, 25, 63, 47, codec="mpeg4") as w:
        for i in range(5):
            w.write(picture(i, w=63, h=47))
    with open_video(out) as r:
        assert (r.codec, r.width, r.height) == ("mpeg4", 64, 48)  # one column and row repeated
        f = next(iter(r))
    assert np.abs(f.image[:47, :63].astype(int) - picture(0, w=63, h=47)).mean() < 12


def test_a_failed_write_leaves_nothing_at_the_destination(tmp_path):
    out = tmp_path / "preview.mp4"
    with pytest.raises(RuntimeError, match="detector crashed"):
        with VideoWriter(out, FPS, W, H) as w:
            for i in range(10):
                w.write(picture(i))
            raise RuntimeError("detector crashed")
    assert list(tmp_path.iterdir()) == []
    out.write_bytes(b"the previous preview")
    with pytest.raises(InputError, match=r"a frame must be \(48, 64, 3\) uint8"):
        with VideoWriter(out, FPS, W, H) as w:
            w.write(picture(0))
            w.write(picture(1, w=32))
    assert out.read_bytes() == b"the previous preview" and sorted(p.name for p in tmp_path.iterdir()) == [out.name]
    w = VideoWriter(out, FPS, W, H)
    w.write(picture(0))
    w.discard()
    assert out.read_bytes() == b"the previous preview" and len(list(tmp_path.iterdir())) == 1
    with pytest.raises(InputError, match="no frame was written"):
        VideoWriter(tmp_path / "empty.mp4", FPS, W, H).close()
    assert not (tmp_path / "empty.mp4").exists() and len(list(tmp_path.iterdir())) == 1


@pytest.mark.parametrize("args,message", [
    (("out.avi", 30, 64, 48), "unsupported video format '.avi'"),
    (("out.mp4", 0, 64, 48), r"fps must be in \(0, 1000\]"),
    (("out.mp4", float("nan"), 64, 48), r"fps must be in"),
    (("out.mp4", 30, 0, 48), "width must be"),
    (("out.mp4", 30, 64, 2.5), "height must be"),
    (("missing/out.mp4", 30, 64, 48), "output folder does not exist"),
])
def test_the_writer_refuses_bad_arguments_in_one_line(tmp_path, args, message):
    name, *rest = args
    with pytest.raises(InputError, match=message) as e:
        VideoWriter(tmp_path / name, *rest)
    assert len(str(e.value).splitlines()) == 1
    assert not any(p.is_file() for p in tmp_path.rglob("*"))


def test_a_colon_in_a_relative_name_is_a_file_not_a_protocol(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with VideoWriter("take:1.mp4", FPS, W, H) as w:  # FFmpeg alone would look for a protocol "take"
        for i in range(3):
            w.write(picture(i))
    with open_video("take:1.mp4") as r:
        assert len(list(r)) == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["take:1.mp4"]
