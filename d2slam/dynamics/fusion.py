"""Moving-probability fusion (eq 7) and the Bayesian filter of D2SLAM (eq 8).

Eq 7, four cases per keypoint ("mask area" = inside a mask or in its uncertainty zone):

    |                      | in the mask area                              | outside every mask area |
    | matched (P_g defined)| P = w P_g + (1 - w) P_S, w = 0.5 uncertain,   | P = P_g                 |
    |                      |                              0.1 reliable     |                         |
    | not matched          | P = P_S                                       | P = 0.5 (no observation)|

Eq 8, binary state (dynamic / static), prior bel(q) of the keypoint's predecessor:

    b- = (1 - eps) bel(q) + eps (1 - bel(q))                    prediction, symmetric transition eps = 0.1
    bel = P b- / (P b- + (1 - P)(1 - b-))                       update, P = likelihood of "dynamic" (eta normalises)

bel > 0.5 -> dynamic.

Ours (``OursConfig.neighbour_p_g``; measured: docs/deviations.md): a keypoint that is not matched takes
max(P, P_nb), P_nb the mean P_g of its matched neighbours at the same depth (``interaction.neighbour_p_g``), where it
has enough of them.

Ours (``FlowConfig.flow_edge_band``, with the flow only; measured: docs/deviations.md): a keypoint nothing
observed, just outside a mask (eq 1's signed distance in (-band, 0)), takes max(P, ``flow_edge_p``) (``edge_band``);
eq 7 leaves it at P_S < 0.5, static.

Ours (``OursConfig.silhouette_px``, off by default; measured: docs/deviations.md): a keypoint outside every mask
whose corner test at its detection scale reaches one (d in (-silhouette_px x s^octave, 0)) takes
max(P, ``silhouette_p``), matched or not (``edge_band``): its corner is the person's outline.
"""

from __future__ import annotations

import numpy as np

from d2slam.dynamics.config import DynamicsConfig
from d2slam.errors import D2SlamError

_DEFAULT = DynamicsConfig()


def fuse(p_s: np.ndarray, p_g: np.ndarray, observed: np.ndarray, in_area: np.ndarray, uncertain: np.ndarray,
         cfg: DynamicsConfig = _DEFAULT, p_nb: np.ndarray | None = None) -> np.ndarray:
    """eq 7: the moving probability P of each keypoint from P_S, P_g and the four cases above.

    ``observed`` = matched with P_g defined (a keypoint whose match has no F is "not matched"); ``in_area`` = inside
    a mask or in its uncertainty zone; ``uncertain`` selects w = ``omega_uncertain`` (0.5), else ``omega_reliable``
    (0.1). NaN P_S/P_g never leak: each case reads only the terms it uses. ``p_nb`` (ours, optional): the neighbours'
    P_g of each keypoint (NaN where it has too few); a keypoint that is not matched gets max(P, p_nb)."""
    p_s = np.asarray(p_s, dtype=np.float64)
    p_s = np.where(np.isnan(p_s), 0.0, p_s)
    p_g = np.asarray(p_g, dtype=np.float64)
    p_g = np.where(np.isnan(p_g), 0.0, p_g)
    observed = np.asarray(observed, dtype=bool)
    in_area = np.asarray(in_area, dtype=bool)
    w = np.where(np.asarray(uncertain, dtype=bool), cfg.omega_uncertain, cfg.omega_reliable)
    p = np.where(in_area,
                 np.where(observed, w * p_g + (1.0 - w) * p_s, p_s),
                 np.where(observed, p_g, cfg.p_no_observation))
    if p_nb is not None:
        p_nb = np.asarray(p_nb, dtype=np.float64)
        with np.errstate(invalid="ignore"):
            p = np.where(~observed & (p_nb > p), p_nb, p)  # NaN p_nb compares False
    return p


def check_edge_band(band: float, p_edge: float) -> None:
    """A clear error for a ``flow_edge_band`` that is not a finite number of px, or a ``flow_edge_p`` outside [0, 1]."""
    if not np.isfinite(band):
        raise D2SlamError(f"flow_edge_band must be a finite width in px (0 turns it off), got {band!r}")
    if not 0.0 <= p_edge <= 1.0:
        raise D2SlamError(f"flow_edge_p must be a probability in [0, 1], got {p_edge!r}")


