"""What a clean-up operation changed: vertex and face counts per step (printable, JSON)."""
from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path

from facegeom.io import atomic_path

__all__ = ["StepReport", "Report"]


@dataclass
class StepReport:
    """What one step changed.

    Attributes
    ----------
    name : str
        The step, as printed.
    vertices_before, vertices_after, faces_before, faces_after : int
    details : dict of str -> int
        Named counts (``merged_vertices``, ``split_copies``, ...).
    seconds : float
        Wall time of the step.
    """

    name: str
    vertices_before: int
    vertices_after: int
    faces_before: int
    faces_after: int
    details: dict[str, int] = field(default_factory=dict)
    seconds: float = 0.0

    @property
    def changed(self) -> bool:
        """True when the step changed a count."""
        return (self.vertices_before != self.vertices_after or self.faces_before != self.faces_after
                or any(self.details.values()))

    def line(self) -> str:
        """One printable line: the step's name and what it changed."""
        parts = []
        dv = self.vertices_after - self.vertices_before
        df = self.faces_after - self.faces_before
        if dv:
            parts.append(f"{dv:+,} vertices")
        if df:
            parts.append(f"{df:+,} faces")
        parts += [f"{v:,} {k.replace('_', ' ')}" for k, v in self.details.items() if v]
        return f"  {self.name:<40} {', '.join(parts) if parts else 'no change'}"


@dataclass
class Report:
    """Counts per step of one operation (printable, JSON-serialisable).

    Attributes
    ----------
    operation : str
        ``clean``, ``decimate`` or ``crop``.
    input_vertices, input_faces, output_vertices, output_faces : int
    steps : list of StepReport
    seconds : float
        Wall time of the whole operation.
    index_map : dict of str -> int
        :meth:`IndexMap.counts` of the result.
    markers : list of dict
        :meth:`CarriedMarkers.summary` of each carried marker file.
    notes : list of str
        Warnings (skipped steps, targets not reached).
    """

    operation: str
    input_vertices: int
    input_faces: int
    output_vertices: int = 0
    output_faces: int = 0
    steps: list[StepReport] = field(default_factory=list)
    seconds: float = 0.0
    index_map: dict[str, int] = field(default_factory=dict)
    markers: list[dict] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def changed(self) -> bool:
        """True when a step changed a count."""
        return any(s.changed for s in self.steps)

    def lines(self) -> list[str]:
        """The printable report: a headline, one line per step, the map, the markers and the notes."""
        out = [f"{self.operation}: {self.input_vertices:,} -> {self.output_vertices:,} vertices, "
               f"{self.input_faces:,} -> {self.output_faces:,} faces in {self.seconds:.2f} s"]
        out += [s.line() for s in self.steps]
        if self.index_map:
            c = self.index_map
            out.append(f"  index map: {c['kept']:,} kept, {c['merged']:,} merged, {c['removed']:,} removed, "
                       f"{c['split']:,} split copies, {c['new']:,} new")
        for m in self.markers:
            lost = f", {m['dropped']} lost and dropped" if m.get("dropped") else ""
            merged = f", {m['merged']} on merged vertices" if m.get("merged") else ""
            out.append(f"  markers {m['file']}: {m['carried']} carried{merged}{lost}"
                       + (f" -> {m['out']}" if m.get("out") else ""))
        out += [f"  note: {n}" for n in self.notes]
        return out

    def __str__(self) -> str:
        return "\n".join(self.lines())

    def to_dict(self) -> dict:
        """Everything as plain JSON types (each step with its ``changed`` flag)."""
        d = asdict(self)
        for s, sd in zip(self.steps, d["steps"]):
            sd["changed"] = s.changed
        return d

    def write_json(self, path: str | os.PathLike) -> Path:
        """Write :meth:`to_dict` as JSON, atomically; returns ``path``."""
        path = Path(path)
        with atomic_path(path) as tmp:
            tmp.write_text(json.dumps(self.to_dict(), indent=2) + "\n")
        return path
