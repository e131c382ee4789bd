"""The realism check of composited people (``d2slam bench realism --composite``, ``d2slam.eval.people_realism``):
the camera's roll, the frames turned upright and back, the comparison at matched depth and coverage. Pure
functions on hand-made data: fast."""

from __future__ import annotations

import numpy as np
import pytest

from d2slam.eval import people_realism as P


def _camera(roll_deg: float) -> np.ndarray:
    """T_world_camera of a camera looking along world +y (x right, y down = -Z), rolled about its optical axis."""
    r = np.radians(roll_deg)
    Rz = np.array([[np.cos(r), -np.sin(r), 0], [np.sin(r), np.cos(r), 0], [0, 0, 1.0]])
    T = np.eye(4)
    T[:3, :3] = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]]) @ Rz
    return T


@pytest.mark.parametrize("roll", [0.0, 20.0, -45.0])
def test_roll_of_a_rolled_camera(roll):
    """The angle between the image's up and the world's up, one sign for one direction of roll."""
    assert P.roll_deg(_camera(roll)) == pytest.approx(-roll, abs=1e-9)


def test_upright_masks_come_back_where_they_were():
    """A segmenter that finds an upright bar: on the frame turned upright, its mask turned back lies on the rolled
    bar of the original frame."""
    from types import SimpleNamespace

    H, W, roll = 120, 160, 30.0
    img = np.zeros((H, W, 3), np.uint8)
    import cv2

    bar = np.zeros((H, W), np.uint8)
    bar[20:100, 75:85] = 1  # an upright bar, then rolled by -roll about the centre
    A = cv2.getRotationMatrix2D((W / 2, H / 2), -roll, 1.0)
    rolled = cv2.warpAffine(bar, A, (W, H), flags=cv2.INTER_NEAREST) > 0
    img[rolled] = 255

    def segmenter(rgb):  # finds the brightest pixels, and reports whether they stand upright
        m = rgb[..., 0] > 128
        ys, xs = np.nonzero(m)
        upright = xs.std() < 0.5 * ys.std()
        return [SimpleNamespace(mask=m, upright=upright)]

    back = P.upright_masks(segmenter, img, roll)
    assert len(back) == 1
    inter = (back[0] & rolled).sum()
    assert inter / rolled.sum() > 0.8 and inter / back[0].sum() > 0.8


def test_matched_weights_the_office_to_the_composites_cells():
    comp = [{"area": 0.05, "depth": 2.0, "iou": 0.6}, {"area": 0.05, "depth": 2.0, "iou": 0.2},
            {"area": 0.2, "depth": 1.0, "iou": 0.9}, {"area": 0.05, "depth": 5.0, "iou": 0.9}]
    office = [{"area": 0.05, "depth": 2.1, "iou": 0.8}, {"area": 0.2, "depth": 1.1, "iou": 0.4},
              {"area": 0.2, "depth": 1.2, "iou": 0.6}, {"area": 0.5, "depth": 3.0, "iou": 1.0}]
    m = P.matched(comp, office, (1.5, 2.5, 3.5))
    assert m["people"] == 4 and m["unmatched"] == 1  # nobody of the office at 5 m
    assert m["composite_rate"] == pytest.approx(2 / 3) and m["composite_mean"] == pytest.approx((0.6 + 0.2 + 0.9) / 3)
    # the office: its 2 m person weighted 2, its two 1 m people 1/2 each
    assert m["office_mean"] == pytest.approx((2 * 0.8 + 0.5 * 0.4 + 0.5 * 0.6) / 3)
    assert m["office_rate"] == pytest.approx((2 * 1 + 0.5 * 0 + 0.5 * 1) / 3)


def test_coverage_counts_frames_shares_and_depths():
    ids = [np.zeros((10, 10), np.uint8) for _ in range(4)]
    ids[1][:5, :5] = 1  # 25 %
    ids[2][:1, :2] = 2  # 2 %
    z = [np.full((10, 10), 2.0) for _ in range(4)]
    c = P.coverage(ids, z, [1, 2])
    assert c["frames"] == 4 and c["in_view"] == pytest.approx(0.25)
    assert c["share"][1] == pytest.approx(0.135)
