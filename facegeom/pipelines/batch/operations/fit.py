"""``fit``: blendshape coefficients of landmark files (a chunk at a time when the fitter can), meshes, clouds.

With ``shared.identity = true`` the job first fits one identity per subject
folder (every input of the folder, jointly: :class:`~facegeom.methods.identity.IdentityFitter`),
writes it as ``identity.npz`` (a :class:`~facegeom.model.rig.BlendshapeRig`) next to the
folder's outputs, and fits every input's expression on that subject's rig. A worker fits a
folder's identity once and keeps it; two workers given inputs of one folder fit the same
identity (the fit is deterministic), and only the folder's first input writes it.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.interfaces import batched_targets, fit_many
from facegeom.pipelines.batch.cache import load_model, stamp
from facegeom.pipelines.batch.job import job_error, resolve_template
from facegeom.pipelines.batch.operations.base import (
    Operation,
    check_method,
    need_data,
    shared_path,
    timed,
)

__all__ = ["FitOperation", "IDENTITY_FILE"]

IDENTITY_FILE = "identity.npz"
"""The rig of a subject folder's fitted identity, written next to the folder's outputs."""


class FitOperation(Operation):
    """``fit``: coefficients ``(B,)`` per target -> ``.json``/``.csv`` weights; metrics against truth weights."""

    name = "fit"

    def prepare(self, job, spec, files):
        """Client side: resolve the rig and the camera, check the fitter, and record them in ``spec['shared']``.

        The rig is the ICT face (face data in ``spec['data']``) unless
        ``shared.rig`` names one, which is loaded once to check it. Landmark targets
        (``shared.kind`` ``landmarks``, or ``auto`` with a ``.csv`` or ``.pts`` input) need
        ``shared.focal``, ``cx`` and ``cy``, or ``shared.image``: a path template of
        each input's photo (``"{stem}.jpg"``), whose size gives what is not set
        (:func:`facegeom.model.photo_camera`). ``spec['shared']`` gets ``rig`` (path or
        None), ``kind``, ``camera`` (``[focal, cx, cy]``), ``image`` (the template and
        the job's folder, or None) and ``vectorised`` (the fitter solves landmark
        targets together).

        Raises
        ------
        InputError
            Naming the job: an unknown kind, a missing or broken rig, no face data,
            a missing camera, or a fitter that cannot be built.
        """
        from facegeom.io import TARGET_KINDS
        from facegeom.model import load_rig

        kind = job.shared.get("kind", "auto")
        if kind not in TARGET_KINDS:
            raise job_error(job.source, f"shared.kind {kind!r}: choose one of {', '.join(TARGET_KINDS)}")
        rig = job.shared.get("rig")
        if rig in (None, "ict"):
            spec["data"] = need_data(job, "the default rig (the ICT face)")
            rig = None
        else:
            rig = shared_path(job, "rig", dir_ok=True)
            try:
                load_rig(rig)  # a broken rig is the job's error, found before any task runs
            except InputError as exc:
                raise job_error(job.source, f"shared.rig: {exc}") from None
        cam = [job.shared.get(k) for k in ("focal", "cx", "cy")]
        image = job.shared.get("image")
        landmarks = kind == "landmarks" or (kind == "auto" and any(f.suffix.lower() in (".csv", ".pts") for f in files))
        if landmarks and image is None and any(c is None for c in cam):
            raise job_error(job.source, "landmark targets need the camera: set shared.focal, shared.cx and shared.cy "
                                        "(pixels), or shared.image (each input's photo, e.g. \"{stem}.jpg\")")
        if landmarks and cam[0] is not None and not cam[0] > 0:
            raise job_error(job.source, f"shared.focal must be a positive number (pixels), got {cam[0]!r}")
        fitter = check_method(job, "fitters")
        identity = job.shared.get("identity", False)
        if not isinstance(identity, bool):
            raise job_error(job.source, f"shared.identity must be true or false, got {identity!r}")
        folders: dict = {}
        if identity:
            if rig is not None:
                raise job_error(job.source, "shared.identity fits the face model's identity: it cannot be combined "
                                            "with shared.rig")
            spec["data"] = need_data(job, "the identity step")
            for f in files:
                folders.setdefault(str(f.parent), []).append(str(f))
        spec["shared"] = {"rig": rig, "kind": kind, "camera": cam, "identity": identity, "folders": folders,
                          "image": None if image is None else [image, str(job.base)],
                          "vectorised": "landmarks" in batched_targets(fitter)}
        spec["stamp"] = stamp([rig] if rig else [spec.get("data")])

    def outputs(self, job, spec, src, stem):
        """The weights file ``<stem>.<format>`` (``json`` or ``csv``); with the identity step, the first input of
        each subject folder also writes the folder's ``identity.npz``."""
        outs = [stem.with_name(stem.name + "." + spec["format"])]
        folder = spec["shared"]["folders"].get(str(src.parent))
        if folder and folder[0] == str(src):
            outs.append(stem.parent / IDENTITY_FILE)
        return outs, {}

    def _is_landmarks(self, spec, path: str) -> bool:
        kind = spec["shared"]["kind"]
        return kind == "landmarks" or (kind == "auto" and path.lower().endswith((".csv", ".pts")))

    @staticmethod
    def _camera(spec, path) -> list:
        """``[focal, cx, cy]`` of the input ``path``: the shared values, completed from its photo (shared.image)."""
        cam = spec["shared"]["camera"]
        image = spec["shared"].get("image")
        if image is None:
            return cam
        from facegeom.model import photo_camera

        return list(photo_camera(*cam, resolve_template(Path(image[1]), image[0], Path(path)))[:3])

    def default_chunk(self, job, spec, items):
        """64 items per task when the fitter batches landmark targets and every item is a landmark file, else 1."""
        lm = spec["shared"]["vectorised"] and all(self._is_landmarks(spec, it["input"]) for it in items)
        return 64 if lm else 1

    def state(self, spec):
        """Load the rig once per worker (its Gram and delta matrices precomputed) and build the fitter.

        Returns
        -------
        dict
            ``rig`` (BlendshapeRig) and ``fitter``.
        """
        from facegeom import registry
        from facegeom.model import load_rig

        rig = load_rig(spec["shared"]["rig"], lambda: load_model(spec))
        rig.gram()  # the Gram matrix, once per worker
        rig.delta_matrix()
        return {"rig": rig, "fitter": registry.create("fitters", spec["method"], **spec["params"]), "subjects": {}}

    def subject_rig(self, state, spec, folder: str):
        """The rig of ``folder``'s fitted identity (fitted on the folder's inputs once per worker).

        An input that cannot be read is left out of the identity fit (its own fit reports it);
        a folder with no readable input raises.
        """
        if folder not in state["subjects"]:
            from facegeom.methods.identity import IdentityFitter
            from facegeom.model import read_fit_target

            targets = []
            for f in spec["shared"]["folders"][folder]:
                try:
                    targets.append(read_fit_target(f, state["rig"], spec["shared"]["kind"], *self._camera(spec, f))[1])
                except InputError:
                    continue
            if not targets:
                raise InputError("no input of the subject folder could be read for its identity", folder)
            subject = IdentityFitter().fit(load_model(spec), targets).rig
            subject.gram()
            subject.delta_matrix()
            state["subjects"][folder] = subject
        return state["subjects"][folder]

    def _rig_of(self, state, spec, item):
        if not spec["shared"].get("identity"):
            return state["rig"]
        return self.subject_rig(state, spec, str(Path(item["input"]).parent))

    def compute(self, state, spec, items):
        """Fit a chunk: the landmark files together when the fitter batches them, the others one by one.

        The batch is one :func:`~facegeom.interfaces.fit_many`; a batched item's
        time is its reading time plus an equal share of the batch fit. When the
        batch fit raises, its items are fitted one by one, so only the bad one
        fails.

        Yields
        ------
        tuple of (dict, FitOutcome or Exception, float)
            The item, its :class:`~facegeom.pipelines.single.FitOutcome` (weights
            ``(B,)`` float64; no vertices from a batch fit) or the exception, and
            seconds.
        """
        if spec["shared"].get("identity"):  # one subject (rig) at a time
            groups: dict = {}
            for it in items:
                groups.setdefault(str(Path(it["input"]).parent), []).append(it)
            for folder, group in groups.items():
                try:
                    rig = self.subject_rig(state, spec, folder)
                except Exception as exc:  # noqa: BLE001 - the folder's items fail, the others go on
                    yield from ((it, exc, 0.0) for it in group)
                    continue
                yield from self._compute(rig, state, spec, group)
            return
        yield from self._compute(state["rig"], state, spec, items)

    def _compute(self, rig, state, spec, items):
        from facegeom.model import read_fit_target
        from facegeom.pipelines.single import FitOutcome, fit_file

        fitter = state["fitter"]
        batch = [it for it in items if spec["shared"]["vectorised"] and self._is_landmarks(spec, it["input"])]
        in_batch = {it["index"] for it in batch}
        single = [it for it in items if it["index"] not in in_batch]
        if batch:
            good, targets = [], []
            for it, res, dt in timed(lambda it: read_fit_target(it["input"], rig, "landmarks",
                                                                *self._camera(spec, it["input"])), batch):
                if isinstance(res, BaseException):
                    yield it, res, dt
                else:
                    good.append((it, dt))
                    targets.append(res[1])
            if targets:
                t0 = time.perf_counter()
                try:
                    res = fit_many(fitter, rig, targets)
                except Exception:  # noqa: BLE001 - one target broke the batch: fit them one by one to find it
                    single = [it for it, _ in good] + single
                else:
                    share = (time.perf_counter() - t0) / len(targets)
                    for k, (it, dt) in enumerate(good):
                        yield it, FitOutcome("landmarks", res[k].weights, res[k].info["camera"]), dt + share

        yield from timed(lambda it: fit_file(rig, it["input"], lambda: fitter, spec["shared"]["kind"],
                                             *self._camera(spec, it["input"])), single)

    def write(self, state, spec, item, result):
        """Write the item's coefficients by shape name, with the method, the target and a landmark fit's pose.

        Returns
        -------
        dict
            ``active``: the number of coefficients above 1e-6 in magnitude.
        """
        from facegeom.pipelines.single import write_fit

        write_fit(item["outputs"][0], state["rig"].names, result, spec["method"], item["input"])
        if len(item["outputs"]) > 1:  # the subject folder's identity
            self._rig_of(state, spec, item).save_npz(item["outputs"][1])
        return {"active": int(result.active.size)}

    def evaluate(self, state, spec, item, result, truth):
        """Coefficient and face errors of one fit against its truth weights file (:meth:`evaluate_many` of one pair).

        Returns
        -------
        dict or Exception
            ``coef_mae`` and ``coef_max`` (coefficients), ``err_mean`` and
            ``err_max`` (vertex distances between the fitted and the true face over
            all vertices, in the rig's units: cm for the ICT face). A truth file that
            cannot be read gives its exception, returned rather than raised.
        """
        return self.evaluate_many(state, spec, [(item, result)])[0]

    def evaluate_many(self, state, spec, pairs):
        """Coefficient and vertex errors; the faces of all pairs from one product ``D (W - W_true)``."""
        from facegeom.io import read_weights

        rig = state["rig"]
        out, dW, slots = [], [], []
        for it, res in pairs:
            try:
                wt = read_weights(it["truth"], rig.names)
            except Exception as exc:  # noqa: BLE001
                out.append(exc)
                continue
            dW.append(np.asarray(res.weights, dtype=np.float64) - wt)
            slots.append(len(out))
            out.append(None)
        if dW:
            dW = np.stack(dW)  # (K, B)
            E = rig.delta_matrix() @ dW.T  # (3n, K): the face difference of each pair, one GEMM
            d = np.sqrt((E.reshape(rig.n_vertices, 3, -1) ** 2).sum(axis=1))  # (n, K) per-vertex distances
            for j, slot in enumerate(slots):
                out[slot] = {"coef_mae": float(np.abs(dW[j]).mean()), "coef_max": float(np.abs(dW[j]).max()),
                             "err_mean": float(d[:, j].mean()), "err_max": float(d[:, j].max())}
        return out
