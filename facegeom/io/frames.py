"""Frame sources: a vertex sequence ``(T, n, 3)`` computed on demand, a chunk of frames at a time.

A long performance on a dense character does not fit in memory (100,000
frames of a 50,000-vertex mesh are 120 GB of float64). A :class:`FrameSource`
stands for such a sequence: its :attr:`~FrameSource.shape` is known, and
:meth:`~FrameSource.chunk` computes frames ``a .. b - 1`` when asked (a deformer
driving them, a file read in pieces, an array sliced). Writers that accept one
(:func:`facegeom.io.gltf.write_sequence_glb`) read it in chunks of
:attr:`~FrameSource.chunk_frames` frames and may ask for the same frames more
than once: a source must return the same values every time.

A source may also know its frames' linear structure (:class:`LinearFrames`:
every frame ``(C[t] @ basis).T`` for a fixed ``(q, n)`` basis, e.g. a deformer
driving the mesh through a fixed marker-to-vertex map); the writer then
encodes from the ``(T, 3, q)`` coefficients and the basis instead of driving
every frame at full resolution (:attr:`FrameSource.linear`).
"""
from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np

from facegeom.errors import InputError

__all__ = ["FrameSource", "LinearFrames", "CHUNK_BYTES"]

#: A chunk of frames holds at most this many bytes of float64 vertices (at least one frame).
CHUNK_BYTES = 64 * 2 ** 20


class LinearFrames(NamedTuple):
    """Frames that are one fixed basis combined: frame ``t`` is ``(coefficients[t] @ basis).T``, ``(n, 3)``.

    Attributes
    ----------
    coefficients : (T, 3, q) float64
        Row ``i`` of frame ``t``: the weights of the basis rows in coordinate ``i`` (x, y, z).
    basis : (q, n) float64
        ``q`` vertex fields (e.g. a marker-to-vertex map's rows, the rest shape's coordinates, a row of ones).
    """

    coefficients: np.ndarray
    basis: np.ndarray


