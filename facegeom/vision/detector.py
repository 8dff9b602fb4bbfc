"""Faces in an image: MediaPipe's BlazeFace detectors (short and full range), decoded here.

Each detector is a single-shot network over a square input: for every anchor
(a fixed cell centre) it regresses a box and six keypoints (the eyes, the
nose tip, the mouth centre and both ear tragions) and scores the cell. The
model card gives the layout, which this module rebuilds:

============  =======  ==================================  ==========
model         input    anchors                             use
============  =======  ==================================  ==========
short range   128 px   16 x 16 cells x 2 + 8 x 8 x 6 = 896  faces within ~2 m (selfies, webcams)
full range    192 px   48 x 48 cells x 1 = 2304             faces up to ~5 m, small in the frame
============  =======  ==================================  ==========

Inputs are RGB scaled to [-1, 1]; offsets are in input pixels from the anchor
centre; scores are logits. The image is padded to a square (the detector
sees the whole frame, undistorted), reduced to the input size, and the boxes
are merged by weighted non-maximum suppression (overlapping boxes are
averaged by score, which steadies the box from frame to frame).

:class:`FaceDetector` with ``model="auto"`` (the default) runs the
short-range model, then, when it finds nothing, the full-range model, then
the image shrunk into the middle of a larger square: a face filling the
frame (a close-up) is larger than either model was trained on.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from facegeom.errors import InputError
from facegeom.vision.models import model_path
from facegeom.vision.runtime import Region, load_interpreter

__all__ = ["FaceDetection", "FaceDetector", "anchors", "weighted_nms"]

KEYPOINTS = ("right_eye", "left_eye", "nose_tip", "mouth", "right_ear", "left_ear")  # the subject's right and left
# model name -> (file, input side, [(stride, anchors per cell)])
_MODELS = {
    "short": ("face_detection_short_range.tflite", 128, [(8, 2), (16, 6)]),
    "full": ("face_detection_full_range.tflite", 192, [(4, 1)]),
}
MIN_SCORE = 0.5  # MediaPipe's own threshold for both detectors
NMS_IOU = 0.3  # boxes overlapping more than this are one face (MediaPipe's value)
ZOOM_OUT = 2.0  # the last "auto" try: the image in the middle of a square this many times its larger side


@dataclass(frozen=True)
class FaceDetection:
    """One face found in an image.

    Attributes
    ----------
    box : (4,) float64
        ``x0, y0, x1, y1`` in image pixels.
    keypoints : (6, 2) float64
        The subject's right eye, left eye, nose tip, mouth centre, right and left ear tragion, in image pixels.
    score : float
        The detector's confidence in [0, 1].
    """

    box: np.ndarray
    keypoints: np.ndarray
    score: float

    @property
    def width(self) -> float:
        """The box's width in pixels."""
        return float(self.box[2] - self.box[0])

    @property
    def area(self) -> float:
        """The box's area in square pixels."""
        return float(max(self.box[2] - self.box[0], 0) * max(self.box[3] - self.box[1], 0))

    def region(self, scale: float = 1.5) -> Region:
        """The square region the face-mesh model reads: the box's centre, ``scale`` times its larger side,
        turned so the eyes lie level (MediaPipe's detection-to-region rule)."""
        (rx, ry), (lx, ly) = self.keypoints[0], self.keypoints[1]
        angle = math.atan2(ly - ry, lx - rx)
        cx, cy = (self.box[0] + self.box[2]) / 2, (self.box[1] + self.box[3]) / 2
        side = max(self.box[2] - self.box[0], self.box[3] - self.box[1]) * scale
        return Region(float(cx), float(cy), float(side), float(angle))


def anchors(side: int, layers) -> np.ndarray:
    """The anchor centres ``(N, 2)`` in [0, 1] of a detector with input ``side`` and ``[(stride, per cell)]``."""
    out = []
    for stride, per_cell in layers:
        n = math.ceil(side / stride)
        g = (np.arange(n) + 0.5) / n
        xx, yy = np.meshgrid(g, g)
        centres = np.stack([xx.ravel(), yy.ravel()], axis=1)
        out.append(np.repeat(centres, per_cell, axis=0))
    return np.concatenate(out, axis=0)


