"""``facegeom bench live``: the latency and the drops of ``facegeom live`` on loopback, with real packets.

A sender streams a real Live Link Face recording (think-biq/LLV's ``dao``, looped, renumbered) at 60 fps to a
session on 127.0.0.1, which relays every frame to a receiver. Per configuration (relay only, then each
processing step, then all of them):

- the session's latency: from a datagram's arrival to the moment the relay has sent it (p50 / p95 / p99);
- the end-to-end latency: from the sender's ``sendto`` to the receiver's ``recv`` (through the kernel twice);
- the session's CPU time per frame (it runs in its own process; the idle waits between frames included).

Then a burst: 3,000 packets sent back to back, counted on arrival (the kernel's socket buffer drops what does
not fit), superseded (all but the newest), and the time until the next fresh packet comes out.

With a clip (:func:`camera`), a camera as the source: another process streams the clip's frames into a named
pipe in real time, encoded one by one as a webcam's MJPEG, and ``facegeom live --camera PIPE`` tracks them:
the frames tracked per second, the ones superseded, the latency from a frame's decoding to its output.
"""
from __future__ import annotations

import csv
import socket
import threading
import time
from pathlib import Path

import numpy as np

from facegeom.io.livelink import encode_packet, parse_packet, read_recording
from facegeom.pipelines import live

__all__ = ["CONFIGS", "run_config", "burst", "run", "camera", "stream_into_pipe"]

CONFIGS = {
    "relay": (),
    "calibrate": ("calibrate",),
    "one-euro": ("one-euro",),
    "calibrate + one-euro + record": ("calibrate", "one-euro", "record"),
}


def _steps(names):
    steps, sinks = [], []
    for n in names:
        if n == "calibrate":
            steps.append(live.Calibration(1.0))
        elif n == "one-euro":
            steps.append(live.OneEuro())
        elif n == "record":
            sinks.append(live.Recorder(Path("unused.npz")))
    return steps, sinks


def _packets(recording: Path, n: int) -> list[bytes]:
    base = [parse_packet(p) for p in read_recording(recording)]
    out = []
    for i in range(n):
        p = base[i % len(base)]
        out.append(encode_packet(p.values, p.device_id, p.subject, i, 0.0, p.rate))
    return out


def _serve(name: str, frames: int, seconds: float, reply_to: int, conn) -> None:
    """The session, in its own process (so its CPU time is its own): tells the parent its port, relays to
    ``reply_to`` until ``frames`` frames went out or ``seconds`` passed, then sends back its numbers."""
    stats = live.LiveStats()
    source = live.UDPSource("127.0.0.1", 0, stats=stats)
    steps, sinks = _steps(CONFIGS[name])
    sinks.insert(0, live.UDPSink("127.0.0.1", reply_to, stats))
    session = live.LiveSession(source, steps, sinks, stats)
    conn.send(source.port)
    conn.recv()  # the parent is ready to send
    c0 = time.process_time()
    session.run(frames=frames, seconds=seconds)
    cpu = time.process_time() - c0
    session.close()
    conn.send({"p": stats.percentiles(), "out": stats.frames_out, "superseded": stats.superseded, "cpu": cpu})
    conn.close()


def run_config(name: str, recording: Path, frames: int = 600, fps: float = 60.0) -> dict:
    """One configuration streamed at ``fps`` for ``frames`` frames -> its row. The session runs in a child
    process; the sender and the receiver (for the end-to-end latency) in this one."""
    import multiprocessing as mp

    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(0.5)
    parent, child = mp.get_context("fork").Pipe()
    proc = mp.get_context("fork").Process(target=_serve, args=(name, frames, frames / fps + 5.0,
                                                               rx.getsockname()[1], child), daemon=True)
    proc.start()
    port = parent.recv()
    packets = _packets(recording, frames)
    sent_at = np.zeros(frames, dtype=np.int64)
    got_at = np.full(frames, -1, dtype=np.int64)

    def receive():
        while True:
            try:
                data = rx.recv(65536)
            except (TimeoutError, socket.timeout):
                return
            now = time.perf_counter_ns()
            k = parse_packet(data).frame
            if 0 <= k < frames:
                got_at[k] = now

    reader = threading.Thread(target=receive)
    reader.start()
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    parent.send("go")
    t0 = time.perf_counter()
    for i, p in enumerate(packets):
        due = t0 + i / fps
        while time.perf_counter() < due:
            time.sleep(min(0.002, max(0.0, due - time.perf_counter())))
        sent_at[i] = time.perf_counter_ns()
        tx.sendto(p, ("127.0.0.1", port))
    result = parent.recv() if parent.poll(frames / fps + 10.0) else {"p": {}, "out": 0, "superseded": 0,
                                                                      "cpu": float("nan")}
    proc.join(5.0)
    reader.join()
    tx.close()
    rx.close()
    ok = got_at >= 0
    e2e = (got_at[ok] - sent_at[ok]) / 1e6
    p = result["p"]
    return {"config": name, "frames_sent": frames, "frames_out": result["out"], "superseded": result["superseded"],
            "lost": int(frames - ok.sum()), "p50_ms": p.get("p50", float("nan")), "p95_ms": p.get("p95", float("nan")),
            "p99_ms": p.get("p99", float("nan")),
            "e2e_p50_ms": float(np.percentile(e2e, 50)) if e2e.size else float("nan"),
            "e2e_p99_ms": float(np.percentile(e2e, 99)) if e2e.size else float("nan"),
            "cpu_us_per_frame": result["cpu"] / max(result["out"], 1) * 1e6}


