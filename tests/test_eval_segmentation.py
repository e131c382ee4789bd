"""Segmenter against the synthetic truth: boundary error of a predicted mask, per-person rows, depth bins, and the
collection loop over rendered frames."""

import importlib

import numpy as np
import pytest
from scipy.spatial.distance import cdist

from d2slam.config import DEFAULT
from d2slam.errors import D2SlamError
from d2slam.eval.segmentation import boundary_error, boundary_table, depth_bin_table, frame_rows, synthetic_rows


def _square(shape=(60, 80), y=15, x=20, size=20, dy=0, dx=0):
    m = np.zeros(shape, bool)
    m[y + dy:y + dy + size, x + dx:x + dx + size] = True
    return m


def _brute(truth, pred, q):
    """Reference: boundary pixels by explicit 4-neighbour tests (image border replicated, so not an edge), all
    pairwise distances."""
    def edge(m):
        p = np.pad(m, 1, mode="edge")
        inner = p[:-2, 1:-1] & p[2:, 1:-1] & p[1:-1, :-2] & p[1:-1, 2:]
        return np.argwhere(m & ~inner).astype(float)

    et, ep = edge(truth), edge(pred)
    d = np.concatenate([cdist(et, ep).min(1), cdist(ep, et).min(1)])
    return d.mean(), np.percentile(d, q)


def test_identical_masks_have_no_boundary_error():
    m = _square()
    assert boundary_error(m, m.copy()) == (0.0, 0.0)


@pytest.mark.parametrize("k", [1, 2, 3, 5])
@pytest.mark.parametrize("axis", [0, 1])
def test_square_shifted_by_k_pixels(k, axis):
    truth = _square()
    pred = _square(dy=k) if axis == 0 else _square(dx=k)
    mean, q = boundary_error(truth, pred, 90.0)
    assert q == pytest.approx(k)
    assert boundary_error(truth, pred, 100.0)[1] == pytest.approx(k)  # no boundary pixel farther than the shift
    assert 0 < mean < k
    np.testing.assert_allclose((mean, q), _brute(truth, pred, 90.0), rtol=1e-6)
    np.testing.assert_allclose(boundary_error(pred, truth, 90.0), (mean, q), rtol=1e-12)  # symmetric


def test_boundary_error_matches_brute_force_on_random_blobs_and_border():
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[:48, :64]
    for _ in range(6):
        cy, cx, r = rng.uniform(0, 48), rng.uniform(0, 64), rng.uniform(6, 20)  # may reach the image border
        truth = (yy - cy) ** 2 + (xx - cx) ** 2 < r ** 2
        pred = (yy - cy - rng.normal(0, 2)) ** 2 / rng.uniform(0.7, 1.4) + (xx - cx - rng.normal(0, 2)) ** 2 < r ** 2
        pred ^= rng.random(pred.shape) < 0.02  # speckle: holes and islands
        if truth.all() or pred.all() or not truth.any() or not pred.any():
            continue
        np.testing.assert_allclose(boundary_error(truth, pred, 75.0), _brute(truth, pred, 75.0), rtol=1e-6)


def test_image_border_is_not_an_edge():
    truth = np.zeros((40, 40), bool)
    truth[:, :10] = True  # a band cut by the top, bottom and left borders: its only edge is column 9
    pred = np.zeros((40, 40), bool)
    pred[:, :13] = True
    assert boundary_error(truth, pred, 90.0) == (3.0, 3.0)


def test_no_mask_or_no_boundary_gives_nan():
    m = _square()
    assert np.isnan(boundary_error(m, None)).all()
    assert np.isnan(boundary_error(m, np.zeros_like(m))).all()
    assert np.isnan(boundary_error(np.ones_like(m), m)).all()  # the whole image: no edge


