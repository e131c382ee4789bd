"""Semantic module of D2SLAM (eq 1-2): signed distance of each keypoint to each person mask's edge, the logistic
probability of being dynamic with the depth-adaptive slope beta(z), and the mask's uncertainty zone.

    d      = signed distance (px) from the keypoint's pixel to the edge of mask n: + inside, - outside     (eq 1)
    P_S    = 1 / (1 + exp(-beta(z) d)),  the largest over the masks                                     (eq 2)
    uncertain  <=>  |d| < ln(3) / beta(z)   (neither state reaches 75 %, fig 2)

``d`` is exactly the Euclidean distance transform of the mask (inside) and of its complement (outside) read at the
keypoint's rounded pixel, i.e. the distance between pixel centres to the nearest background pixel (inside) or the
nearest mask pixel (outside); the image border is not an edge (a person cut by the border continues out of view).

Deviation, for speed: distance transforms of the image (``cv2.distanceTransform``, scipy's
``distance_transform_edt``), even on crops around each mask, would with two masks alone exceed the 3 ms budget of
all modules (measured: docs/deviations.md, ``semantic.semantic_module``). We obtain the *same values* at the
keypoints only: the nearest background pixel of an inside pixel is 4-adjacent to the mask, and the nearest mask
pixel of an outside pixel is 4-adjacent to the background, so the distance transforms at the keypoints equal
nearest-neighbour distances to the edge pixels of the mask and of its complement (on the mask's bounding box),
found by the compiled kernels of ``d2slam.dynamics.kernels`` (the edge pixels by row, searched outwards from the
keypoint's row). ``tests/test_dynamics_semantic.py`` checks the equality against
``scipy.ndimage.distance_transform_edt`` on random masks. Outside points are only searched within ``margin`` px of
the mask (the classifier passes the widest uncertainty zone and extends the search to the OIM's interaction zone
only for the keypoints that need it, ``interaction.oim_frame``); beyond it ``d = -max(margin, distance to the mask's
bounding box)``, a lower bound of the true distance that changes neither zone nor eq 7 (P_S is used by eq 7 only
inside the mask area), and P_S there is below 1 / (1 + exp(beta margin)).

Per frame the work is shared (``FrameMasks``): the keypoints are rounded once (``KeypointPixels``), each mask's
edges, bounding-box distances and pixel lookups are computed once and reused by the OIM's zone test.
``d2slam bench dynamics`` times all modules per frame; ``tests/test_dynamics_equivalence.py`` checks that every
output equals its stored reference (``tests/data/dynamics_reference.npz``).

Special masks (documented recoveries):
- no masks (``None`` or ``(0, H, W)``) or an empty mask: the mask does not exist, ``d = -inf``, P_S = 0, no zone;
- a mask covering the whole image has no edge: every keypoint is inside at ``d = +hypot(H, W)`` (beyond any
  possible edge), so P_S -> 1 and there is no uncertainty zone (everything is a person).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.special import expit

from d2slam.dynamics.config import DynamicsConfig
from d2slam.dynamics.depth import uncertainty_width
from d2slam.dynamics.kernels import edge_rows, nearest_sq
from d2slam.errors import D2SlamError

_DEFAULT = DynamicsConfig()
_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))


class KeypointPixels:
    """A frame's keypoints rounded to the nearest pixel and clipped to the image, computed once per frame and shared
    by every mask and module: ``pu``, ``pv`` (N,) int64, ``pts`` (N, 2) float64 (the same pixels), ``finite`` (N,)
    bool (non-finite keypoints sit at pixel (0, 0) and are flagged), ``flat`` (N,) row-major pixel index."""

    __slots__ = ("pu", "pv", "pts", "finite", "flat", "shape")

    def __init__(self, kps: np.ndarray, shape: tuple[int, int]):
        kps = np.asarray(kps, dtype=np.float64).reshape(-1, 2)
        h, w = shape
        self.shape = (h, w)
        self.finite = np.isfinite(kps[:, 0]) & np.isfinite(kps[:, 1])
        pix = np.rint(kps)
        if not self.finite.all():
            pix[~self.finite] = 0.0
        self.pts = np.minimum(np.maximum(pix, 0.0), np.array([w - 1, h - 1], dtype=np.float64))
        self.pu = self.pts[:, 0].astype(np.int64)
        self.pv = self.pts[:, 1].astype(np.int64)
        self.flat = self.pv * w + self.pu


class MaskEdges:
    """Edge pixels of one person mask, built once per frame and queried for any set of keypoints.

    *inner*: mask pixels 4-adjacent to the background (the nearest mask pixel of any outside pixel is one of them);
    *outer*: background pixels 4-adjacent to the mask (the nearest background pixel of any inside pixel). Both are
    found on the bounding box + 1 px only (morphology with a 3x3 cross) and listed by row (``kernels.edge_rows``; the
    inner edge on first use); the image border is not an edge. ``outer`` / ``inner`` give them as (P, 2) float64
    (x, y) in row-major order."""

    def __init__(self, mask: np.ndarray):
        mb = mask if mask.dtype == bool else mask != 0
        self.mask = np.ascontiguousarray(mb).view(np.uint8)
        self.flat = self.mask.reshape(-1)
        h, w = self.mask.shape
        self.shape = (h, w)
        self.diag = float(np.hypot(h, w))
        x, y, bw, bh = cv2.boundingRect(self.mask)
        self.bbox = (x, y, bw, bh)
        self.empty = bw == 0 or bh == 0
        self.full = False
        if self.empty:
            return
        x0, y0, x1, y1 = max(x - 1, 0), max(y - 1, 0), min(x + bw + 1, w), min(y + bh + 1, h)
        self.crop = self.mask[y0:y1, x0:x1]
        self.origin = (x0, y0)
        self._outer = edge_rows(cv2.dilate(self.crop, _CROSS) - self.crop)
        self._inner = None
        self.full = len(self._outer[1]) == 0  # no background pixel next to the mask: it covers the whole image

    def _points(self, rows: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        start, xs = rows
        y = np.repeat(np.arange(len(start) - 1), np.diff(start))
        return np.stack([xs + self.origin[0], y + self.origin[1]], axis=1).astype(np.float64)

    @property
    def outer(self) -> np.ndarray:
        """(P, 2) background pixels 4-adjacent to the mask."""
        return self._points(self._outer)

    @property
    def inner(self) -> np.ndarray:
        """(P, 2) mask pixels 4-adjacent to the background."""
        return self._points(self._inner_rows())

    def _inner_rows(self) -> tuple[np.ndarray, np.ndarray]:
        if self._inner is None:  # on first use
            self._inner = edge_rows(self.crop - cv2.erode(self.crop, _CROSS, borderType=cv2.BORDER_REPLICATE))
        return self._inner

    def box_distance(self, pts: np.ndarray) -> np.ndarray:
        """Distance (px) of pixel positions (P, 2) to the mask's bounding box (0 inside it): a lower bound of the
        distance to the mask."""
        x, y, bw, bh = self.bbox
        gx = np.maximum(np.maximum(x - pts[:, 0], pts[:, 0] - (x + bw - 1)), 0.0)
        gy = np.maximum(np.maximum(y - pts[:, 1], pts[:, 1] - (y + bh - 1)), 0.0)
        return np.hypot(gx, gy)

    def signed_px(self, pts: np.ndarray, inside: np.ndarray, box: np.ndarray, margin: float = np.inf) -> np.ndarray:
        """eq 1 at pixel positions ``pts`` (P, 2) given the mask at them (``inside``, (P,) bool) and their distances
        to its bounding box (``box``, (P,)): + distance to the nearest background pixel inside, - distance to the
        nearest mask pixel outside, exact within ``margin``, ``-max(margin, box)`` beyond (the box test: an outside
        keypoint farther than ``margin`` from the bounding box is never searched)."""
        n = len(pts)
        if self.empty:
            return np.full(n, -np.inf)
        if self.full:
            return np.full(n, self.diag)
        d = -np.maximum(margin, box)
        x0, y0 = self.origin
        if inside.any():
            q = pts[inside].astype(np.int64)
            d[inside] = np.sqrt(nearest_sq(*self._outer, x0, y0, q[:, 0], q[:, 1], np.inf))
        near = (box <= margin) & ~inside
        if near.any():
            q = pts[near].astype(np.int64)
            d2 = nearest_sq(*self._inner_rows(), x0, y0, q[:, 0], q[:, 1], float(margin))
            found = np.isfinite(d2)
            d[np.flatnonzero(near)[found]] = -np.sqrt(d2[found])
        return d

    def signed(self, pu: np.ndarray, pv: np.ndarray, margin: float = np.inf) -> np.ndarray:
        """eq 1 at integer in-image pixels (pu, pv): + distance to the nearest background pixel inside, - distance to
        the nearest mask pixel outside (exact within ``margin``; ``-max(margin, box distance)`` beyond)."""
        if self.empty:
            return np.full(len(pu), -np.inf)
        pts = np.stack([pu, pv], axis=1).astype(np.float64)
        return self.signed_px(pts, self.mask[pv, pu].view(bool), self.box_distance(pts), margin)


def mask_edges(masks: np.ndarray | None) -> list[MaskEdges]:
    """One ``MaskEdges`` per mask of an (n, H, W) array (empty list for None)."""
    if masks is None:
        return []
    masks = np.asarray(masks)
    if masks.ndim != 3:
        raise D2SlamError(f"person masks must be an (n, H, W) array, got shape {masks.shape}")
    return [MaskEdges(masks[k]) for k in range(len(masks))]


class FrameMasks:
    """A frame's person masks seen from its keypoints, built once and shared by eq 1-2 and the OIM's zone (eq 9).

    ``edges`` (one ``MaskEdges`` per mask, with their cached trees), ``kp`` (``KeypointPixels``), and per mask k:
    ``inside[k]`` (N,) bool, the mask at each keypoint's pixel, and ``box[k]`` (N,) the distance of each keypoint's
    pixel to the mask's bounding box (None for an empty mask)."""

    def __init__(self, masks: np.ndarray | list[MaskEdges] | None, kps: np.ndarray,
                 shape: tuple[int, int] | None = None):
        self.edges = masks if isinstance(masks, list) else mask_edges(masks)
        if shape is None:
            shape = self.edges[0].shape if self.edges else (1, 1)
        self.kp = KeypointPixels(kps, shape)
        self.inside: list[np.ndarray | None] = []
        self.box: list[np.ndarray | None] = []
        for e in self.edges:  # loop over masks only
            if e.empty:
                self.inside.append(None)
                self.box.append(None)
            else:
                self.inside.append(e.flat.take(self.kp.flat).view(bool))
                self.box.append(e.box_distance(self.kp.pts))

    def signed(self, k: int, margin: float, rows: np.ndarray | None = None) -> np.ndarray:
        """eq 1 for mask k at all keypoints (or the index array ``rows``); NaN is not set here (see ``distances``)."""
        e = self.edges[k]
        if e.empty:
            return np.full(self.kp.pu.shape if rows is None else len(rows), -np.inf)
        if rows is None:
            return e.signed_px(self.kp.pts, self.inside[k], self.box[k], margin)
        return e.signed_px(self.kp.pts[rows], self.inside[k][rows], self.box[k][rows], margin)

    def distances(self, margin: float | np.ndarray = np.inf) -> np.ndarray:
        """eq 1: (N, n) signed distances, exact within ``margin`` (scalar or (n,)) of each mask; NaN rows for
        non-finite keypoints (see ``signed_distances``)."""
        n_kp = len(self.kp.pu)
        out = np.full((n_kp, len(self.edges)), -np.inf)
        if n_kp == 0 or not self.edges:
            return out
        margins = np.broadcast_to(np.asarray(margin, dtype=np.float64), (len(self.edges),))
        for k in range(len(self.edges)):  # loop over masks only
            out[:, k] = self.signed(k, float(margins[k]))
        if not self.kp.finite.all():
            out[~self.kp.finite] = np.nan
        return out


