"""``facegeom live``: a Live Link Face stream received, processed and relayed while the actor performs."""
from __future__ import annotations

from pathlib import Path

import click


@click.command("live")
@click.option("--listen", default=None, metavar="[HOST:]PORT",
              help="Receive the Live Link Face app's packets here (default 127.0.0.1:11111; another machine's "
                   "phone needs --listen 0.0.0.0:11111, given explicitly).")
@click.option("--replay", "replay_path", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Instead of listening, play a recording (.gesichter), a Live Link Face take (.csv) or a marker "
                   "capture (.c3d, solved on --rig first) at its own rate, as a phone would stream it.")
@click.option("--video", "video_path", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Instead of listening, track a video of a face as it plays (at its own rate; no phone, no "
                   "markers): the weights, head and eye rotations as the phone sends them (facegeom[video]).")
@click.option("--camera", default=None, metavar="N|DEVICE|URL",
              help="Instead of listening, track a camera as it films: its number (0 the first), a device "
                   "(/dev/video2, on Windows video=NAME) or a live stream's URL (rtsp://, udp://, srt://: an IP "
                   "camera, OBS). The newest frame is always the one tracked (facegeom[video]).")
@click.option("--rig", "rig_path", type=click.Path(), default=None,
              help="With --video, --camera or a --replay of a .c3d capture: the actor's own rig (from `facegeom track "
                   "--rig-out`, `facegeom identity` or any rig the capture's markers name); default the generic face.")
@click.option("--loop", is_flag=True, help="With --replay or --video: start over at the end.")
@click.option("--subject", default=None,
              help="Take only this subject's frames (default: the first subject heard; others are dropped).")
@click.option("--send", "sends", multiple=True, metavar="HOST:PORT",
              help="Relay the frames as Live Link Face packets (Unreal's Live Link sees a phone); repeatable.")
@click.option("--osc", "oscs", multiple=True, metavar="HOST:PORT",
              help="Send the weights as VMC-protocol OSC blendshapes (VTuber apps; VSeeFace listens on 39539); "
                   "repeatable.")
@click.option("--record", "record_path", type=click.Path(dir_okay=False), default=None, metavar="OUT",
              help="Write what was passed on when the session ends (Ctrl-C included): OUT.csv a Live Link Face "
                   "take, OUT.gesichter the packets, OUT.npz the values and arrival times, OUT.glb or OUT.usda/.usdc/"
                   ".usdz (with --character) the character performing it.")
@click.option("--character", "character_path", type=click.Path(), default=None, metavar="RIG",
              help="Your character's rig (an OBJ folder, .glb/.gltf or .npz, e.g. from `facegeom transfer`): its "
                   "shapes follow the stream by name, its head turns with the actor's.")
@click.option("--character-names", "character_map", type=click.Path(dir_okay=False), default=None,
              metavar="MAP.csv", help="With --character: a mapping CSV rig_shape,source_shape,gain.")
@click.option("--view", is_flag=True, help="Show the character following the stream in a window (needs "
                                           "--character).")
@click.option("--screenshot", type=click.Path(dir_okay=False), default=None,
              help="With --view: run the session to its end headless and render the last frame to this PNG.")
@click.option("--size", default="1280x800", show_default=True, metavar="WxH", help="With --view: window size.")
@click.option("--calibrate", type=float, default=None, metavar="SECONDS",
              help="The first SECONDS are the actor's rest (hold a neutral face): it becomes zero.")
@click.option("--smooth", type=click.Choice(["off", "one-euro"]), default="off", show_default=True,
              help="Smoothing: off, or the One-Euro filter (adaptive: strong on a still face, little lag in "
                   "motion; its lag is reported).")
@click.option("--frames", type=click.IntRange(1), default=None, help="Stop after N frames passed on.")
@click.option("--seconds", type=click.FloatRange(min=0, min_open=True), default=None, help="Stop after S seconds.")
@click.option("--quiet", is_flag=True, help="No status line while running.")
@click.pass_obj
def live_cmd(obj, listen, replay_path, video_path, camera, rig_path, loop, subject, sends, oscs, record_path, character_path, character_map, view,
             screenshot, size, calibrate, smooth, frames, seconds, quiet):
    """Receive a Live Link Face stream (or replay one) and pass it on live.

    Every datagram is checked before use; malformed ones, other subjects and frames superseded by newer ones
    are counted and dropped, never forwarded. Ctrl-C ends the session cleanly (the recording is written).
    """
    import sys

    from facegeom.errors import InputError
    from facegeom.io import check_outputs, check_writable_folder
    from facegeom.pipelines import live

    given = [flag for flag, v in (("--listen", listen), ("--replay", replay_path), ("--video", video_path),
                                  ("--camera", camera)) if v is not None]
    if len(given) > 1:
        raise InputError(f"{' and '.join(given)} are {len(given)} sources: give one")
    if rig_path is not None and replay_path is None and video_path is None and camera is None:
        raise InputError("--rig is the actor's rig for --video, --camera or a --replay of a .c3d capture (a phone "
                         "sends its weights already solved)", rig_path)
    if calibrate is not None and not (calibrate > 0 and calibrate < 1e6):
        raise InputError(f"--calibrate must be a positive number of seconds, got {calibrate}")
    if loop and replay_path is None and video_path is None:
        raise InputError("--loop goes with --replay or --video")
    if character_map is not None and character_path is None:
        raise InputError("--character-names goes with --character")
    if view and character_path is None:
        raise InputError("--view shows your character: give --character RIG")
    if screenshot is not None and not view:
        raise InputError("--screenshot goes with --view")
    glb = record_path is not None and Path(record_path).suffix.lower() in live.CHARACTER_SUFFIXES
    if glb and character_path is None:
        raise InputError(f"--record OUT{Path(record_path).suffix.lower()} records your character: give --character "
                         "RIG", record_path)
    if record_path is not None:
        if Path(record_path).suffix.lower() not in live.RECORD_SUFFIXES:
            raise InputError(f"--record must be one of {', '.join(live.RECORD_SUFFIXES)}", record_path)
    check_outputs([replay_path, video_path, rig_path, character_path, character_map], [record_path, screenshot])
    for out_path in (record_path, screenshot):
        if out_path is not None:
            check_writable_folder(out_path)
    if view:
        from facegeom.viewer.app import check_display, parse_size

        check_display(screenshot)
        width, height = parse_size(size)
    if loop and record_path is not None and frames is None and seconds is None:
        raise InputError("--loop with --record never ends on its own: add --frames or --seconds (or stop it with "
                         "Ctrl-C)")
    targets = [live.parse_address(s, what="--send") for s in sends]
    osc_targets = [live.parse_address(s, what="--osc") for s in oscs]
    stats = live.LiveStats()
    if replay_path is not None:
        rig = None
        if Path(replay_path).suffix.lower() == ".c3d":
            from facegeom.cli.rigopts import load_cli_rig

            rig = load_cli_rig(rig_path, obj.face_model)
        elif rig_path is not None:
            raise InputError("--rig goes with --video or a --replay of a .c3d capture (a take or recording already "
                             "holds the weights)", rig_path)
        source = live.ReplaySource(replay_path, loop=loop, stats=stats, subject=subject, rig=rig)
        for line in source.notes:
            click.echo(line)
        what = f"replaying {Path(replay_path).name} at {source.fps:g} fps"
    elif video_path is not None:
        from facegeom.pipelines.live_video import VideoSource

        if not Path(video_path).exists():
            raise InputError("no such file", video_path)
        actor = None
        if rig_path is not None:
            from facegeom.model import load_rig

            actor = load_rig(rig_path, obj.face_model)
        source = VideoSource(video_path, obj.face_model(), rig=actor, stats=stats, loop=loop, subject=subject)
        what = f"tracking {Path(video_path).name} live at {source.fps:g} fps"
    elif camera is not None:
        from facegeom.pipelines.live_video import CameraSource

        actor = None
        if rig_path is not None:
            from facegeom.model import load_rig

            actor = load_rig(rig_path, obj.face_model)
        source = CameraSource(camera, obj.face_model(), rig=actor, stats=stats, subject=subject)
        what = f"tracking the camera {source.camera.name} live ({source.fps:g} fps stated)"
    else:
        host, port = live.parse_address(listen or str(live.DEFAULT_PORT))
        source = live.UDPSource(host, port, subject=subject, stats=stats)
        what = f"listening on {source.host}:{source.port} (UDP)"
    steps = []
    if calibrate is not None:
        steps.append(live.Calibration(calibrate))
    if smooth == "one-euro":
        steps.append(live.OneEuro())
    sinks = [live.UDPSink(h, p, stats) for h, p in targets] + [live.OSCSink(h, p, stats) for h, p in osc_targets]
    recorder = live.Recorder(record_path) if record_path is not None and not glb else None
    if recorder is not None:
        sinks.append(recorder)
    character = None
    if character_path is not None:
        from facegeom.cli.rigopts import load_cli_rig

        character = live.CharacterSink(load_cli_rig(character_path, obj.face_model, names_map=character_map),
                                       keep=glb)
        sinks.append(character)
    session = live.LiveSession(source, steps, sinks, stats)
    out = ", ".join([f"sending to {h}:{p}" for h, p in targets] + [f"OSC (VMC) to {h}:{p}" for h, p in osc_targets]
                    + ([f"recording to {record_path}"] if record_path else []))
    click.echo(f"{what}; {out or 'passing nothing on (add --send or --record)'}; Ctrl-C to stop")
    tty = sys.stderr.isatty()

    def status(line):
        if quiet:
            return
        if tty:
            click.echo("\r" + line, nl=False, err=True)

    try:
        if view:
            from facegeom.viewer.live import LiveView

            v = LiveView(session, character, frames=frames, seconds=seconds,
                         name=Path(character_path).name)
            v.run(screenshot=screenshot, width=width, height=height, echo=click.echo)
            fps = v.viewer_fps(window=1e9)
            if fps is not None:
                click.echo(f"viewer: {fps:.0f} frames per second while receiving")
        else:
            session.run(frames=frames, seconds=seconds, status=status)
    finally:
        session.close()
        if tty and not quiet and not view:
            click.echo("", err=True)
        if glb:
            fps = source.fps if replay_path is not None or video_path is not None or camera is not None else 60.0
            written = character.write_glb(record_path, fps)
            count = len(character.kept_weights)
        else:
            written = recorder.write() if recorder is not None else None
            count = len(recorder.values) if recorder is not None else 0
    click.echo(stats.line())
    if getattr(source, "error", None):
        click.echo(f"the stream ended: {source.error}")
    if stats.first_error:
        click.echo(f"first malformed datagram: {stats.first_error}")
    if written is not None:
        click.echo(f"wrote {written} ({count} frames)")
    elif record_path is not None:
        click.echo(f"nothing received: {record_path} not written")