def edge_band(p: np.ndarray, d_max: np.ndarray, observed: np.ndarray | None, band: float | np.ndarray,
              p_edge: float) -> tuple[np.ndarray, np.ndarray]:
    """eq 7, ours (``FlowConfig.flow_edge_band``, ``OursConfig.silhouette_px``): ``(P', edge)``, where ``edge`` marks
    the keypoints that are not ``observed`` (None: every keypoint) and lie outside every mask within ``band`` px of one
    (``d_max``, eq 1's largest signed distance, in (-band, 0); ``band`` one width or one per keypoint), and
    ``P' = max(P, p_edge)`` there, P elsewhere. ``band <= 0`` flags nothing (the interval is empty). ``d_max`` is
    -inf for a keypoint without masks or with non-finite coordinates, NaN compares False: neither is flagged."""
    p = np.asarray(p, dtype=np.float64)
    d_max = np.asarray(d_max, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        edge = (d_max < 0) & (d_max > -np.asarray(band, dtype=np.float64))
    if observed is not None:
        edge &= ~np.asarray(observed, dtype=bool)
    return np.where(edge, np.maximum(p, p_edge), p), edge


def prior_belief(n: int, matches: np.ndarray, prev_belief: np.ndarray, mappoint_belief: np.ndarray | None,
                 cfg: DynamicsConfig = _DEFAULT) -> np.ndarray:
    """eq 8: bel(q) of each current keypoint (N,).

    Precedence: the belief of the matched previous keypoint (through ``matches``) wins over the belief of the map
    point the keypoint is associated to (``mappoint_belief``, NaN when none), which wins over the prior 0.5 of a new
    keypoint. Why: eq 8 integrates over q_i, the keypoint's match in frame t-1, whose belief was updated one frame
    ago; the map point's belief can be older (it is written when the point is observed) and is the fallback that
    carries the state across frames where the frame-to-frame match was lost (as map-point beliefs do in DP-SLAM).
    NaN beliefs are ignored."""
    prior = np.full(n, cfg.prior, dtype=np.float64)
    if mappoint_belief is not None:
        mp = np.asarray(mappoint_belief, dtype=np.float64).reshape(-1)
        if len(mp) != n:
            raise D2SlamError(f"mappoint_belief has {len(mp)} entries for {n} keypoints")
        ok = np.isfinite(mp)
        prior[ok] = mp[ok]
    m = np.asarray(matches).reshape(-1, 2).astype(np.int64)
    if len(m):
        pb = np.asarray(prev_belief, dtype=np.float64).reshape(-1)[m[:, 1]]
        ok = np.isfinite(pb)
        prior[m[ok, 0]] = pb[ok]
    return np.clip(prior, 0.0, 1.0)


def predict(prior: np.ndarray, cfg: DynamicsConfig = _DEFAULT) -> np.ndarray:
    """eq 8, prediction: b- = (1 - eps) bel(q) + eps (1 - bel(q)); b- stays in [eps, 1 - eps]."""
    prior = np.asarray(prior, dtype=np.float64)
    return (1.0 - cfg.transition) * prior + cfg.transition * (1.0 - prior)


def bayes_update(prior: np.ndarray, p: np.ndarray, cfg: DynamicsConfig = _DEFAULT) -> np.ndarray:
    """eq 8: posterior belief of "dynamic" from the prior bel(q) and the eq 7 probability P (likelihood).

    The likelihood is clipped to [c, 1 - c], c = ``likelihood_clip`` (1e-3): with P exactly 0 or 1 the posterior would
    be exactly P whatever the prior (the history erased, and a belief of exactly 0/1 only the transition can undo).
    As b- is in [eps, 1 - eps] after prediction, the normaliser P b- + (1 - P)(1 - b-) is never 0."""
    b = predict(prior, cfg)
    c = cfg.ours.likelihood_clip
    lik = np.clip(np.asarray(p, dtype=np.float64), c, 1.0 - c)
    num = lik * b
    return num / (num + (1.0 - lik) * (1.0 - b))
