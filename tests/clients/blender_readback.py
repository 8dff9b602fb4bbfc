"""Blender-side half of ``tests/test_real_client_blender.py``: import animated ``.glb`` files and report what plays.

Run by Blender, not by pytest::

    blender -b --factory-startup --python-exit-code 1 --python tests/clients/blender_readback.py -- \\
        OUT.json FPS FRAMES IN1.glb [IN2.glb ...]

``FPS`` is the files' frame rate (a whole number): the scene is set to it before each import, since Blender's
importer places a key at time ``t`` (seconds) on scene frame ``t * scene.render.fps``. ``FRAMES`` is a comma
separated list of scene frames to evaluate (``7.5`` evaluates frame 7 at subframe 0.5).

Each file is imported into an empty scene with the stock importer (``import_shading='SMOOTH'``: its default
normals mode needs a newer numpy than Debian ships with Blender 3.4). For the file's mesh object it reports
its shape key names and slider ranges, the key positions of the first weight and node curves, the rest
vertex positions, and per frame: the shape key values, the object's world matrix and the evaluated
(depsgraph) vertex positions in the object's local space. Each frame is evaluated twice: as imported
(``"played"``) and after widening every shape key's slider range to the range of its curve (``"widened"``).

Before the files, a one-triangle glTF written here is imported: if that fails the importer itself is unusable
in this Blender (a missing add-on or numpy) and ``OUT.json`` says ``{"status": "unusable", "reason": ...}``;
a failure on the files themselves is an error (a traceback, exit code 1). One JSON summary line is printed.
"""
import base64
import json
import os
import re
import struct
import sys
import tempfile
import traceback

import bpy


def _args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    if len(argv) < 4:
        raise SystemExit("usage: blender -b --python blender_readback.py -- OUT.json FPS FRAMES IN.glb [...]")
    fps = float(argv[1])
    if fps != int(fps) or fps <= 0:
        raise SystemExit(f"FPS must be a positive whole number (Blender's scene rate), got {argv[1]}")
    return argv[0], int(fps), [float(f) for f in argv[2].split(",")], argv[3:]


def _empty_scene(fps):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps = fps
    scene.render.fps_base = 1.0
    return scene


def _import(path):
    before = set(bpy.data.objects)
    result = bpy.ops.import_scene.gltf(filepath=path, import_shading="SMOOTH", merge_vertices=False)
    if "FINISHED" not in result:
        raise RuntimeError(f"the glTF importer returned {result} for {path}")
    return [o for o in bpy.data.objects if o not in before]


def _probe_importer(fps):
    """Import a one-triangle glTF (positions only, embedded buffer): the importer works at all -> None, else why."""
    data = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
           "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                          "min": [0, 0, 0], "max": [1, 1, 0]}],
           "bufferViews": [{"buffer": 0, "byteLength": len(data)}],
           "buffers": [{"byteLength": len(data),
                        "uri": "data:application/octet-stream;base64," + base64.b64encode(data).decode()}]}
    fd, path = tempfile.mkstemp(suffix=".gltf")
    try:
        with os.fdopen(fd, "w") as fh:
            json.dump(doc, fh)
        _empty_scene(fps)
        meshes = [o for o in _import(path) if o.type == "MESH"]
        if len(meshes) != 1 or len(meshes[0].data.vertices) != 3:
            return f"a one-triangle glTF gave {len(meshes)} mesh objects"
        return None
    except Exception:  # noqa: BLE001 - any failure here means the importer cannot be used
        return _cause(traceback.format_exc())
    finally:
        os.unlink(path)


def _cause(text):
    """The most telling line of a traceback (the importer's own error is nested in the operator's RuntimeError)."""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    errors = [ln for ln in lines if re.match(r"^[A-Za-z_.]*(Error|Exception)\b: ", ln)
              and not ln.startswith("RuntimeError: Error: Python: Traceback")]
    return (errors or lines or ["no message"])[-1][:300]


def _coords(vertices):
    flat = [0.0] * (3 * len(vertices))
    vertices.foreach_get("co", flat)
    return flat


def _evaluate(scene, obj, frames):
    keys = obj.data.shape_keys
    out = []
    for f in frames:
        whole = int(f // 1)
        scene.frame_set(whole, subframe=f - whole)
        depsgraph = bpy.context.evaluated_depsgraph_get()
        evaluated = obj.evaluated_get(depsgraph)
        mesh = evaluated.to_mesh()
        try:
            co = _coords(mesh.vertices)
        finally:
            evaluated.to_mesh_clear()
        out.append({"frame": f,
                    "values": [kb.value for kb in keys.key_blocks[1:]] if keys else [],
                    "matrix_world": [list(row) for row in obj.matrix_world],
                    "co": co})
    return out


def _key_frames(animation_data):
    """The frames of the first curve's keys (None without an action)."""
    if animation_data is None or animation_data.action is None or not animation_data.action.fcurves:
        return None
    return [kp.co[0] for kp in animation_data.action.fcurves[0].keyframe_points]


def _widen(keys):
    """Widen each shape key's slider range to the range of its animation curve, as a user would by hand."""
    action = keys.animation_data.action if keys and keys.animation_data else None
    for fc in action.fcurves if action else ():
        if not fc.data_path.startswith("key_blocks["):
            continue
        kb = keys.path_resolve(fc.data_path.rsplit(".", 1)[0])
        values = [kp.co[1] for kp in fc.keyframe_points]
        kb.slider_min = min(kb.slider_min, min(values))
        kb.slider_max = max(kb.slider_max, max(values))


def _read(path, fps, frames):
    scene = _empty_scene(fps)
    meshes = [o for o in _import(path) if o.type == "MESH"]
    if len(meshes) != 1:
        raise RuntimeError(f"{path}: {len(meshes)} mesh objects imported, expected one")
    obj = meshes[0]
    keys = obj.data.shape_keys
    report = {
        "path": path,
        "object": obj.name,
        "rotation_mode": obj.rotation_mode,
        "shape_keys": [kb.name for kb in keys.key_blocks[1:]] if keys else [],
        "basis": keys.key_blocks[0].name if keys else None,
        "sliders_as_imported": [[kb.slider_min, kb.slider_max] for kb in keys.key_blocks[1:]] if keys else [],
        "weight_key_frames": _key_frames(keys.animation_data if keys else None),
        "node_key_frames": _key_frames(obj.animation_data),
        "rest": _coords(obj.data.vertices),
        "played": _evaluate(scene, obj, frames),
    }
    _widen(keys)
    report["widened"] = _evaluate(scene, obj, frames)
    return report


def main():
    out, fps, frames, files = _args()
    result = {"blender": bpy.app.version_string, "fps": fps, "frames": frames}
    reason = _probe_importer(fps)
    if reason is not None:
        result.update(status="unusable", reason=f"Blender {bpy.app.version_string}'s glTF importer: {reason}")
    else:
        result.update(status="ok", files=[_read(os.path.abspath(p), fps, frames) for p in files])
    with open(out, "w") as fh:
        json.dump(result, fh)
    print(json.dumps({k: result[k] for k in ("status", "blender", "fps", "frames")} | {
        "reason": result.get("reason"),
        "files": [{"path": f["path"], "shape_keys": len(f["shape_keys"]), "vertices": len(f["rest"]) // 3}
                  for f in result.get("files", [])]}))


main()
