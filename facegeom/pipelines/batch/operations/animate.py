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
        """Client side: check the animation settings and both methods, and resolve them into the task spec.

        ``spec['shared']`` gets the job's ``shared`` over the defaults ``start=0``,
        ``frames=100``, ``labels=10``, ``seed=0``, ``deformer="tangent"``;
        ``spec['data']`` the face data bundle and ``spec['stamp']`` its stamp.

        Raises
        ------
        InputError
            Naming the job: ``start < 0``, ``frames`` or ``labels`` below 2, more
            labels than frames, no face data, or a retargeter (the job's method) or
            ``shared.deformer`` that cannot be built.
        """
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
        """One output per take: the animation ``<stem>.npz``; no extra item data."""
        return [stem.with_name(stem.name + ".npz")], {}

    def state(self, spec):
        """The worker's face model and deformer, built once per process and job.

        The deformer skips ``fit`` when called again with the same rest mesh and
        markers: every take of a job drives the character of ``shared.seed``, so it
        is factorized once per worker.

        Returns
        -------
        dict
            ``model`` (FaceModel) and ``deformer``.
        """
        from facegeom.registry import parse_method

        return {"model": load_model(spec),
                "deformer": _FitOnce(parse_method(spec["shared"]["deformer"]).build("deformers"))}

    def one(self, state, spec, item):
        """Animate a window of the take ``item['input']`` (:func:`~facegeom.pipelines.animate.animate_take`).

        The window is frames ``start .. start + frames - 1``; a new retargeter
        (the job's method and params) per take, the worker's deformer.

        Returns
        -------
        anim : Animation
            Vertices ``(T, n, 3)`` float64 (cm), markers ``(T, 80, 3)``, per-frame
            errors ``(T,)`` in mm.
        ids : (80,) int64
            The ``ict80`` marker vertices.

        Raises
        ------
        InputError
            An unreadable take, or a window past its end.
        """
        from facegeom import registry
        from facegeom.pipelines.animate import animate_take

        s = spec["shared"]
        anim, _, ids = animate_take(state["model"], item["input"], s["start"], s["frames"], s["labels"], s["seed"],
                                    lambda: registry.create("retargeters", spec["method"], **spec["params"]),
                                    lambda: state["deformer"])
        return anim, ids

    def write(self, state, spec, item, result):
        """Write the animation npz (float32 vertices, :func:`~facegeom.pipelines.animate.write_animation_npz`).

        Returns
        -------
        dict
            ``face_err_mm_mean`` and ``face_err_mm_max`` (mean and largest of the
            per-frame face-area errors, mm) and ``marker_err_mm_mean`` (mm).
        """
        from facegeom.pipelines.animate import write_animation_npz

        anim, ids = result
        write_animation_npz(item["outputs"][0], anim, ids)
        return {"face_err_mm_mean": float(anim.frame_error_mm.mean()),
                "face_err_mm_max": float(anim.frame_error_mm.max()),
                "marker_err_mm_mean": float(anim.marker_error_mm.mean())}