def signed_distances(masks: np.ndarray | list[MaskEdges] | None, kps: np.ndarray,
                     margin: float | np.ndarray = np.inf) -> np.ndarray:
    """eq 1: (N, n) signed distance (px) of each keypoint to the edge of each mask, + inside, - outside.

    ``masks`` (n, H, W) bool, None, or the ``mask_edges`` of a frame (reused across calls); ``kps`` (N, 2) pixel
    (u, v), rounded to the nearest pixel and clipped to the image; non-finite keypoints get NaN. ``margin`` (scalar
    or (n,)): outside points farther than this from mask n get ``-max(margin, distance to the bounding box)`` (see
    the module docstring). The loop is over masks, never over keypoints or pixels.
    """
    return FrameMasks(masks, kps).distances(margin)


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


def semantic_module(masks: np.ndarray | list[MaskEdges] | FrameMasks | None, kps: np.ndarray, b: np.ndarray,
                    margin: float | np.ndarray = np.inf, cfg: DynamicsConfig = _DEFAULT) -> SemanticResult:
    """eq 1-2 for all keypoints and masks. ``b`` (N,) is beta(z) of each keypoint (``depth.beta``). ``masks`` may be
    the frame's ``FrameMasks`` (built on the same ``kps``), whose edges, trees and pixel lookups are then reused.

    P_S is monotone in d for a given keypoint (same beta for every mask), so the largest P_S over the masks is the
    one of the largest signed distance ``d_max``; the uncertainty zone is taken on that same mask, i.e. it is exactly
    the set where the keypoint's P_S lies in (0.25, 0.75). Non-finite keypoints: P_S = 0, outside every area.
    """
    fm = masks if isinstance(masks, FrameMasks) else FrameMasks(masks, kps)
    d = fm.distances(margin)
    b = np.asarray(b, dtype=np.float64).reshape(-1)
    n = d.shape[0]
    if d.shape[1] == 0:
        d_max = np.full(n, -np.inf)
    else:
        d_max = d.max(axis=1)  # NaN only on the rows of non-finite keypoints (whole rows)
        if not fm.kp.finite.all():
            d_max[~fm.kp.finite] = -np.inf
    p_s = semantic_probability(d_max, b)
    inside = d_max > 0
    with np.errstate(invalid="ignore"):
        uncertain = np.abs(d_max) < uncertainty_width(b, cfg)
    return SemanticResult(d=d, d_max=d_max, p_s=p_s, inside=inside, uncertain=uncertain,
                          in_area=inside | uncertain)
