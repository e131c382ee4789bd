"""Semantic module of D2SLAM (eq 1-2): signed distance of each keypoint to each person mask's edge, the logistic
probability of being dynamic with the depth-adaptive slope beta(z), and the mask's uncertainty zone.

    d      = signed distance (px) from the keypoint's pixel to the edge of mask n: + inside, - outside     (eq 1)
    P_S    = 1 / (1 + exp(-beta(z) d)),  the largest over the masks                                     (eq 2)
    uncertain  <=>  |d| < ln(3) / beta(z)   (neither state reaches 75 %, fig 2)

``d`` is exactly the Euclidean distance transform of the mask (inside) and of its complement (outside) read at the
keypoint's rounded pixel, i.e. the distance between pixel centres to the nearest background pixel (inside) or the
nearest mask pixel (outside); the image border is not an edge (a person cut by the border continues out of view).

Deviation, measured (640x480, one person-sized ellipse mask, 1 thread, this project's 2-core build machine):
``cv2.distanceTransform(DIST_L2, DIST_MASK_PRECISE)`` costs 2.9 ms per full-image transform (scipy's
``distance_transform_edt`` 15 ms) and still 0.64 ms + 1.40 ms on crops around the mask (+ 80 px), so two masks
alone would exceed the 3 ms budget of all modules. We obtain the *same values* at the keypoints only: the nearest background pixel of an inside pixel is
4-adjacent to the mask, and the nearest mask pixel of an outside pixel is 4-adjacent to the background, so the
distance transforms at the keypoints equal nearest-neighbour distances to the border pixels of the mask and of its
complement (morphology on the mask's bounding box), found with ``scipy.spatial.cKDTree``. ``tests/test_dynamics
_semantic.py`` checks the equality against ``scipy.ndimage.distance_transform_edt`` on random masks. Outside
points are only searched within ``margin`` px of the mask (the classifier passes the widest uncertainty zone and
extends the search to the OIM's interaction zone only for the keypoints that need it, ``interaction.zone_distances``);
beyond it ``d = -max(margin, distance to the mask's bounding box)``, a lower bound of the true
distance that changes neither zone nor eq 7 (P_S is used by eq 7 only inside the mask area), and P_S there is below
1 / (1 + exp(beta margin)).

Special masks (documented recoveries):
- no masks (``None`` or ``(0, H, W)``) or an empty mask: the mask does not exist, ``d = -inf``, P_S = 0, no zone;
- a mask covering the whole image has no edge: every keypoint is inside at ``d = +hypot(H, W)`` (beyond any
  possible edge), so P_S -> 1 and there is no uncertainty zone (everything is a person).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree
from scipy.special import expit

from d2slam.config import DynamicsConfig
from .depth import uncertainty_width
from d2slam.errors import D2SlamError

_DEFAULT = DynamicsConfig()


_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))


def _nonzero_xy(img: np.ndarray, offset: np.ndarray) -> np.ndarray:
    pts = cv2.findNonZero(img)
    if pts is None:
        return np.zeros((0, 2))
    return pts.reshape(-1, 2).astype(np.float64) + offset


class MaskEdges:
    """Edge pixels of one person mask, built once per frame and queried for any set of keypoints.

    ``inner``: mask pixels 4-adjacent to the background (the nearest mask pixel of any outside pixel is one of them);
    ``outer``: background pixels 4-adjacent to the mask (the nearest background pixel of any inside pixel). Both are
    found on the bounding box + 1 px only (morphology with a 3x3 cross); the image border is not an edge. The
    cKDTrees are built lazily, on the first query that needs them."""

    def __init__(self, mask: np.ndarray):
        mb = mask if mask.dtype == bool else mask != 0
        self.mask = np.ascontiguousarray(mb).view(np.uint8)
        h, w = self.mask.shape
        self.shape = (h, w)
        self.diag = float(np.hypot(h, w))
        x, y, bw, bh = cv2.boundingRect(self.mask)
        self.bbox = (x, y, bw, bh)
        self.empty = bw == 0 or bh == 0
        self.full = False
        self._inner_tree = self._outer_tree = None
        if self.empty:
            return
        x0, y0, x1, y1 = max(x - 1, 0), max(y - 1, 0), min(x + bw + 1, w), min(y + bh + 1, h)
        self.crop = self.mask[y0:y1, x0:x1]
        self.offset = np.array([x0, y0], dtype=np.float64)
        self.outer = _nonzero_xy(cv2.dilate(self.crop, _CROSS) - self.crop, self.offset)
        self.full = len(self.outer) == 0  # no background pixel next to the mask: it covers the whole image

    def box_distance(self, pts: np.ndarray) -> np.ndarray:
        """Distance (px) of pixel positions (P, 2) to the mask's bounding box (0 inside it): a lower bound of the
        distance to the mask."""
        x, y, bw, bh = self.bbox
        gx = np.maximum(np.maximum(x - pts[:, 0], pts[:, 0] - (x + bw - 1)), 0.0)
        gy = np.maximum(np.maximum(y - pts[:, 1], pts[:, 1] - (y + bh - 1)), 0.0)
        return np.hypot(gx, gy)

    def signed(self, pu: np.ndarray, pv: np.ndarray, margin: float = np.inf) -> np.ndarray:
        """eq 1 at integer in-image pixels (pu, pv): + distance to the nearest background pixel inside, - distance to
        the nearest mask pixel outside (exact within ``margin``; ``-max(margin, box distance)`` beyond)."""
        n = len(pu)
        if self.empty:
            return np.full(n, -np.inf)
        if self.full:
            return np.full(n, self.diag)
        d = np.empty(n)
        inside = self.mask[pv, pu].view(bool)
        pts = np.stack([pu, pv], axis=1).astype(np.float64)
        if inside.any():
            if self._outer_tree is None:
                self._outer_tree = cKDTree(self.outer)
            d[inside], _ = self._outer_tree.query(pts[inside])
        out = ~inside
        if out.any():
            box = self.box_distance(pts[out])
            res = np.maximum(margin, box)
            near = box <= margin
            if near.any():
                if self._inner_tree is None:
                    inner = self.crop - cv2.erode(self.crop, _CROSS, borderType=cv2.BORDER_REPLICATE)
                    self._inner_tree = cKDTree(_nonzero_xy(inner, self.offset))
                q, _ = self._inner_tree.query(pts[out][near], distance_upper_bound=margin)
                res[near] = np.where(np.isfinite(q), q, res[near])
            d[out] = -res
        return d


def mask_edges(masks: np.ndarray | None) -> list[MaskEdges]:
    """One ``MaskEdges`` per mask of an (n, H, W) array (empty list for None)."""
    if masks is None:
        return []
    masks = np.asarray(masks)
    if masks.ndim != 3:
        raise D2SlamError(f"person masks must be an (n, H, W) array, got shape {masks.shape}")
    return [MaskEdges(masks[k]) for k in range(len(masks))]


def keypoint_pixels(kps: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pu, pv, finite): keypoints rounded to the nearest pixel and clipped to the image; non-finite ones -> (0, 0)."""
    kps = np.asarray(kps, dtype=np.float64).reshape(-1, 2)
    h, w = shape
    finite = np.all(np.isfinite(kps), axis=1)
    pix = np.where(finite[:, None], np.rint(kps), 0.0)
    pu = np.clip(pix[:, 0], 0, w - 1).astype(np.int64)
    pv = np.clip(pix[:, 1], 0, h - 1).astype(np.int64)
    return pu, pv, finite


