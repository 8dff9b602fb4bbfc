"""The 68 Multi-PIE landmark index sets used by fitting and its benchmarks.

Indices are into the 68 Multi-PIE / iBUG landmarks (``BlendshapeRig.landmark_ids``,
``FaceModel.landmarks``); the paper is the SEM paper (Kang et al., IEEE Access).

:data:`INNER_LANDMARKS_49` are the 49 inner points the paper evaluates on (17-67
without the inner lip corners 60 and 64).  The paper splits them into 23
*used* (fitted) and 26 *unused* (evaluation only) points (Fig. 6) but does not
list them; :data:`FIT_LANDMARKS_23` / :data:`EVAL_LANDMARKS_26` is our fixed
split.  Both halves are mirror-symmetric (left/right) and both cover every
region, so a method cannot score well on the unused points by overfitting one
region:

=============  ==============================  ================================
region         fit (23)                        eval (26)
=============  ==============================  ================================
brows          17 19 21 22 24 26 (ends, mid)   18 20 23 25
nose           27 30 31 33 35 (top, tip, base) 28 29 32 34
eyes           36 37 39 42 44 45 (corners,     38 40 41 43 46 47 (other lids,
               one upper-lid point each)       all lower lid points)
outer lips     48 51 54 57 (corners, mids)     49 50 52 53 55 56 58 59
inner lips     62 66 (mid points)              61 63 65 67
=============  ==============================  ================================

The inner eye corners 39 / 42 (the paper's inter-ocular normaliser, eq. 31)
are in the fitted set. :data:`INNER_EYE_CORNERS` and :data:`OUTER_EYE_CORNERS`
give those and the outer corners 36 / 45 (right eye first); :data:`MIRROR_68`
maps each landmark to its left/right mirror.
"""
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
