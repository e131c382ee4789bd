"""The fragment rule, in one place: a run that tracked less than ``EvalConfig.min_tracked_share`` of its frames is a
fragment (:func:`is_fragment`): its ATE and RPE are over the tracked part only. ``d2slam run`` and the study both ask
``RunRecord.fragment`` (:mod:`d2slam.run.record`); the study's tables ask :func:`is_fragment` of a median share over
seeds.
"""

from __future__ import annotations

import math

from d2slam.eval.config import EvalConfig


def tracked_share(tracked, frames) -> float:
    """The share of its frames a run tracked: ``tracked / frames`` (NaN when either is unknown or no frame ran)."""
    try:
        tracked, frames = float(tracked), float(frames)
    except (TypeError, ValueError):
        return math.nan
    return tracked / frames if frames > 0 and math.isfinite(tracked) and math.isfinite(frames) else math.nan


def is_fragment(share: float, min_share: float = EvalConfig().min_tracked_share) -> bool:
    """Whether a run (or a median over runs) that tracked ``share`` of its frames is a fragment: below ``min_share``
    (``EvalConfig.min_tracked_share``). An unknown share (NaN) is not."""
    return math.isfinite(share) and share < min_share


def fragment_fields(tracked, frames, min_share: float) -> dict:
    """What a run JSON says of the share tracked: ``tracked_share`` (rounded, None when unknown), ``fragment``,
    ``min_tracked_share`` and, for a fragment, ``fragment_note`` (its ATE and RPE are over the tracked part only)."""
    share = tracked_share(tracked, frames)
    out = {"tracked_share": round(share, 4) if math.isfinite(share) else None,
           "fragment": is_fragment(share, min_share), "min_tracked_share": min_share}
    if out["fragment"]:
        out["fragment_note"] = (f"tracked {float(tracked):g} of {float(frames):g} frames ({100 * share:.1f} %, below "
                                f"evaluation.min_tracked_share {min_share:g}): a fragment; its ATE and RPE are over "
                                "the tracked frames only, not a result for the sequence")
    return out
