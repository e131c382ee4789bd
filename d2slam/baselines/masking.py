"""People cut out of an RGB-D frame before an unmodified SLAM system sees it (the ``orbslam3-masked`` baseline).

``mask_frame(rgb, depth, masks, cfg) -> (rgb, depth, region)``: the union of the frame's person masks, grown by
``cfg.dilate_px`` pixels, is the *region*; its depth becomes 0 (invalid: no 3-D point is made there) and its RGB is
replaced by a fill (``cfg.fill``) meant to give the ORB extractor nothing to detect, at the region's edge least of
all. The fills, all pure array functions of the image and the region:

* ``black``: 0, the naive fill (a strong edge all around the region, and corners wherever the outline bends);
* ``mean``: the frame's mean colour outside the region (a flat fill, a weaker edge);
* ``blur``: a normalised convolution of the pixels outside the region (a Gaussian of sigma ``cfg.blur_px`` / 3, at
  1/4 of the resolution), the mean colour where no outside pixel is within reach: the fill continues the colours of
  its surroundings;
* ``pushpull``: the same idea at every scale: a Gaussian pyramid of the outside pixels weighted by their coverage
  (push), then each level composited over the upsampled coarser one (pull), so every region pixel gets a smooth
  average of the nearest outside colours, however large the region;
* ``telea`` / ``ns``: OpenCV inpainting (``cv2.INPAINT_TELEA`` / ``cv2.INPAINT_NS``) at 1/``cfg.inpaint_scale`` of
  the resolution (at full resolution it costs hundreds of milliseconds on a person-sized region), upsampled into the
  region.

The smooth fills (``blur``, ``pushpull``, ``telea``, ``ns``) are computed on the region's bounding box grown by
``cfg.crop_margin_px`` only; OpenCV does the per-pixel work. Pixels outside the region are never changed. Which fill
and dilation ``orbslam3-masked`` uses, and why, is in ``docs/masking.md``; the cost per frame is printed by
``d2slam bench masking``.
"""

from __future__ import annotations

import cv2
import numpy as np

from d2slam.baselines.config import MASK_FILLS, MaskingConfig
from d2slam.errors import D2SlamError

FILLS = MASK_FILLS  # MaskingConfig.fill