def test_frame_rows_boundary_of_the_best_mask():
    ids = np.zeros((60, 80), np.uint8)
    ids[_square(x=5)] = 1
    ids[_square(x=50, size=10)] = 2
    ids[_square(y=45, x=70, size=3)] = 3  # visible, no predicted mask overlaps it
    depth = np.where(ids > 0, 1.0 + ids, 0.0).astype(np.float32)
    good = _square(x=5, dx=2)
    poor = _square(x=5, size=12)  # inside person 1: lower IoU, larger boundary error
    rows = frame_rows(ids, depth, [1, 2, 3, 4], [poor, good, _square(x=50, size=10)], percentile=90.0)
    assert [r["id"] for r in rows] == [1, 2, 3]
    r1, r2, r3 = rows
    assert r1["iou"] == pytest.approx(360 / 440) and r1["boundary_q"] == pytest.approx(2.0)
    assert (r1["boundary_mean"], r1["boundary_q"]) == boundary_error(ids == 1, good, 90.0)
    assert r2["iou"] == 1.0 and r2["boundary_mean"] == 0.0 and r2["depth"] == 3.0
    assert r3["iou"] == 0.0 and np.isnan(r3["boundary_mean"]) and np.isnan(r3["boundary_q"])
    assert all(np.isnan(r["boundary_q"]) for r in frame_rows(ids, depth, [1, 2], []))


def test_depth_bin_table_leaves_out_nan():
    table = depth_bin_table(np.array([1.0, 1.2, 2.0, 4.0]), np.array([2.0, np.nan, 6.0, np.nan]), (1.5, 2.5))
    assert [t[0] for t in table] == ["0.0-1.5 m", "1.5-2.5 m", ">= 2.5 m"]
    assert [t[1] for t in table] == [1, 1, 0]
    assert table[0][2] == 2.0 and table[1][3] == 6.0 and np.isnan(table[2][2])


def test_synthetic_rows_with_the_truth_as_segmenter():
    """The loop over rendered frames: a segmenter that returns each visible person's true mask (plus one spurious
    mask) gives IoU 1, boundary error 0 and one false positive per frame."""
    from d2slam.segmentation.base import PersonInstance

    ids_seen = []

    class Truth:
        def __call__(self, rgb):
            ids = self.frame["mask_gt"]
            out = [PersonInstance(ids == p, 1.0, (0, 0, 1, 1)) for p in np.unique(ids) if 1 <= p <= 3]
            spurious = np.zeros(ids.shape, bool)
            spurious[:4, :4] = True
            return out + [PersonInstance(spurious, 0.5, (0, 0, 4, 4))]

    rows = importlib.import_module("d2slam.eval.segmentation")  # renders with the generator's render_frame
    truth = Truth()
    real = rows.render_frame

    def render(scene, renderer, i):
        truth.frame = real(scene, renderer, i)
        ids_seen.append(i)
        return truth.frame

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(rows, "render_frame", render)
        people, frames = synthetic_rows([("walking_xyz", 0, 40, 20)], truth, DEFAULT)
    assert ids_seen == [0, 20] and [f["frame"] for f in frames] == [0, 20]
    assert all(f["false_pos"] == 1 and f["scenario"] == "walking_xyz" and f["seed"] == 0 for f in frames)
    assert people and all(r["iou"] == 1.0 and r["boundary_q"] == 0.0 for r in people)
    with pytest.raises(D2SlamError, match="stride"):
        synthetic_rows([("walking_xyz", 0, 40, 0)], truth)


def test_boundary_table_against_the_band():
    """Detected people only (area and IoU thresholds); the share within the band compares each person's percentile
    error with ln 3 / beta(z) at its own depth (22.0 px at 0.5 m, 4.4 px at 4.5 m)."""
    from d2slam.config import DEFAULT

    def row(z, q, iou=0.9, area=0.1):
        return {"area": area, "iou": iou, "depth": z, "boundary_mean": q / 2, "boundary_q": q}

    people = [row(0.5, 20.0), row(1.0, 30.0), row(4.5, 4.0), row(4.5, 5.0),
              row(1.0, 1.0, iou=0.3), row(1.0, 1.0, area=0.01), row(1.0, np.nan)]  # last three: not counted
    table = boundary_table(people, DEFAULT)
    assert [t[0] for t in table] == ["0.0-1.5 m", "1.5-2.5 m", "2.5-3.5 m", ">= 3.5 m", "all"]
    near, _, _, far, total = table
    assert near[1] == 2 and near[3] == 25.0 and near[2] == 12.5 and near[5] == 0.5
    assert near[4] == pytest.approx(np.median([np.log(3) / 0.05, np.log(3) / 0.075]))
    assert far[1] == 2 and far[4] == pytest.approx(np.log(3) / 0.25) and far[5] == 0.5
    assert total[1] == 4 and total[5] == 0.5