class FrameSource:
    """``T`` frames of ``n`` vertices, computed by ``fn(a, b) -> (b - a, n, 3)`` when asked.

    Parameters
    ----------
    T : int
        Number of frames (at least 1).
    n : int
        Vertices per frame (at least 1).
    fn : callable
        ``fn(a, b)`` -> array_like ``(b - a, n, 3)``: frames ``a .. b - 1``
        (``0 <= a < b <= T``). Asked for the same frames twice, it must give
        the same values.
    chunk_frames : int, optional
        Frames per chunk; by default as many as fit in :data:`CHUNK_BYTES`.
    linear : LinearFrames or callable, optional
        The frames' linear structure (or a function computing it when first asked): the frames ``fn`` gives
        must equal ``(coefficients[t] @ basis).T`` up to float64 rounding. Writers may use it instead of
        ``fn`` (:func:`facegeom.io.gltf.write_sequence_glb`), and check a few frames against ``fn``.

    Attributes
    ----------
    shape : tuple of int
        ``(T, n, 3)``.
    chunk_frames : int
        Frames per chunk (at least 1, at most ``T``): as given, else as many
        as fit in :data:`CHUNK_BYTES` of float64 vertices.

    Examples
    --------
    >>> import numpy as np
    >>> base = np.zeros((4, 3))
    >>> src = FrameSource(10, 4, lambda a, b: base + np.arange(a, b)[:, None, None])
    >>> src.shape, src.chunk(2, 4)[:, 0, 0].tolist()
    ((10, 4, 3), [2.0, 3.0])
    """

    def __init__(self, T: int, n: int, fn: Callable[[int, int], np.ndarray], chunk_frames: int | None = None,
                 linear=None):
        T, n = int(T), int(n)
        if T < 1 or n < 1:
            raise InputError(f"a frame source needs at least one frame of at least one vertex, got T={T}, n={n}")
        if not callable(fn):
            raise InputError(f"a frame source needs a function fn(a, b) -> frames, got {type(fn).__name__}")
        self.shape = (T, n, 3)
        self._fn = fn
        step = CHUNK_BYTES // (24 * n) if chunk_frames is None else int(chunk_frames)
        self.chunk_frames = max(1, min(T, step))
        self._linear = linear

    @property
    def linear(self) -> LinearFrames | None:
        """The frames' :class:`LinearFrames` (computed on first access when given as a function), or None.

        Raises
        ------
        InputError
            Coefficients or basis of the wrong shape, or not finite.
        """
        lin = self._linear
        if lin is None:
            return None
        if callable(lin) and not isinstance(lin, tuple):
            lin = lin()
            if lin is None:
                self._linear = None
                return None
        C = np.asarray(lin[0], dtype=np.float64)
        B = np.asarray(lin[1], dtype=np.float64)
        T, n = self.shape[:2]
        if C.ndim != 3 or C.shape[:2] != (T, 3) or B.shape != (C.shape[2], n):
            raise InputError(f"a frame source's linear structure must be coefficients (T={T}, 3, q) and a basis "
                             f"(q, n={n}), got {C.shape} and {B.shape}")
        if not (np.isfinite(C).all() and np.isfinite(B).all()):
            raise InputError("a frame source's linear structure holds NaN or inf")
        self._linear = LinearFrames(C, B)
        return self._linear

    @classmethod
    def from_array(cls, frames, chunk_frames: int | None = None) -> FrameSource:
        """Wrap an in-memory (or memory-mapped) ``(T, n, 3)`` array, read a chunk at a time.

        Parameters
        ----------
        frames : array_like
            ``(T, n, 3)`` vertex positions, any real dtype (a ``numpy.memmap``
            too). Chunks of a float64 array are read-only views of it, others
            float64 copies.
        chunk_frames : int, optional
            Frames per chunk (default: :data:`CHUNK_BYTES` worth).

        Returns
        -------
        FrameSource
        """
        X = frames if isinstance(frames, np.ndarray) else np.asarray(frames)
        if X.ndim != 3 or X.shape[2] != 3 or X.shape[0] == 0 or X.shape[1] == 0:
            raise InputError(f"frames must have shape (T, n, 3) with T > 0, got {X.shape}")

        def frames(a: int, b: int) -> np.ndarray:
            view = X[a:b]
            view.flags.writeable = False  # the caller's data: a chunk is read, never changed
            return view

        return cls(X.shape[0], X.shape[1], frames, chunk_frames)

    def __len__(self) -> int:
        return self.shape[0]

    def __repr__(self) -> str:
        return f"FrameSource(T={self.shape[0]}, n={self.shape[1]})"

    def chunk(self, a: int, b: int) -> np.ndarray:
        """Frames ``a .. b - 1`` as a ``(b - a, n, 3)`` float64 array.

        Parameters
        ----------
        a, b : int
            ``0 <= a <= b <= T``.

        Returns
        -------
        (b - a, n, 3) float64
            ``fn``'s own array when it gives float64 (no copy: read it, do
            not change it), else a converted copy.

        Raises
        ------
        InputError
            A range outside the frames, or ``fn`` returning the wrong shape.
        """
        T, n = self.shape[:2]
        a, b = int(a), int(b)
        if not 0 <= a <= b <= T:
            raise InputError(f"frames {a}..{b - 1} asked of a {T}-frame source")
        if a == b:
            return np.empty((0, n, 3))
        X = np.asarray(self._fn(a, b), dtype=np.float64)
        if X.shape != (b - a, n, 3):
            raise InputError(f"the frame source gave shape {X.shape} for frames {a}..{b - 1}, "
                             f"expected {(b - a, n, 3)}")
        return X

    def chunks(self, a: int = 0, b: int | None = None):
        """Yield ``(start, frames)`` over frames ``a .. b - 1`` in chunks of :attr:`chunk_frames`.

        Parameters
        ----------
        a, b : int
            The range (all frames by default).

        Yields
        ------
        (int, (m, n, 3) float64)
            The first frame of the chunk and its frames.
        """
        b = self.shape[0] if b is None else b
        for s in range(a, b, self.chunk_frames):
            yield s, self.chunk(s, min(b, s + self.chunk_frames))