def union_mask(masks: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool union of (n, H, W) instance masks (or one (H, W) mask); all False for n = 0."""
    masks = np.asarray(masks, dtype=bool)
    if masks.ndim == 2:
        masks = masks[None]
    if masks.ndim != 3 or masks.shape[1:] != tuple(shape):
        raise D2SlamError(f"person masks of shape {masks.shape} do not match the frame's {tuple(shape)}")
    return masks.any(axis=0) if len(masks) else np.zeros(shape, dtype=bool)


def dilate(mask: np.ndarray, px: int) -> np.ndarray:
    """``mask`` grown by ``px`` pixels (elliptic kernel of diameter 2 px + 1); ``px`` = 0 returns it as is."""
    if px < 0:
        raise D2SlamError(f"mask dilation must be >= 0 pixels, got {px}")
    if px == 0 or not mask.any():
        return mask
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * px + 1, 2 * px + 1))
    return cv2.dilate(mask.view(np.uint8), kernel).view(bool)


def _mean_colour(rgb: np.ndarray, keep8: np.ndarray) -> np.ndarray:
    """Mean colour (3,) float of the pixels where ``keep8`` (uint8) is non-zero; mid grey when there are none."""
    if not cv2.countNonZero(keep8):
        return np.full(3, 128.0)
    return np.asarray(cv2.mean(rgb, mask=keep8)[:3])


def _premultiplied(rgb: np.ndarray, keep8: np.ndarray) -> np.ndarray:
    """(H, W, 4) uint8 ``(r w, g w, b w, 255 w)`` with the coverage w = 1 outside the region, 0 in it."""
    rgba = cv2.cvtColor(rgb, cv2.COLOR_RGB2RGBA)
    return cv2.bitwise_and(rgba, rgba, mask=keep8)


def _over(rgba: np.ndarray, under: np.ndarray) -> np.ndarray:
    """Premultiplied ``rgba`` composited over the opaque ``under`` (H, W, 4): ``rgba + (1 - w) under``."""
    alpha4 = np.empty_like(rgba)
    cv2.mixChannels([rgba], [alpha4], [3, 0, 3, 1, 3, 2, 3, 3])
    return cv2.add(rgba, cv2.subtract(under, cv2.multiply(under, alpha4, scale=1.0 / 255.0)))


def _unpremultiply(rgba: np.ndarray) -> np.ndarray:
    """(H, W, 4) float32 colour of a small premultiplied image, colour / w (its fourth channel is unused); where
    w < 1/1000, the coverage-weighted mean colour of the whole image (mid grey if it has no coverage at all)."""
    alpha = cv2.split(rgba)[3]
    low = cv2.compare(alpha, 0.255, cv2.CMP_LT)
    inv = np.float32(255.0) / np.maximum(alpha, np.float32(0.255))
    out = cv2.multiply(rgba, cv2.merge([inv, inv, inv, inv]))
    if cv2.countNonZero(low):
        total = rgba.reshape(-1, 4).sum(axis=0, dtype=np.float64)
        mean = total[:3] * 255.0 / total[3] if total[3] > 0 else np.full(3, 128.0)
        h, w = alpha.shape
        cv2.copyTo(cv2.merge([np.full((h, w), c, np.float32) for c in (*mean, 255.0)]), low, out)
    return out


def _blur_fill(rgb: np.ndarray, keep8: np.ndarray, px: int) -> np.ndarray:
    """Normalised convolution: the Gaussian-weighted mean (sigma ``px`` / 3) of the outside pixels (their mean
    colour where none is within reach), computed at 1/4 of the resolution (two ``cv2.pyrDown`` of the
    premultiplied image) and upsampled: (H, W, 3) uint8."""
    small = cv2.pyrDown(cv2.pyrDown(_premultiplied(rgb, keep8)).astype(np.float32))
    small = cv2.GaussianBlur(small, (0, 0), px / 12.0, borderType=cv2.BORDER_REFLECT)
    est = cv2.cvtColor(cv2.convertScaleAbs(_unpremultiply(small)), cv2.COLOR_RGBA2RGB)
    h, w = keep8.shape
    return cv2.pyrUp(cv2.pyrUp(est, dstsize=((w + 1) // 2, (h + 1) // 2)), dstsize=(w, h))


def _pushpull_fill(rgb: np.ndarray, keep8: np.ndarray, levels: int) -> np.ndarray:
    """Push-pull: a pyramid of the premultiplied colours and coverage (``cv2.pyrDown``; from the uint8 image, whose
    premultiplied values are exact, down to 1/4 of the resolution, then in float32 down to 1/2^levels), its coarsest
    level normalised (the mean outside colour where it holds no outside pixel), then each level composited over the
    upsampled coarser one (``c_l = num_l + (1 - w_l) up(c_l+1)``) up to 1/4, upsampled twice: (H, W, 3) uint8, what
    every region pixel (w_0 = 0) gets, a smooth average of the nearest outside colours however large the region.
    Starting the pull at 1/4 rather than 1/2 of the resolution costs 2.5x less for as many keypoints at the region's
    edge (docs/masking.md)."""
    pyr = [cv2.pyrDown(cv2.pyrDown(_premultiplied(rgb, keep8))).astype(np.float32)]
    while len(pyr) < levels - 1 and min(pyr[-1].shape[:2]) >= 8:
        pyr.append(cv2.pyrDown(pyr[-1]))
    est = _unpremultiply(pyr[-1])
    for lvl in reversed(pyr[:-1]):
        est = _over(lvl, cv2.pyrUp(est, dstsize=(lvl.shape[1], lvl.shape[0])))
    est = cv2.cvtColor(cv2.convertScaleAbs(est), cv2.COLOR_RGBA2RGB)
    h, w = keep8.shape
    return cv2.pyrUp(cv2.pyrUp(est, dstsize=((w + 1) // 2, (h + 1) // 2)), dstsize=(w, h))


def _inpaint_fill(rgb: np.ndarray, region8: np.ndarray, flag: int, radius: float, scale: int) -> np.ndarray:
    """``cv2.inpaint`` at 1/``scale`` resolution; a low-resolution pixel is inpainted when any of its pixels is in the
    region, so no region colour leaks into the fill; the result is upsampled bilinearly."""
    h, w = region8.shape
    if scale <= 1:
        return cv2.inpaint(rgb, region8, radius, flag)
    sw, sh = -(-w // scale), -(-h // scale)
    small = cv2.resize(rgb, (sw, sh), interpolation=cv2.INTER_AREA)
    hole = cv2.resize(region8 * np.uint8(255), (sw, sh), interpolation=cv2.INTER_AREA)
    small = cv2.inpaint(small, (hole > 0).view(np.uint8), radius, flag)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)


def fill_rgb(rgb: np.ndarray, region: np.ndarray, cfg: MaskingConfig = MaskingConfig()) -> np.ndarray:
    """``rgb`` (H, W, 3) uint8 with the pixels of ``region`` (H, W) bool replaced by ``cfg.fill`` (module docstring);
    a new array, the other pixels unchanged."""
    region8 = np.ascontiguousarray(region).view(np.uint8)
    if not cv2.countNonZero(region8):
        return rgb.copy()
    keep8 = cv2.compare(region8, 0, cv2.CMP_EQ)
    if cfg.fill == "black":
        return cv2.bitwise_and(rgb, rgb, mask=keep8)
    out = rgb.copy()
    if cfg.fill == "mean":
        h, w = region8.shape
        fill = cv2.merge([np.full((h, w), c, np.uint8) for c in np.rint(_mean_colour(rgb, keep8)).astype(np.uint8)])
        cv2.copyTo(fill, region8, out)
        return out
    # the smooth fills look only at the region's bounding box grown by crop_margin_px
    x, y, w, h = cv2.boundingRect(region8)
    m = cfg.crop_margin_px
    box = (slice(max(y - m, 0), y + h + m), slice(max(x - m, 0), x + w + m))
    rgb_c, region_c, keep_c = rgb[box], region8[box], keep8[box]
    if cfg.fill == "blur":
        fill = _blur_fill(rgb_c, keep_c, cfg.blur_px)
    elif cfg.fill == "pushpull":
        fill = _pushpull_fill(rgb_c, keep_c, cfg.pushpull_levels)
    else:
        flag = cv2.INPAINT_TELEA if cfg.fill == "telea" else cv2.INPAINT_NS
        fill = _inpaint_fill(np.ascontiguousarray(rgb_c), region_c, flag, cfg.inpaint_radius, cfg.inpaint_scale)
    out_c = out[box]
    cv2.copyTo(fill, np.ascontiguousarray(region_c), out_c)
    out[box] = out_c
    return out


def mask_frame(rgb: np.ndarray, depth: np.ndarray, masks: np.ndarray, cfg: MaskingConfig = MaskingConfig()
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(rgb, depth, region)``: the frame with its people removed (module docstring). ``masks``: (n, H, W) bool
    instance masks (``d2slam.segmentation.stack_masks``) or one (H, W) mask; ``depth`` any dtype (0 = invalid).
    The inputs are not modified."""
    if rgb.ndim != 3 or rgb.dtype != np.uint8 or depth.shape != rgb.shape[:2]:
        raise D2SlamError(f"mask_frame needs (H, W, 3) uint8 RGB and a depth of the same size, got {rgb.shape} "
                          f"{rgb.dtype} and {depth.shape}")
    region = dilate(union_mask(masks, rgb.shape[:2]), cfg.dilate_px)
    depth = np.where(region, depth.dtype.type(0), depth)
    return fill_rgb(np.ascontiguousarray(rgb), region, cfg), depth, region


def boundary_band(region: np.ndarray, px: int) -> np.ndarray:
    """(H, W) bool: pixels within ``px`` pixels of the edge of ``region``, on either side (empty without a region)."""
    if not region.any() or px <= 0:
        return np.zeros_like(region)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * px + 1, 2 * px + 1))
    u8 = region.view(np.uint8)
    return (cv2.dilate(u8, kernel) != cv2.erode(u8, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=1))


def keypoints_in(mask: np.ndarray, pts: np.ndarray) -> int:
    """How many of the (N, 2) pixel positions ``pts`` fall on ``mask``."""
    if len(pts) == 0:
        return 0
    h, w = mask.shape
    x = np.clip(np.rint(pts[:, 0]).astype(np.int64), 0, w - 1)
    y = np.clip(np.rint(pts[:, 1]).astype(np.int64), 0, h - 1)
    return int(mask[y, x].sum())
