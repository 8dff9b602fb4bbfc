"""The 68 Multi-PIE landmark index sets used by fitting and its benchmarks."""
from __future__ import annotations

__all__ = ['INNER_LANDMARKS_49', 'FIT_LANDMARKS_23', 'EVAL_LANDMARKS_26', 'INNER_EYE_CORNERS', 'OUTER_EYE_CORNERS', 'MIRROR_68']


INNER_LANDMARKS_49: tuple[int, ...] = tuple(i for i in range(17, 68) if i not in (60, 64))


FIT_LANDMARKS_23: tuple[int, ...] = (
    17, 19, 21, 22, 24, 26,  # brows: outer ends, middles, inner ends
    27, 30, 31, 33, 35,  # nose: top of the bridge, tip, base (both wings, centre)
    36, 37, 39, 42, 44, 45,  # eyes: four corners + one upper-lid point per eye
    48, 51, 54, 57,  # outer lips: corners, upper / lower middle
    62, 66,  # inner lips: upper / lower middle (mouth opening)
)


EVAL_LANDMARKS_26: tuple[int, ...] = tuple(i for i in INNER_LANDMARKS_49 if i not in FIT_LANDMARKS_23)


INNER_EYE_CORNERS: tuple[int, int] = (39, 42)  # right eye inner, left eye inner


OUTER_EYE_CORNERS: tuple[int, int] = (36, 45)  # right eye outer, left eye outer


def _mirror_68() -> tuple[int, ...]:
    m = list(range(68))
    pairs = [(i, 16 - i) for i in range(8)]  # jaw
    pairs += [(17 + i, 26 - i) for i in range(5)]  # brows
    pairs += [(31, 35), (32, 34)]  # nose base
    pairs += [(36, 45), (37, 44), (38, 43), (39, 42), (40, 47), (41, 46)]  # eyes
    pairs += [(48, 54), (49, 53), (50, 52), (55, 59), (56, 58)]  # outer lips
    pairs += [(60, 64), (61, 63), (65, 67)]  # inner lips
    for a, b in pairs:
        m[a], m[b] = b, a
    return tuple(m)


MIRROR_68: tuple[int, ...] = _mirror_68()
"""Left/right mirror of the 68 landmark indices (``MIRROR_68[36] == 45``)."""
