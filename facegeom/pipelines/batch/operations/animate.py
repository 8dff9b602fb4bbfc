"""``animate``: Live Link Face takes -> character animation npz (as ``facegeom animate``)."""
from __future__ import annotations

import hashlib

import numpy as np

from facegeom.errors import InputError
from facegeom.pipelines.batch.cache import load_model, stamp
from facegeom.pipelines.batch.job import job_error
from facegeom.pipelines.batch.operations.base import (
    Operation,
    check_method,
    need_data,
)

__all__ = ["AnimateOperation"]


class _FitOnce:
    """A deformer whose ``fit`` is skipped when called again on the same rest mesh and markers."""

    def __init__(self, deformer):
        self.deformer = deformer
        self._key = None

    def fit(self, vertices, faces, handles):
        h = hashlib.sha1()
        for a in (vertices, faces, handles):
            a = np.ascontiguousarray(a)
            h.update(str((a.dtype, a.shape)).encode())
            h.update(a.tobytes())
        key = h.hexdigest()
        if key != self._key:
            self._key = None
            self.deformer.fit(vertices, faces, handles)
            self._key = key
        return self

    def deform(self, handle_positions):
        return self.deformer.deform(handle_positions)

    def __getattr__(self, name):  # deform_many and the rest of the deformer
        if name == "deformer":
            raise AttributeError(name)
        return getattr(self.deformer, name)


class AnimateOperation(Operation):
    """``animate``: takes -> animation npz (:func:`facegeom.pipelines.animate.write_animation_npz`)."""

    name = "animate"

    def prepare(self, job, spec, files):
        from facegeom.registry import parse_method

        s = {"start": 0, "frames": 100, "labels": 10, "seed": 0, "deformer": "tangent", **job.shared}
        if s["start"] < 0 or s["frames"] < 2 or s["labels"] < 2:
            raise job_error(job.source, "shared.start must be >= 0, shared.frames and shared.labels >= 2")
        if s["labels"] > s["frames"]:
            raise job_error(job.source, f"shared.labels {s['labels']} exceeds shared.frames {s['frames']}")
        spec["data"] = need_data(job, "animate")
        check_method(job, "retargeters")
        try:
            parse_method(s["deformer"]).build("deformers")
        except InputError as exc:
            raise job_error(job.source, f"shared.deformer {s['deformer']!r}: {exc}") from None
        spec["shared"] = s
        spec["stamp"] = stamp([spec["data"]])

    def outputs(self, job, spec, src, stem):
        return [stem.with_name(stem.name + ".npz")], {}

    def state(self, spec):
        from facegeom.registry import parse_method

        return {"model": load_model(spec),
                "deformer": _FitOnce(parse_method(spec["shared"]["deformer"]).build("deformers"))}

    def one(self, state, spec, item):
        from facegeom import registry
        from facegeom.pipelines.animate import animate_take

        s = spec["shared"]
        anim, _, ids = animate_take(state["model"], item["input"], s["start"], s["frames"], s["labels"], s["seed"],
                                    lambda: registry.create("retargeters", spec["method"], **spec["params"]),
                                    lambda: state["deformer"])
        return anim, ids

    def write(self, state, spec, item, result):
        from facegeom.pipelines.animate import write_animation_npz

        anim, ids = result
        write_animation_npz(item["outputs"][0], anim, ids)
        return {"face_err_mm_mean": float(anim.frame_error_mm.mean()),
                "face_err_mm_max": float(anim.frame_error_mm.max()),
                "marker_err_mm_mean": float(anim.marker_error_mm.mean())}
