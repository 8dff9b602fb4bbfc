"""The pieces every face model shares: the TFLite interpreter and rotated square crops.

The models run in LiteRT (``ai-edge-litert``, installed by ``pip install
'facegeom[video]'``), one interpreter thread each: facegeom processes frames
one after another and a second thread buys little on 192 x 192 inputs while
it doubles the CPU time a frame costs (measured on this project's 2-core
machine).

A *region* (:class:`Region`) is a square of the image, turned by an angle: the
models see the face upright whatever the head's roll. :func:`crop` samples it
into the model's input size (bilinear, black outside the image); the
region's :meth:`Region.to_image` maps model coordinates back to image pixels.
"""
from __future__ import annotations

import contextlib
import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facegeom.errors import InputError

__all__ = ["Region", "crop", "load_interpreter", "require_runtime"]


def require_runtime():
    """The LiteRT interpreter class, or one line saying what to install."""
    try:
        from ai_edge_litert.interpreter import Interpreter
    except ImportError:
        raise InputError("finding faces in pixels needs LiteRT: pip install 'facegeom[video]'") from None
    return Interpreter


@contextlib.contextmanager
def _quiet_stderr():
    """Silence the process's file descriptor 2 (C++ libraries write there, past Python's sys.stderr)."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):  # no real stderr (an embedding host): nothing to silence
        yield
        return
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
            yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


class _Model:
    """One TFLite model with its input and output tensors looked up once."""

    def __init__(self, path: Path, threads: int = 1):
        Interpreter = require_runtime()
        with _quiet_stderr():  # LiteRT's C++ prints an INFO line about its CPU delegate on every interpreter
            self.interpreter = Interpreter(model_path=str(path), num_threads=threads)
            self.interpreter.allocate_tensors()
        inp = self.interpreter.get_input_details()[0]
        self.input_index = inp["index"]
        self.input_shape = tuple(int(s) for s in inp["shape"])
        self.outputs = [d["index"] for d in self.interpreter.get_output_details()]

    @property
    def size(self) -> int:
        """The side of the square input, in pixels."""
        return self.input_shape[1]

    def __call__(self, x: np.ndarray) -> list[np.ndarray]:
        self.interpreter.set_tensor(self.input_index, x.reshape(self.input_shape).astype(np.float32, copy=False))
        self.interpreter.invoke()
        return [self.interpreter.get_tensor(i).copy() for i in self.outputs]


def load_interpreter(path: Path, threads: int = 1) -> _Model:
    """A loaded model (:class:`_Model`): call it with the input array, get its outputs."""
    return _Model(path, threads)


@dataclass(frozen=True)
class Region:
    """A square region of an image, turned by ``angle``.

    Attributes
    ----------
    cx, cy : float
        The centre, in image pixels: x right, y down, 0-based, the centre of pixel (row i, column j) at
        ``(j, i)`` (facegeom's convention, as :class:`facegeom.model.camera.PinholeCamera`; a ``.pts`` file adds 1).
    size : float
        The side, in image pixels.
    angle : float
        Radians: the region's x axis in the image is ``(cos angle, sin angle)`` (y down), so a face
        whose eye line falls to the right by ``angle`` is seen upright.
    """

    cx: float
    cy: float
    size: float
    angle: float = 0.0

    def axes(self) -> np.ndarray:
        """(2, 2): the region's unit x and y axes in the image, as rows."""
        c, s = math.cos(self.angle), math.sin(self.angle)
        return np.array([[c, s], [-s, c]])

    def to_image(self, uv: np.ndarray, side: int) -> np.ndarray:
        """Map ``(..., 2)`` coordinates in a ``side`` x ``side`` crop of this region to image pixels.

        Crop coordinates are continuous, crop pixel ``k`` covering ``[k, k + 1)`` (what the models read and
        return); ``(side / 2, side / 2)`` is the region's centre.
        """
        uv = np.asarray(uv, dtype=np.float64)
        local = (uv / side - 0.5) * self.size
        return local @ self.axes() + np.array([self.cx, self.cy])

    def to_region(self, xy: np.ndarray, side: int) -> np.ndarray:
        """The inverse of :meth:`to_image`: image pixels to crop coordinates."""
        local = (np.asarray(xy, dtype=np.float64) - np.array([self.cx, self.cy])) @ self.axes().T
        return (local / self.size + 0.5) * side

    def scaled(self, factor: float) -> "Region":
        """The same region, its side times ``factor``."""
        return Region(self.cx, self.cy, self.size * factor, self.angle)


def crop(image: np.ndarray, region: Region, side: int) -> np.ndarray:
    """Sample ``region`` of ``image`` into a ``(side, side, 3)`` float32 array in [0, 1] (bilinear, black outside).

    Only the part of the image under the region is read. A region many times
    larger than ``side`` (a face filling a 4K frame) is first reduced by a
    whole factor (box filter), so the bilinear taps do not skip pixels. The
    sampling is Pillow's affine transform (C, about 1 ms at 192 x 192).
    """
    from PIL import Image

    corners = region.to_image(np.array([[0, 0], [side, 0], [0, side], [side, side]], dtype=np.float64), side)
    H, W = image.shape[:2]
    x0 = int(min(max(math.floor(corners[:, 0].min()) - 2, 0), W))
    y0 = int(min(max(math.floor(corners[:, 1].min()) - 2, 0), H))
    x1 = int(max(min(math.ceil(corners[:, 0].max()) + 3, W), x0))
    y1 = int(max(min(math.ceil(corners[:, 1].max()) + 3, H), y0))
    if x1 <= x0 or y1 <= y0:
        return np.zeros((side, side, 3), dtype=np.float32)
    sub = Image.fromarray(np.ascontiguousarray(image[y0:y1, x0:x1]))
    step = region.size / side
    factor = int(step) if step >= 2.0 else 1
    factor = max(1, min(factor, sub.width, sub.height))
    if factor > 1:
        sub = sub.reduce(factor)
    # output point (u, v) (continuous, pixel u covers [u, u+1)) -> sub-image point, in the sub-image's pixels
    ax = region.axes() * (region.size / side / factor)
    # Pillow's coordinates put pixel j on [j, j + 1): ours (pixel j's centre at j) + 0.5
    origin = (np.array([region.cx + 0.5 - x0, region.cy + 0.5 - y0]) / factor) - (side / 2) * (ax[0] + ax[1])
    coeffs = (ax[0, 0], ax[1, 0], origin[0], ax[0, 1], ax[1, 1], origin[1])
    out = sub.transform((side, side), Image.AFFINE, coeffs, resample=Image.BILINEAR, fillcolor=(0, 0, 0))
    return np.asarray(out, dtype=np.float32) * np.float32(1 / 255)
