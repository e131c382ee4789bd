"""Instance masks of a segmenter against the synthetic truth: per person and frame, the best IoU of any predicted
mask with the person's visible mask (``mask_gt``), whether the person counts as detected (IoU at least a threshold),
the boundary error of that best mask (pixels), and the person's median depth, for detection rates, IoU and boundary
error by depth bin.

Boundary error: the boundary of a mask is its pixels 4-adjacent to the background (the image border is not an edge,
as for eq 1 in ``d2slam.dynamics.semantic``: a person cut by the border continues out of view). The distance from
each boundary pixel of one mask to the nearest boundary pixel of the other, both ways, pooled (symmetric), gives the
mean and a high percentile (``SynthEvalConfig.seg_eval_boundary_percentile``). This is the quantity eq 2's uncertainty
band is meant to absorb: a true edge within ``ln 3 / beta(z)`` px of the predicted edge lies inside the band."""

from __future__ import annotations

import cv2
import numpy as np
from tqdm import tqdm

from d2slam.dynamics.config import DynamicsConfig
from d2slam.dynamics.depth import beta, uncertainty_width
from d2slam.ranges import AnyConfig, part_of
from d2slam.synth.config import SynthConfig, SynthEvalConfig
from d2slam.synth.generate import render_frame
from d2slam.synth.realism import sample_indices
from d2slam.synth.scene import Scene
from d2slam.synth.world import WorldRenderer

_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
_PERCENTILE = SynthEvalConfig.seg_eval_boundary_percentile


def person_ious(ids: np.ndarray, person_ids, masks: list[np.ndarray]) -> np.ndarray:
    """(P, K) IoU of each listed person's visible mask (``ids == pid``) with each predicted bool mask (vectorised:
    one matrix product over the flattened images)."""
    P, K = len(person_ids), len(masks)
    if P == 0 or K == 0:
        return np.zeros((P, K))
    gt = (ids.ravel()[None, :] == np.asarray(person_ids, ids.dtype)[:, None]).astype(np.float32)
    pr = np.stack([m.ravel() for m in masks]).astype(np.float32)
    inter = gt @ pr.T
    union = gt.sum(1)[:, None] + pr.sum(1)[None, :] - inter
    return np.where(union > 0, inter / np.maximum(union, 1.0), 0.0)


