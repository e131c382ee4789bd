"""Instance masks of a segmenter against the synthetic truth: per person and frame, the best IoU of any predicted
mask with the person's visible mask (``mask_gt``), whether the person counts as detected (IoU at least a threshold),
and the person's median depth, for detection rates and IoU by depth bin."""

from __future__ import annotations

import numpy as np


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


def frame_rows(ids: np.ndarray, depth: np.ndarray, person_ids, masks: list[np.ndarray]) -> list[dict]:
    """One row per listed person visible in the frame: ``id``, ``area`` (fraction of the image), ``depth`` (median
    metres over its visible pixels), ``iou`` (best predicted mask; 0 when none)."""
    counts = np.bincount(ids.ravel(), minlength=256)
    present = [int(p) for p in person_ids if counts[p] > 0]
    iou = person_ious(ids, present, masks)
    rows = []
    for k, pid in enumerate(present):
        z = depth[(ids == pid) & (depth > 0)]
        rows.append({"id": pid, "area": float(counts[pid]) / ids.size,
                     "depth": float(np.median(z)) if z.size else float("nan"),
                     "iou": float(iou[k].max()) if iou.shape[1] else 0.0})
    return rows


def depth_bin_table(depth: np.ndarray, iou: np.ndarray, edges) -> list[tuple[str, int, float, float]]:
    """(bin label, count, mean IoU, median IoU) per depth bin with the given inner edges (metres)."""
    edges = [0.0, *edges, np.inf]
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        sel = (depth >= a) & (depth < b)
        label = f"{a:.1f}-{b:.1f} m" if np.isfinite(b) else f">= {a:.1f} m"
        v = iou[sel]
        out.append((label, int(sel.sum()), float(v.mean()) if v.size else float("nan"),
                    float(np.median(v)) if v.size else float("nan")))
    return out
