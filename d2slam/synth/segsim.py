"""Simulated instance segmenter: ground-truth person masks -> the masks a real network would give.

The paper's premise is that mask reliability depends on depth, so the errors here do:

* boundary error ``e = r(z) * sqrt(w h)`` pixels, where ``w h`` is the person's bounding box (apparent size) and
  ``r(z)`` grows linearly with normalised depth from ``seg_rel_err_near`` to ``seg_rel_err_far``: the contour is
  smoothed (Gaussian, sigma ~ e, so thin limbs and corners are lost or bloated), thresholded at a random level
  (a global dilation or erosion), and displaced by a smooth random field of amplitude ~ e;
* missed people: per frame with probability ``seg_flicker`` (temporal flicker), more when far
  (``seg_far_miss`` ramping in beyond ``seg_far_start``), when cut by the image border with little of the body
  visible (``seg_cut_miss``), always below ``seg_min_area`` pixels;
* the output labels person instances 1..n by decreasing area; objects (even moved ones) are never labelled.
"""

from __future__ import annotations

import cv2
import numpy as np

from d2slam.synth.config import SynthConfig


def simulate_segmenter(ids: np.ndarray, depth: np.ndarray, person_ids: list[int], K: np.ndarray,
                       rng: np.random.Generator, cfg: SynthConfig | None = None,
                       return_info: bool = False):
    """``ids``: (H, W) uint8 object ids (mask_gt); ``depth``: clean depth (m). Returns the (H, W) uint8 label image
    (and, with ``return_info``, one dict per person: id, area, depth, rel_err, error_px, missed, reason)."""
    sc = (cfg or SynthConfig()).segsim
    H, W = ids.shape
    counts = np.bincount(ids.ravel(), minlength=256)
    present = [pid for pid in person_ids if counts[pid] > 0]
    # draw every random number in a fixed order (one block per listed person) so that the stream does not
    # depend on which people happen to be visible
    draws = {pid: (rng.random(), rng.normal(0.0, 0.1), int(rng.integers(0, 2 ** 31))) for pid in person_ids}
    results, info = [], []
    for pid in present:
        m = (ids == pid).astype(np.uint8)
        area = int(np.count_nonzero(m))
        box = cv2.boundingRect(m)
        z = float(np.median(depth[m != 0]))
        s = float(np.clip((z - sc.seg_z_near) / (sc.seg_z_far - sc.seg_z_near), 0.0, 1.0))
        rel = sc.seg_rel_err_near + (sc.seg_rel_err_far - sc.seg_rel_err_near) * s
        err = rel * float(np.sqrt(box[2] * box[3]))
        u_miss, bias, sub_seed = draws[pid]
        reason = _missed(area, z, box, (H, W), K, u_miss, sc)
        info.append({"id": pid, "area": area, "depth": z, "rel_err": rel, "error_px": err, "missed": reason is not None,
                     "reason": reason})
        if reason is not None:
            continue
        out = _segmented(m, box, err, bias, np.random.default_rng(sub_seed))
        if out.any():
            results.append((z, int(out.sum()), out))
    labels = np.zeros((H, W), np.uint8)
    # instance number by decreasing area; where masks overlap the nearer person wins
    order = sorted(range(len(results)), key=lambda i: -results[i][1])
    number = {i: n + 1 for n, i in enumerate(order)}
    for i in sorted(range(len(results)), key=lambda i: -results[i][0]):  # far first, near painted last
        labels[results[i][2]] = number[i]
    if return_info:
        return labels, info
    return labels


def _missed(area: int, z: float, box, shape, K: np.ndarray, u_miss: float, sc) -> str | None:
    """Why the segmenter misses a person of ``area`` pixels at depth ``z`` with bounding ``box`` (x, y, w, h) in this
    frame (``u_miss``: its uniform draw): "small", "far", "cut", "flicker", or None when it is found. The miss
    probability: flicker everywhere, plus far people, plus people cut by the image border whose visible fraction of
    an expected full body is small."""
    x, y, w, h = box
    H, W = shape
    p_miss = sc.seg_flicker
    p_miss += sc.seg_far_miss * float(np.clip((z - sc.seg_far_start) / max(sc.seg_z_far - sc.seg_far_start, 1e-6),
                                              0.0, 1.0))
    cut = x == 0 or y == 0 or x + w >= W or y + h >= H
    if cut:
        fy, fx = K[1, 1], K[0, 0]
        full = (1.75 * fy / z) * (0.5 * fx / z)  # expected pixels of a whole standing body at this depth
        visible = area / max(full, 1.0)
        p_miss += sc.seg_cut_miss * float(np.clip(1.0 - visible / sc.seg_cut_visible, 0.0, 1.0))
    if area < sc.seg_min_area:
        return "small"
    if u_miss < p_miss:
        return "far" if z > sc.seg_far_start else ("cut" if cut else "flicker")
    return None


def _segmented(m: np.ndarray, box, err: float, bias: float, sub: np.random.Generator) -> np.ndarray:
    """(H, W) bool: the person's mask ``m`` as the segmenter outlines it: blurred, its contour displaced smoothly by
    about ``err`` px (random field of ``sub``) and cut at 0.5 + ``bias``."""
    H, W = m.shape
    x, y, w, h = box
    pad = int(np.ceil(3 * err)) + 4
    x0, y0, x1, y1 = max(x - pad, 0), max(y - pad, 0), min(x + w + pad, W), min(y + h + pad, H)
    crop = m[y0:y1, x0:x1].astype(np.float32)
    sig = max(0.6 * err, 0.3)
    soft = cv2.GaussianBlur(crop, (0, 0), sig)
    # smooth random displacement of the contour, amplitude ~ err
    ch, cw = y1 - y0, x1 - x0
    cell = max(4.0 * err, 8.0)
    gh, gw = int(np.ceil(ch / cell)) + 2, int(np.ceil(cw / cell)) + 2
    dx = cv2.resize(sub.normal(0.0, err, (gh, gw)).astype(np.float32), (cw, ch), interpolation=cv2.INTER_CUBIC)
    dy = cv2.resize(sub.normal(0.0, err, (gh, gw)).astype(np.float32), (cw, ch), interpolation=cv2.INTER_CUBIC)
    gx, gy = np.meshgrid(np.arange(cw, dtype=np.float32), np.arange(ch, dtype=np.float32))
    warped = cv2.remap(soft, gx + dx, gy + dy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    thr = float(np.clip(0.5 + bias, 0.3, 0.7))
    out = np.zeros((H, W), bool)
    out[y0:y1, x0:x1] = warped > thr
    return out
