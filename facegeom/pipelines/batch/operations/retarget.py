"""``retarget``: marker sequences with their labelled character frames -> retargeted sequences."""
from __future__ import annotations

import numpy as np

from facegeom.errors import InputError
from facegeom.pipelines.batch.job import job_error, resolve_template
from facegeom.pipelines.batch.operations.base import (
    Operation,
    check_method,
    vertex_errors,
)

__all__ = ["RetargetOperation"]


class RetargetOperation(Operation):
    """``retarget``: source sequences ``(T, p, 3)`` and labelled frames -> retargeted sequences."""

    name = "retarget"

    def prepare(self, job, spec, files):
        """Client side: require ``shared.labels`` (a path template) and check the retargeter.

        ``spec['shared']`` gets ``fill_gaps``.

        Raises
        ------
        InputError
            Naming the job: no ``shared.labels``, or a retargeter that cannot be
            built.
        """
        if "labels" not in job.shared:
            raise job_error(job.source, "retarget needs shared.labels, the labelled character frames of each source "
                                        "as a path template, e.g. \"labels/{stem}.csv\"")
        check_method(job, "retargeters")
        spec["shared"] = {"fill_gaps": bool(job.shared.get("fill_gaps", False))}

    def outputs(self, job, spec, src, stem):
        """One output per source: the retargeted sequence ``<stem>.<format>`` (``npz`` or ``csv``).

        Returns
        -------
        paths : list of Path
            The output.
        extra : dict
            ``labels``: the source's labelled-frames file (``shared.labels``
            resolved for ``src``).
        """
        return [stem.with_name(stem.name + "." + spec["format"])], \
            {"labels": str(resolve_template(job.base, job.shared["labels"], src))}

    def one(self, state, spec, item):
        """Read the source and its labelled frames and retarget (:func:`~facegeom.pipelines.single.retarget_files`).

        Returns
        -------
        Retargeted
            The character's markers ``(T, p, 3)`` float64 with the source and the
            labels they came from.

        Raises
        ------
        InputError
            Unreadable files, labels whose markers or frames do not match the
            source, fewer than two labelled frames, or lost source markers without
            ``shared.fill_gaps``.
        """
        from facegeom import registry
        from facegeom.pipelines.single import retarget_files

        return retarget_files(item["input"], item["extra"]["labels"],
                              lambda: registry.create("retargeters", spec["method"], **spec["params"]),
                              spec["shared"]["fill_gaps"])

    def write(self, state, spec, item, result):
        """Write the retargeted sequence with its labelled frames (:func:`~facegeom.pipelines.single.write_retargeted`).

        Returns
        -------
        dict
            ``frames`` (``T``), ``filled`` (lost source samples interpolated) and
            ``label_dev`` (largest coordinate difference between the result and a
            labelled frame).
        """
        from facegeom.pipelines.single import write_retargeted

        write_retargeted(item["outputs"][0], result)
        return {"frames": int(result.markers.shape[0]), "filled": int(result.filled),
                "label_dev": result.label_deviation}

    def evaluate(self, state, spec, item, result, truth):
        """Marker errors against a truth sequence holding frames ``0 .. T-1`` of the source (markers matched by name).

        Returns
        -------
        dict
            ``err_mean`` and ``err_max``: mean and largest marker distance, in the
            sequence's units.

        Raises
        ------
        InputError
            An unreadable truth, missing markers or frames, or a shape different
            from the result.
        """
        from facegeom.io import read_marker_sequence

        Y, names = result.markers, result.source.names
        tr = read_marker_sequence(truth).reorder(names, "truth")
        if tr.n_frames != Y.shape[0] or not np.array_equal(tr.frames, np.arange(Y.shape[0])):
            raise InputError(f"the truth must hold the frames 0..{Y.shape[0] - 1} of the source", truth)
        return vertex_errors(Y, tr.positions, "the truth", truth)