def _iou(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    x0 = np.maximum(box[0], boxes[:, 0])
    y0 = np.maximum(box[1], boxes[:, 1])
    x1 = np.minimum(box[2], boxes[:, 2])
    y1 = np.minimum(box[3], boxes[:, 3])
    inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    area = lambda b: np.clip(b[..., 2] - b[..., 0], 0, None) * np.clip(b[..., 3] - b[..., 1], 0, None)  # noqa: E731
    union = area(box) + area(boxes) - inter
    return np.where(union > 0, inter / np.where(union > 0, union, 1), 0.0)


def weighted_nms(boxes: np.ndarray, keypoints: np.ndarray, scores: np.ndarray, iou: float = NMS_IOU):
    """Merge overlapping detections: each group around the best remaining box is averaged, weighted by score.

    Parameters
    ----------
    boxes : (N, 4), keypoints : (N, K, 2), scores : (N,)

    Returns
    -------
    list of (box, keypoints, score), best first; the score is the group's best.
    """
    order = np.argsort(-scores, kind="stable")
    boxes, keypoints, scores = boxes[order], keypoints[order], scores[order]
    left = np.ones(len(scores), dtype=bool)
    out = []
    for i in range(len(scores)):
        if not left[i]:
            continue
        group = left & (_iou(boxes[i], boxes) > iou)
        group[i] = True
        w = scores[group] / scores[group].sum()
        out.append(((w[:, None] * boxes[group]).sum(0), (w[:, None, None] * keypoints[group]).sum(0),
                    float(scores[i])))
        left &= ~group
    return out


def _square_input(image: np.ndarray, side: int, zoom: float = 1.0) -> tuple[np.ndarray, float, float, float]:
    """The image padded to a square (centred) ``zoom`` times its larger side, reduced to ``side`` pixels.

    Returns the input in [-1, 1] and the map back: image = input_unit * span - (offset_x, offset_y).
    """
    from PIL import Image

    h, w = image.shape[:2]
    span = max(h, w) * zoom
    ox, oy = (span - w) / 2, (span - h) / 2
    scale = side / span
    nw, nh = max(1, round(w * scale)), max(1, round(h * scale))
    small = np.asarray(Image.fromarray(np.ascontiguousarray(image)).resize((nw, nh), Image.BILINEAR, reducing_gap=2.0))
    x = np.zeros((side, side, 3), dtype=np.float32)
    px, py = int(round(ox * scale)), int(round(oy * scale))
    nh, nw = min(nh, side - py), min(nw, side - px)
    x[py:py + nh, px:px + nw] = small[:nh, :nw]
    # the exact offsets of the pasted image, in image pixels (rounding included)
    return x / 127.5 - 1.0, span, px / scale, py / scale


class FaceDetector:
    """MediaPipe's face detector: boxes and six keypoints of every face in an RGB image.

    Parameters
    ----------
    model : {"auto", "short", "full"}
        ``"short"``: the short-range model (faces near the camera); ``"full"``: the full-range model (small,
        far faces); ``"auto"``: short range, then full range, then the image zoomed out, until a face is found.
    min_score : float
        Detections below this confidence are dropped (MediaPipe's 0.5).
    threads : int
        Interpreter threads per model.

    Examples
    --------
    >>> faces = FaceDetector().detect(rgb)        # doctest: +SKIP
    >>> faces[0].box, faces[0].score              # doctest: +SKIP
    """

    def __init__(self, model: str = "auto", min_score: float = MIN_SCORE, threads: int = 1):
        if model not in ("auto", "short", "full"):
            raise InputError(f"model must be 'auto', 'short' or 'full', not {model!r}")
        if not (0.0 < float(min_score) < 1.0):
            raise InputError(f"min_score must lie in (0, 1), not {min_score!r}")
        self.model = model
        self.min_score = float(min_score)
        self.threads = int(threads)
        self._nets: dict[str, tuple] = {}

    def _net(self, name: str):
        if name not in self._nets:
            fname, side, layers = _MODELS[name]
            self._nets[name] = (load_interpreter(model_path(fname), self.threads), side, anchors(side, layers))
        return self._nets[name]

    def run(self, image: np.ndarray, name: str = "short", zoom: float = 1.0) -> list[FaceDetection]:
        """One detector on the whole image (padded to a square ``zoom`` times its larger side)."""
        image = _check_image(image)
        net, side, anc = self._net(name)
        x, span, ox, oy = _square_input(image, side, zoom)
        raw, logits = net(x[None])
        raw = raw.reshape(-1, 16)
        score = 1.0 / (1.0 + np.exp(-np.clip(logits.reshape(-1).astype(np.float64), -100, 100)))
        keep = score >= self.min_score
        if not keep.any():
            return []
        raw, score, anc = raw[keep].astype(np.float64), score[keep].astype(np.float64), anc[keep]
        c = raw[:, :2] / side + anc
        half = raw[:, 2:4] / side / 2
        boxes = np.concatenate([c - half, c + half], axis=1)
        kps = raw[:, 4:16].reshape(-1, 6, 2) / side + anc[:, None, :]
        faces = []
        shift = np.array([ox, oy]) + 0.5  # the input's continuous coordinates -> pixel centres at integers
        for box, kp, s in weighted_nms(boxes, kps, score):
            box = box * span - np.concatenate([shift, shift])
            faces.append(FaceDetection(box=box, keypoints=kp * span - shift, score=s))
        return faces

    def detect(self, image: np.ndarray) -> list[FaceDetection]:
        """Every face in ``image`` ((H, W, 3) uint8 RGB), best score first (empty when none)."""
        if self.model != "auto":
            return self.run(image, self.model)
        for name, zoom in (("short", 1.0), ("full", 1.0), ("short", ZOOM_OUT)):
            faces = self.run(image, name, zoom)
            if faces:
                return faces
        return []


def _check_image(image) -> np.ndarray:
    a = np.asarray(image)
    if a.ndim != 3 or a.shape[2] != 3 or a.dtype != np.uint8 or a.shape[0] < 1 or a.shape[1] < 1:
        raise InputError(f"an image must be (H, W, 3) uint8 RGB, not {a.shape} {a.dtype}")
    return a