def signed_distances(masks: np.ndarray | list[MaskEdges] | None, kps: np.ndarray,
                     margin: float | np.ndarray = np.inf) -> np.ndarray:
    """eq 1: (N, n) signed distance (px) of each keypoint to the edge of each mask, + inside, - outside.

    ``masks`` (n, H, W) bool, None, or the ``mask_edges`` of a frame (reused across calls); ``kps`` (N, 2) pixel
    (u, v), rounded to the nearest pixel and clipped to the image; non-finite keypoints get NaN. ``margin`` (scalar
    or (n,)): outside points farther than this from mask n get ``-max(margin, distance to the bounding box)`` (see
    the module docstring). The loop is over masks, never over keypoints or pixels.
    """
    edges = masks if isinstance(masks, list) else mask_edges(masks)
    kps = np.asarray(kps, dtype=np.float64).reshape(-1, 2)
    out = np.full((len(kps), len(edges)), -np.inf)
    if len(kps) == 0 or not edges:
        return out
    margins = np.broadcast_to(np.asarray(margin, dtype=np.float64), (len(edges),))
    pu, pv, finite = keypoint_pixels(kps, edges[0].shape)
    for k, e in enumerate(edges):
        out[:, k] = e.signed(pu, pv, float(margins[k]))
    out[~finite] = np.nan
    return out


def semantic_probability(d: np.ndarray, b: np.ndarray) -> np.ndarray:
    """eq 2: P_S = 1 / (1 + exp(-beta d)) (``scipy.special.expit``, no overflow). ``d = -inf`` gives 0, NaN gives NaN."""
    return expit(np.asarray(b, dtype=np.float64) * np.asarray(d, dtype=np.float64))


@dataclass
class SemanticResult:
    d: np.ndarray  # (N, n) signed distances to each mask's edge (eq 1)
    d_max: np.ndarray  # (N,) largest signed distance over the masks (-inf without masks); defines P_S
    p_s: np.ndarray  # (N,) eq 2, max over the masks (0 without masks)
    inside: np.ndarray  # (N,) bool: inside some mask (d_max > 0)
    uncertain: np.ndarray  # (N,) bool: |d_max| < ln(3) / beta(z), neither state reaches 75 %
    in_area: np.ndarray  # (N,) bool: inside a mask or in its uncertainty zone (the "mask area" of eq 7)


def semantic_module(masks: np.ndarray | list[MaskEdges] | None, kps: np.ndarray, b: np.ndarray,
                    margin: float | np.ndarray = np.inf, cfg: DynamicsConfig = _DEFAULT) -> SemanticResult:
    """eq 1-2 for all keypoints and masks. ``b`` (N,) is beta(z) of each keypoint (``depth.beta``).

    P_S is monotone in d for a given keypoint (same beta for every mask), so the largest P_S over the masks is the
    one of the largest signed distance ``d_max``; the uncertainty zone is taken on that same mask, i.e. it is exactly
    the set where the keypoint's P_S lies in (0.25, 0.75). Non-finite keypoints: P_S = 0, outside every area.
    """
    d = signed_distances(masks, kps, margin)
    b = np.asarray(b, dtype=np.float64).reshape(-1)
    n = d.shape[0]
    if d.shape[1] == 0:
        d_max = np.full(n, -np.inf)
    else:
        d_max = np.max(np.nan_to_num(d, nan=-np.inf), axis=1)
    p_s = semantic_probability(d_max, b)
    inside = d_max > 0
    with np.errstate(invalid="ignore"):
        uncertain = np.abs(d_max) < uncertainty_width(b, cfg)
    return SemanticResult(d=d, d_max=d_max, p_s=p_s, inside=inside, uncertain=uncertain,
                          in_area=inside | uncertain)
