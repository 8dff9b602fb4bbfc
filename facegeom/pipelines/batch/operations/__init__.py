"""The five operations of a batch job and their per-worker shared state.

``fit``, ``drive``, ``retarget``, ``animate`` and ``clean`` (:data:`OPS`), each
an :class:`Operation`: client-side checks of the job, the output files of an
input, the state a worker builds once per job, and per item compute, write
and error metrics against ground truth.
"""
from __future__ import annotations

from facegeom.pipelines.batch.operations.animate import AnimateOperation
from facegeom.pipelines.batch.operations.base import Operation
from facegeom.pipelines.batch.operations.clean import CleanOperation
from facegeom.pipelines.batch.operations.drive import DriveOperation
from facegeom.pipelines.batch.operations.fit import FitOperation
from facegeom.pipelines.batch.operations.retarget import RetargetOperation

__all__ = ["Operation", "OPS"]

OPS = {op.name: op for op in (FitOperation(), DriveOperation(), RetargetOperation(), AnimateOperation(),
                              CleanOperation())}