def burst(recording: Path, n: int = 3000) -> dict:
    """``n`` packets sent back to back at one session, then one more: what arrived, what was dropped, and how
    soon the fresh one came out."""
    stats = live.LiveStats()
    source = live.UDPSource("127.0.0.1", 0, stats=stats)
    packets = _packets(recording, n + 1)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    for p in packets[:n]:
        tx.sendto(p, ("127.0.0.1", source.port))
    time.sleep(0.05)
    first = source.poll(1.0)
    sent = time.perf_counter_ns()
    tx.sendto(packets[n], ("127.0.0.1", source.port))
    fresh = source.poll(1.0)
    after_ms = (time.perf_counter_ns() - sent) / 1e6 if fresh is not None else float("nan")
    tx.close()
    source.close()
    return {"sent": n, "arrived": stats.frames_in - (1 if fresh is not None else 0),
            "superseded": stats.superseded, "kernel_dropped": n - (stats.frames_in - (1 if fresh is not None else 0)),
            "newest_passed_on": first.frame if first is not None else -1,
            "fresh_frame_after_ms": after_ms}


def run(recording: Path, out: Path, frames: int = 600, burst_size: int = 3000, echo=print) -> list[dict]:
    """Every configuration, then the burst; writes ``live.csv`` and ``live-summary.md`` into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for name in CONFIGS:
        r = run_config(name, recording, frames)
        rows.append(r)
        echo(f"  {name}: p50 {r['p50_ms']:.3f} ms, p99 {r['p99_ms']:.3f} ms; end to end p50 {r['e2e_p50_ms']:.3f} ms; "
             f"{r['cpu_us_per_frame']:.0f} us CPU a frame; {r['frames_out']} of {r['frames_sent']} out")
    b = burst(recording, burst_size)
    with open(out / "live.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    lines = ["| configuration | latency p50 (ms) | p95 | p99 | end to end p50 (ms) | p99 | CPU / frame (us) | "
             "frames out / sent |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['config']} | {r['p50_ms']:.3f} | {r['p95_ms']:.3f} | {r['p99_ms']:.3f} | "
                     f"{r['e2e_p50_ms']:.3f} | {r['e2e_p99_ms']:.3f} | {r['cpu_us_per_frame']:.0f} | "
                     f"{r['frames_out']} / {r['frames_sent']} |")
    lines += ["", f"Burst: {b['sent']} packets back to back; {b['arrived']} reached the socket (the kernel dropped "
              f"{b['kernel_dropped']}), {b['superseded']} superseded, the newest passed on (frame "
              f"{b['newest_passed_on']}); the next fresh packet came out {b['fresh_frame_after_ms']:.2f} ms after it "
              "was sent."]
    (out / "live-summary.md").write_text("\n".join(lines) + "\n")
    echo("\n".join(lines))
    return rows + [b]


def stream_into_pipe(target: str, clip: Path, fps: float) -> None:
    """Stream ``clip``'s frames into the named pipe ``target`` as a live camera would: each encoded alone (MJPEG
    in NUT) and written at its time, ``fps`` a second. Returns when the last frame is written."""
    import os

    import av

    with av.open(str(clip)) as v:
        frames = [f.to_ndarray(format="rgb24") for f in v.decode(video=0)]
    # read-write: the open does not wait for a reader (FFmpeg would wait holding the interpreter's lock)
    with os.fdopen(os.open(target, os.O_RDWR), "wb", buffering=0) as pipe:
        out = av.open(pipe, "w", format="nut")
        st = out.add_stream("mjpeg", rate=int(round(fps)))
        st.height, st.width = frames[0].shape[:2]
        st.pix_fmt = "yuvj420p"
        t0 = time.perf_counter()
        for i, a in enumerate(frames):
            wait = t0 + i / fps - time.perf_counter()
            if wait > 0:
                time.sleep(wait)
            for packet in st.encode(av.VideoFrame.from_ndarray(a, format="rgb24")):
                out.mux(packet)
        for packet in st.encode(None):
            out.mux(packet)
        out.close()


def camera(model, clip: Path, fps: float = 30.0) -> dict:
    """A camera as the source (see the module docstring): the clip streamed by another process into a named
    pipe at ``fps``, tracked by :class:`facegeom.pipelines.live_video.CameraSource` -> its numbers."""
    import multiprocessing
    import os
    import tempfile

    from facegeom.pipelines.live_video import CameraSource

    with tempfile.TemporaryDirectory() as tmp:
        fifo = os.path.join(tmp, "camera")
        os.mkfifo(fifo)
        ctx = multiprocessing.get_context("fork")
        writer = ctx.Process(target=stream_into_pipe, args=(fifo, Path(clip), fps), daemon=True)
        writer.start()
        stats = live.LiveStats()
        source = CameraSource(fifo, model, stats=stats)
        first = source._taken
        session = live.LiveSession(source, [], [], stats)
        t0 = time.perf_counter()
        session.run()
        elapsed = time.perf_counter() - t0
        session.close()
        writer.join(10.0)
    p = stats.percentiles()
    return {"size": f"{source.camera.width}x{source.camera.height}", "fps": fps,
            "frames_filmed": first + stats.frames_out + stats.superseded + source.lost, "before_start": first,
            "tracked": stats.frames_out, "superseded": stats.superseded, "lost": source.lost,
            "tracked_per_s": stats.frames_out / elapsed, "p50_ms": p.get("p50", float("nan")),
            "p99_ms": p.get("p99", float("nan"))}
