"""Removing people from a frame (d2slam.baselines.masking): depth zeroed exactly on the dilated mask, RGB unchanged
off it, smooth fills without the strong edge (and the boundary keypoints) of a black fill, bad input."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from d2slam.baselines import masking as M
from d2slam.config import DEFAULT
from d2slam.data.base import Camera
from d2slam.errors import D2SlamError
from d2slam.slam.frame import OrbExtractor

H, W = 240, 320


def _scene(seed: int = 0):
    """A textured RGB image (random coloured blocks, blurred a little), a depth ramp and two person masks: a disc and
    a rectangle with a notch (outline corners)."""
    rng = np.random.default_rng(seed)
    blocks = rng.integers(0, 256, (H // 8, W // 8, 3), dtype=np.uint8)
    rgb = cv2.GaussianBlur(cv2.resize(blocks, (W, H), interpolation=cv2.INTER_NEAREST), (3, 3), 0)
    depth = np.tile(np.linspace(1.0, 3.0, W, dtype=np.float32), (H, 1))
    yy, xx = np.mgrid[:H, :W]
    disc = (yy - 120) ** 2 + (xx - 90) ** 2 < 50 ** 2
    rect = (yy > 40) & (yy < 200) & (xx > 190) & (xx < 280) & ~((yy > 100) & (yy < 140) & (xx > 250))
    return rgb, depth, np.stack([disc, rect])


def _cfg(**kw):
    return dataclasses.replace(DEFAULT.masking, **kw)


@pytest.mark.parametrize("fill", M.FILLS)
def test_depth_zero_exactly_on_the_dilated_mask_and_rgb_unchanged_off_it(fill):
    rgb, depth, masks = _scene()
    rgb0, depth0, masks0 = rgb.copy(), depth.copy(), masks.copy()
    out_rgb, out_depth, region = M.mask_frame(rgb, depth, masks, _cfg(fill=fill, dilate_px=3))
    union = masks.any(axis=0)
    # the region is the union grown by 3 px: every pixel within 3 px of a mask, none farther than 3.5 px
    dist = cv2.distanceTransform((~union).view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    assert region[dist <= 3.0].all() and not region[dist > 3.5].any() and region[union].all()
    assert (out_depth[region] == 0).all() and np.array_equal(out_depth[~region], depth[~region])
    assert np.array_equal(out_rgb[~region], rgb[~region])
    assert out_rgb.shape == rgb.shape and out_rgb.dtype == np.uint8 and out_depth.dtype == depth.dtype
    # inputs untouched
    assert np.array_equal(rgb, rgb0) and np.array_equal(depth, depth0) and np.array_equal(masks, masks0)
    if fill == "black":
        assert (out_rgb[region] == 0).all()
    elif fill == "mean":
        assert len(np.unique(out_rgb[region], axis=0)) == 1
        assert np.allclose(out_rgb[region][0], rgb[~region].mean(axis=0), atol=0.51)


def test_no_masks_changes_nothing():
    rgb, depth, masks = _scene()
    out_rgb, out_depth, region = M.mask_frame(rgb, depth, masks[:0], _cfg(fill="pushpull"))
    assert not region.any() and np.array_equal(out_rgb, rgb) and np.array_equal(out_depth, depth)
    # a single (H, W) mask is accepted as well, dilation 0 = the mask itself
    _, out_depth, region = M.mask_frame(rgb, depth, masks[0], _cfg(dilate_px=0))
    assert np.array_equal(region, masks[0]) and (out_depth[masks[0]] == 0).all()


def _edge_contrast(img: np.ndarray, region: np.ndarray) -> float:
    """Mean absolute difference between each region pixel on the edge and its outside 4-neighbours (grey levels)."""
    g = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY).astype(np.float32)
    diffs = []
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        a = region[1:-1, 1:-1]
        b = region[1 + dy:H - 1 + dy, 1 + dx:W - 1 + dx]
        edge = a & ~b
        diffs.append(np.abs(g[1:-1, 1:-1][edge] - g[1 + dy:H - 1 + dy, 1 + dx:W - 1 + dx][edge]))
    return float(np.concatenate(diffs).mean())


def _band_keypoints(img: np.ndarray, region: np.ndarray) -> int:
    cam = Camera(fx=300.0, fy=300.0, cx=W / 2, cy=H / 2, width=W, height=H)
    kps = OrbExtractor(DEFAULT.orb, DEFAULT.engine, cam)(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY),
                                                          np.ones((H, W), np.float32)).kps_raw
    return M.keypoints_in(M.boundary_band(region, DEFAULT.masking.boundary_band_px), kps)


@pytest.mark.parametrize("fill", ["blur", "pushpull", "telea", "ns"])
def test_smooth_fills_have_weak_edges_and_fewer_boundary_keypoints_than_black(fill):
    # a scene with few corners of its own: a smooth colour field (cubic upsampling of random colours)
    _, depth, masks = _scene()
    coarse = np.random.default_rng(1).integers(60, 200, (H // 40, W // 40, 3), dtype=np.uint8)
    rgb = cv2.resize(coarse, (W, H), interpolation=cv2.INTER_CUBIC)
    black, _, region = M.mask_frame(rgb, depth, masks, _cfg(fill="black"))
    smooth, _, region2 = M.mask_frame(rgb, depth, masks, _cfg(fill=fill))
    assert np.array_equal(region, region2)
    assert _edge_contrast(smooth, region) < 0.25 * _edge_contrast(black, region)
    assert _band_keypoints(smooth, region) < 0.5 * _band_keypoints(black, region)
    # and the fill itself is smooth: inside the region, no step near FAST's threshold (20 grey levels: Sobel 80)
    g = cv2.cvtColor(smooth, cv2.COLOR_RGB2GRAY).astype(np.float32)
    grad = np.hypot(cv2.Sobel(g, cv2.CV_32F, 1, 0), cv2.Sobel(g, cv2.CV_32F, 0, 1))
    inner = cv2.erode(region.view(np.uint8), np.ones((7, 7), np.uint8)).view(bool)
    assert np.percentile(grad[inner], 99) < 40


def test_pushpull_fills_a_huge_region_from_the_little_left():
    rgb, depth, _ = _scene()
    region = np.ones((H, W), bool)
    region[:4, :] = False  # only the top rows are left
    out, _, _ = M.mask_frame(rgb, depth, region, _cfg(fill="pushpull", dilate_px=0))
    top_mean = rgb[:4].reshape(-1, 3).mean(axis=0)
    assert np.abs(out[H // 2:].reshape(-1, 3).mean(axis=0) - top_mean).max() < 40


def test_boundary_band_and_keypoints_in():
    region = np.zeros((20, 20), bool)
    region[5:15, 5:15] = True
    band = M.boundary_band(region, 2)
    assert band[5, 10] and band[3, 10] and band[6, 10] and not band[10, 10] and not band[1, 10]
    assert not M.boundary_band(np.zeros((5, 5), bool), 2).any()
    pts = np.array([[10.0, 5.2], [10.0, 10.0], [0.0, 0.0], [19.6, 19.6]])
    assert M.keypoints_in(band, pts) == 1 and M.keypoints_in(region, pts) == 2
    assert M.keypoints_in(region, np.zeros((0, 2))) == 0


def test_bad_input_is_a_one_line_error():
    rgb, depth, masks = _scene()
    with pytest.raises(D2SlamError, match="masking.fill = 'magic' is out of range: one of 'black'"):
        M.mask_frame(rgb, depth, masks, _cfg(fill="magic"))
    with pytest.raises(D2SlamError, match="do not match"):
        M.mask_frame(rgb, depth, masks[:, :100], _cfg())
    with pytest.raises(D2SlamError, match=r"masking.dilate_px = -1 is out of range: an integer in \[0, 1000\]"):
        M.mask_frame(rgb, depth, masks, _cfg(dilate_px=-1))
    with pytest.raises(D2SlamError, match="dilation"):
        M.dilate(masks[0], -1)
    with pytest.raises(D2SlamError, match="uint8"):
        M.mask_frame(rgb.astype(np.float32), depth, masks, _cfg())
    with pytest.raises(D2SlamError, match="uint8"):
        M.mask_frame(rgb, depth[:10], masks, _cfg())