def boundary_error(truth: np.ndarray, pred: np.ndarray | None,
                   percentile: float = _PERCENTILE) -> tuple[float, float]:
    """(mean, ``percentile``-th percentile) of the symmetric boundary distances (px) between two (H, W) masks:
    from each boundary pixel of ``truth`` to the nearest boundary pixel of ``pred`` and vice versa, pooled. A mask
    shifted by k px against itself gives a percentile of k. (NaN, NaN) when ``pred`` is None or either mask has no
    boundary (empty, or covering the whole image).

    Exact Euclidean distances between pixel centres (``cv2.distanceTransform``, ``DIST_MASK_PRECISE``), computed on
    the bounding box of both masks plus 1 px only: every boundary pixel, hence every nearest one, lies in it."""
    nan = (float("nan"), float("nan"))
    if pred is None:
        return nan
    t = np.ascontiguousarray(truth != 0).view(np.uint8)
    p = np.ascontiguousarray(pred != 0).view(np.uint8)
    x, y, w, h = cv2.boundingRect(t | p)
    if w == 0 or h == 0:
        return nan
    H, W = t.shape
    box = np.s_[max(y - 1, 0):min(y + h + 1, H), max(x - 1, 0):min(x + w + 1, W)]
    t, p = t[box], p[box]
    # boundary = mask minus its erosion; BORDER_REPLICATE: the image border is not an edge (the crop's own margin
    # rows and columns are background wherever the crop does not reach the image border)
    bt = (t - cv2.erode(t, _CROSS, borderType=cv2.BORDER_REPLICATE)).view(bool)
    bp = (p - cv2.erode(p, _CROSS, borderType=cv2.BORDER_REPLICATE)).view(bool)
    if not bt.any() or not bp.any():
        return nan
    to_p = cv2.distanceTransform((~bp).view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    to_t = cv2.distanceTransform((~bt).view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    d = np.concatenate([to_p[bt], to_t[bp]]).astype(np.float64)
    return float(d.mean()), float(np.percentile(d, percentile))


def frame_rows(ids: np.ndarray, depth: np.ndarray, person_ids, masks: list[np.ndarray],
               percentile: float = _PERCENTILE) -> list[dict]:
    """One row per listed person visible in the frame: ``id``, ``area`` (fraction of the image), ``depth`` (median
    metres over its visible pixels), ``iou`` (best predicted mask; 0 when none), ``boundary_mean`` and
    ``boundary_q`` (``boundary_error`` of the best mask: mean and ``percentile``-th percentile, px; NaN when no
    predicted mask overlaps the person)."""
    counts = np.bincount(ids.ravel(), minlength=256)
    present = [int(p) for p in person_ids if counts[p] > 0]
    iou = person_ious(ids, present, masks)
    rows = []
    for k, pid in enumerate(present):
        person = ids == pid
        z = depth[person & (depth > 0)]
        best = int(np.argmax(iou[k])) if iou.shape[1] else -1
        matched = best >= 0 and iou[k, best] > 0
        b_mean, b_q = boundary_error(person, masks[best] if matched else None, percentile)
        rows.append({"id": pid, "area": float(counts[pid]) / ids.size,
                     "depth": float(np.median(z)) if z.size else float("nan"),
                     "iou": float(iou[k, best]) if best >= 0 else 0.0,
                     "boundary_mean": b_mean, "boundary_q": b_q})
    return rows


def depth_bin_table(depth: np.ndarray, values: np.ndarray, edges) -> list[tuple[str, int, float, float]]:
    """(bin label, count, mean, median) of ``values`` (IoU, boundary error, ...) per depth bin with the given inner
    edges (metres); NaN values are left out (and not counted)."""
    depth, values = np.asarray(depth, float), np.asarray(values, float)
    edges = [0.0, *edges, np.inf]
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        v = values[(depth >= a) & (depth < b) & np.isfinite(values)]
        label = f"{a:.1f}-{b:.1f} m" if np.isfinite(b) else f">= {a:.1f} m"
        out.append((label, int(v.size), float(v.mean()) if v.size else float("nan"),
                    float(np.median(v)) if v.size else float("nan")))
    return out


def synthetic_rows(runs, segmenter, config: AnyConfig | None = None) -> tuple[list[dict], list[dict]]:
    """A segmenter on synthetic people. For each run ``(scenario, seed, frames, stride)``, every ``stride``-th frame
    of the sequence is rendered in memory (the generator's own ``render_frame``: the RGB as written to ``rgb/``,
    sensor blur and noise included) and segmented (``segmenter(rgb)`` -> list of ``PersonInstance``).

    Returns ``(people, frames)``: one ``frame_rows`` row per visible person plus ``scenario``, ``seed``, ``frame``;
    one row per frame with ``scenario``, ``seed``, ``frame``, ``masks`` (predicted) and ``false_pos`` (predicted
    masks whose IoU with every person of the scene is below ``config.synth_eval.seg_eval_iou``)."""
    cfg, ev = part_of(config, "synth", SynthConfig), part_of(config, "synth_eval", SynthEvalConfig)
    runs = [(str(sc), int(seed), int(n), int(stride)) for sc, seed, n, stride in runs]
    todo = [sample_indices(n, stride) for _, _, n, stride in runs]
    people, frames = [], []
    with tqdm(total=sum(len(t) for t in todo), desc="segment", unit="frame", disable=None) as bar:
        for (scenario, seed, n, _), idx in zip(runs, todo):
            scene = Scene(scenario, seed, n, False, cfg)
            renderer = WorldRenderer(scene)
            try:
                for i in idx:
                    f = render_frame(scene, renderer, int(i))
                    masks = [p.mask for p in segmenter(f["rgb"])]
                    key = {"scenario": scenario, "seed": seed, "frame": int(i)}
                    people += [dict(r, **key) for r in frame_rows(f["mask_gt"], f["depth_clean"], scene.person_ids,
                                                                  masks, ev.seg_eval_boundary_percentile)]
                    iou = person_ious(f["mask_gt"], scene.person_ids, masks)
                    fp = int((iou.max(axis=0, initial=0.0) < ev.seg_eval_iou).sum()) if masks else 0
                    frames.append(dict(key, masks=len(masks), false_pos=fp))
                    bar.update()
            finally:
                renderer.close()
    return people, frames


def detected(people: list[dict], cfg: SynthEvalConfig | None = None) -> np.ndarray:
    """(N,) bool: the ``frame_rows`` rows of people covering at least ``seg_eval_min_area`` of the image whose best
    mask has IoU >= ``seg_eval_iou``."""
    cfg = cfg or SynthEvalConfig()
    area = np.array([r["area"] for r in people], float).reshape(-1)
    iou = np.array([r["iou"] for r in people], float).reshape(-1)
    return (area >= cfg.seg_eval_min_area) & (iou >= cfg.seg_eval_iou)


def boundary_table(people: list[dict],
                   config: AnyConfig | None = None) -> list[tuple[str, int, float, float, float, float]]:
    """Boundary error of detected people (``frame_rows`` rows with area >= ``seg_eval_min_area`` and IoU >=
    ``seg_eval_iou``) beside eq 2's uncertainty half-width ``w(z) = ln(p / (1 - p)) / beta(z)`` at each person's
    median depth, per depth bin (``seg_eval_depth_bins``) and over all (label "all"): (label, people, median of the
    mean error, median of the percentile error, median w, share of people whose percentile error is <= w)."""

    cfg, dyn = part_of(config, "synth_eval", SynthEvalConfig), part_of(config, "dynamics", DynamicsConfig)
    col = {k: np.array([r[k] for r in people], float).reshape(-1) for k in ("depth", "boundary_mean", "boundary_q")}
    det = detected(people, cfg) & np.isfinite(col["boundary_q"])  # NaN: a person covering the whole image
    z = col["depth"][det]
    width = uncertainty_width(beta(z, dyn), dyn)
    values = [col["boundary_mean"][det], col["boundary_q"][det], width, (col["boundary_q"][det] <= width) * 1.0]
    tables = [depth_bin_table(z, v, cfg.seg_eval_depth_bins) + [("all", *depth_bin_table(z, v, ())[0][1:])]
              for v in values]
    return [(t_mean[0], t_mean[1], t_mean[3], t_q[3], t_w[3], t_in[2]) for t_mean, t_q, t_w, t_in in zip(*tables)]
