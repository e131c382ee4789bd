"""The free space of a real recording's room, from its own depth along its ground truth: where a person can stand.

``d2slam synth real_walking --on-trajectory TUM_DIR`` composites our people into a real recording
(``d2slam.synth.composite``); they must stand on its floor and keep out of its furniture. Everything here is measured
from the recording itself (``CompositeConfig``; the measurements: docs/real_people.md):

- **Fusion** (:func:`fuse_depth`): every ``fuse_stride``-th depth image, every ``fuse_step``-th pixel, back-projected
  through the camera's lens (the pixel's undistorted ray) and placed in the ground truth's world at the instant its
  row was taken (the twin's calibrated depth timing: ``TwinConfig.depth_time_shift``, ``depth_row_readout``).
- **Floor** (:func:`estimate_floor`): the lowest horizontal plane the depth holds: the lowest height (along the
  world's Z, which the motion capture's world keeps up) where at least ``floor_min_share`` of the points lie within
  ``floor_band_m``, refined by a least-squares plane through the points near it (its tilt must stay within
  ``floor_max_tilt_deg`` of the vertical).
- **Room frame** (:func:`room_frame`): a rigid motion of the recording's world that puts the floor at Z = 0, Z up,
  the mean camera centre above the origin and the cameras' mean horizontal viewing direction along +y: the frame in
  which the people are planned (``d2slam.synth.actors``: the camera's home at the origin, looking along +y).
- **Free space** (:class:`FreeSpace`): a grid of ``cell_m`` cells on the floor. A cell is *occupied* when the fused
  depth holds at least ``occupied_points`` points above it between ``body_low_m`` and ``body_high_m`` (furniture,
  walls); *seen free* when it is not occupied and either the floor was seen there (``floor_points`` fused points) or
  the frames' depth looked through the space above it: at least one of its points at ``probe_heights_m`` projects
  onto a depth at least ``see_through_m`` farther in at least ``seen_frames`` frames, and each of the others either
  does too or was never seen with a surface at it (within ``see_through_m``: never in view, or always hidden behind
  nearer surfaces or over holes). So the space behind a desk counts as free when the space above the desk is seen
  through: whatever stands hidden there is hidden in every frame, and so is whatever part of a person the z-test hides; *in view* by the share of frames whose image (grown by ``view_margin_px``) holds any of its points at
  ``view_heights_m``. A person may stand where
  no occupied cell lies within ``clearance_m`` and the cell is seen free, or never in view (``never_view_share``):
  where no frame shows the space, whatever stands there is never seen and nothing is known of it; where a frame
  could have seen it but the depth did not (behind the furniture), nobody stands. The camera's operator stands
  under the camera: the cells within ``operator_radius_m`` of its centres are occupied.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from d2slam.data.tum import interpolate_poses
from d2slam.errors import D2SlamError
from d2slam.synth.twin import distort_normalised, undistort_normalised


# --------------------------------------------------------------------------------------------------
# the recording's depth in its world
# --------------------------------------------------------------------------------------------------
def pixel_rays(camera, step: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rows, cols, rays): every ``step``-th pixel of the camera's image and its ray (N, 3) with z = 1, through the
    lens (the undistorted normalised coordinates of the pixel)."""
    K = camera.K
    vv, uu = np.mgrid[0:camera.height:step, 0:camera.width:step]
    xd = np.stack([(uu.ravel() - K[0, 2]) / K[0, 0], (vv.ravel() - K[1, 2]) / K[1, 1]], axis=1)
    x = undistort_normalised(xd, camera.dist) if camera.has_distortion else xd
    return vv.ravel(), uu.ravel(), np.concatenate([x, np.ones((len(x), 1))], axis=1)


def depth_row_poses(rec, depth_time: float, rows: np.ndarray, twin) -> np.ndarray:
    """(N, 4, 4) ``T_world_camera`` of the recording's world at the instants ``rows`` of the depth image stamped
    ``depth_time`` were taken (``TwinConfig.depth_time_shift`` before... after its stamp, each row
    ``depth_row_readout`` after the one above it, the middle row at the shifted stamp)."""
    t = depth_time + twin.depth_time_shift + (rows - (rec.camera.height - 1) / 2.0) * twin.depth_row_readout
    t = np.clip(t, rec.gt_times[0], rec.gt_times[-1])
    return interpolate_poses(rec.gt_times, rec.gt_poses, t, max_gap=None)


@dataclass(frozen=True)
class Fused:
    """The recording's depth in its world: ``points`` (N, 3), the frame each came from (``frame``, N), and per fused
    frame its index in the recording (``frames``), its depth image (``depths``, float32 m, 0 = hole) and the poses of
    its rows (``row_poses``, (F, H, 4, 4))."""

    points: np.ndarray
    frame: np.ndarray
    frames: np.ndarray
    depths: list
    row_poses: np.ndarray


def fuse_depth(rec, depth_of, cfg) -> Fused:
    """Every ``cfg.fuse_stride``-th depth image of the recording ``rec`` (``depth_of(i)``: frame i's depth, float32
    m) in its world (see the module docstring). ``cfg``: the ``SynthConfig``."""
    cc, tw = cfg.composite, cfg.twin
    H = rec.camera.height
    rows, cols, rays = pixel_rays(rec.camera, cc.fuse_step)
    frames = np.arange(0, len(rec), cc.fuse_stride)
    pts, which, depths, row_poses = [], [], [], []
    all_rows = np.arange(H)
    for k, i in enumerate(frames):
        z = np.asarray(depth_of(int(i)), np.float32)
        T = depth_row_poses(rec, float(rec.depth_times[i]), all_rows, tw)
        zz = z[rows, cols].astype(np.float64)
        ok = zz > 0
        X = rays[ok] * zz[ok, None]
        Tr = T[rows[ok]]
        pts.append(np.einsum("nij,nj->ni", Tr[:, :3, :3], X) + Tr[:, :3, 3])
        which.append(np.full(int(ok.sum()), k, np.int32))
        depths.append(z)
        row_poses.append(T)
    return Fused(np.concatenate(pts), np.concatenate(which), frames, depths, np.stack(row_poses))


# --------------------------------------------------------------------------------------------------
# the floor and the room frame
# --------------------------------------------------------------------------------------------------
def estimate_floor(points: np.ndarray, cfg) -> tuple[np.ndarray, float]:
    """(unit normal n, offset d) of the floor plane ``n . X = d`` (n pointing up) among ``points`` (N, 3) in a world
    whose Z is about up: the lowest height where at least ``floor_min_share`` of the points lie within
    ``floor_band_m`` (a horizontal surface seen in many frames; the desks above it hold more), then the least-squares
    plane through the points within ``floor_band_m`` of it, twice (the second time about the first plane). A
    D2SlamError when no such height exists or the plane tilts more than ``floor_max_tilt_deg``."""
    cc = cfg.composite
    P = np.asarray(points, np.float64)
    if len(P) < 3:
        raise D2SlamError("the recording's depth holds too few points to find its floor")
    z = P[:, 2]
    band = cc.floor_band_m
    edges = np.arange(np.percentile(z, 0.1) - band, np.percentile(z, 99.9) + band, band / 2.0)
    counts = np.histogram(z, edges)[0]
    window = np.convolve(counts, np.ones(4, int), mode="valid")  # points within a band of 2 bins either side
    dense = np.flatnonzero(window >= cc.floor_min_share * len(P))
    if not dense.size:
        raise D2SlamError(f"no floor in the recording's depth: no horizontal band of {100 * band:.0f} cm holds "
                          f"{100 * cc.floor_min_share:g} % of its points")
    k = dense[0] + int(np.argmax(window[dense[0]:dense[0] + 4]))  # the densest window where the lowest dense one is
    n, d = np.array([0.0, 0.0, 1.0]), 0.5 * (edges[k] + edges[k + 4])
    for _ in range(2):
        near = P[np.abs(P @ n - d) <= band]
        if len(near) < 3:
            break
        c = near.mean(axis=0)
        n = np.linalg.svd(near - c, full_matrices=False)[2][-1]
        n = n if n[2] > 0 else -n
        d = float(n @ c)
    tilt = float(np.degrees(np.arccos(np.clip(n[2], -1.0, 1.0))))
    if tilt > cc.floor_max_tilt_deg:
        raise D2SlamError(f"the recording's lowest plane tilts {tilt:.1f} deg from the world's vertical (at most "
                          f"{cc.floor_max_tilt_deg:g}): not a floor")
    return n, float(d)


def room_frame(normal: np.ndarray, offset: float, cam_poses: np.ndarray) -> np.ndarray:
    """The 4x4 rigid motion from the recording's world to the room frame (module docstring): the floor ``normal .
    X = offset`` to Z = 0 with ``normal`` to +Z (the least rotation), the cameras' mean centre above the origin,
    their mean horizontal viewing direction (the optical axes projected on the floor, summed) along +y."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    z = np.array([0.0, 0.0, 1.0])
    v, c = np.cross(n, z), float(n @ z)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    R1 = np.eye(3) + vx + vx @ vx / (1.0 + c)  # n -> z
    axes = np.einsum("ij,njk->nik", R1, cam_poses[:, :3, :3])[:, :, 2]
    h = axes[:, :2].sum(axis=0)
    if np.hypot(*h) < 1e-9:
        raise D2SlamError("the recording's cameras have no mean horizontal viewing direction")
    phi = np.pi / 2 - np.arctan2(h[1], h[0])  # rotate the mean heading to +y
    Rz = np.array([[np.cos(phi), -np.sin(phi), 0.0], [np.sin(phi), np.cos(phi), 0.0], [0.0, 0.0, 1.0]])
    R = Rz @ R1
    centre = R @ cam_poses[:, :3, 3].mean(axis=0)
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = [-centre[0], -centre[1], -offset]  # R @ X on the floor has height n . X = offset
    return M


# --------------------------------------------------------------------------------------------------
# free space
# --------------------------------------------------------------------------------------------------
class FreeSpace:
    """Where a person can stand in the room frame (module docstring): boolean grids over cells of ``cell_m``,
    index [ix, iy] of the cell whose lower corner is ``origin + (ix, iy) cell_m``: ``occupied``, ``known_free``
    (not occupied, and the floor seen or the space above seen through at every probe height), ``never_in_view``,
    ``standable`` (a person's root may stand there), ``passable`` (a walked route's rounded corners may cross it),
    ``view_share`` and ``out_of_view`` (never within the images grown by ``view_margin_px``). ``free(P)`` is the planner's test
    (``d2slam.synth.actors.FloorPlan``), ``path(a, b)`` a route."""

    def __init__(self, origin, cell: float, occupied, known_free, view_share, near_view_share, cfg):
        cc = cfg.composite
        self.origin, self.cell = np.asarray(origin, float), float(cell)
        self.occupied, self.known_free, self.view_share = occupied, known_free, view_share
        # out of view with a margin: where a person is surely unseen (where people leave the view to)
        self.out_of_view = near_view_share <= cc.never_view_share
        r = int(np.ceil(cc.clearance_m / self.cell))
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        near = cv2.dilate(occupied.astype(np.uint8), disc, borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0
        self.never_in_view = view_share <= cc.never_view_share
        self.standable = ~near & (known_free | self.never_in_view)
        # where a walked route's rounded corners may pass: within route_slack_m of standable cells, never occupied
        r = int(np.ceil(cc.route_slack_m / self.cell))
        slack = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        self.passable = (cv2.dilate(self.standable.astype(np.uint8), slack) > 0) & ~occupied

    @property
    def shape(self) -> tuple[int, int]:
        return self.standable.shape

    def area(self, cells: np.ndarray) -> float:
        """Square metres of the True cells of a grid."""
        return float(np.count_nonzero(cells)) * self.cell ** 2

    def cells(self, P) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ix, iy, inside) of points P (N, 2)."""
        ij = np.floor((np.atleast_2d(P)[:, :2] - self.origin) / self.cell).astype(np.int64)
        inside = (ij >= 0).all(axis=1) & (ij[:, 0] < self.shape[0]) & (ij[:, 1] < self.shape[1])
        ij = np.where(inside[:, None], ij, 0)
        return ij[:, 0], ij[:, 1], inside

    def centre(self, ix, iy) -> np.ndarray:
        return self.origin + (np.stack([np.asarray(ix), np.asarray(iy)], axis=-1) + 0.5) * self.cell

    def free(self, P) -> bool:
        ix, iy, inside = self.cells(P)
        return bool((inside & self.standable[ix, iy]).all())

    def passes(self, P) -> bool:
        """May a walked route go through the points P (N, 2)? (``passable``: its corners rounded off standable
        cells by at most ``route_slack_m``.)"""
        ix, iy, inside = self.cells(P)
        return bool((inside & self.passable[ix, iy]).all())

    def path(self, a, b) -> np.ndarray | None:
        """The shortest 8-connected chain of standable cells from the cell of ``a`` to the cell of ``b`` (A*), as
        floor points from ``a`` to ``b`` with the cells' centres between, thinned to the turns that keep every
        straight piece on standable cells; None when none exists."""
        a, b = np.asarray(a, float), np.asarray(b, float)
        (ia,), (ja,), (ok_a,) = self.cells(a[None])
        (ib,), (jb,), (ok_b,) = self.cells(b[None])
        if not (ok_a and ok_b and self.standable[ia, ja] and self.standable[ib, jb]):
            return None
        chain = astar(self.standable, (int(ia), int(ja)), (int(ib), int(jb)))
        if chain is None:
            return None
        inner = np.array(chain[1:-1], np.int64).reshape(-1, 2)
        return self.thin(np.concatenate([a[None], self.centre(inner[:, 0], inner[:, 1]), b[None]]))

    def thin(self, pts: np.ndarray) -> np.ndarray:
        """Greedy string pulling: from each kept point, the farthest later point reachable in a straight line over
        standable cells (sampled every half cell)."""
        out, k = [pts[0]], 0
        while k < len(pts) - 1:
            j = len(pts) - 1
            while j > k + 1 and not self.segment_free(pts[k], pts[j]):
                j -= 1
            out.append(pts[j])
            k = j
        return np.array(out)

    def segment_free(self, a, b) -> bool:
        n = max(int(np.ceil(np.linalg.norm(np.asarray(b) - a) / (0.5 * self.cell))), 1)
        return self.free(a + np.linspace(0.0, 1.0, n + 1)[:, None] * (np.asarray(b) - a))


def astar(grid: np.ndarray, start: tuple[int, int], goal: tuple[int, int]) -> list | None:
    """The shortest 8-connected path of True cells of ``grid`` from ``start`` to ``goal`` (A* with the octile
    distance, no corner cutting; ties broken by cell order, so the path is deterministic), or None."""
    if start == goal:
        return [start, goal]
    nx, ny = grid.shape
    steps = [(dx, dy, float(np.hypot(dx, dy))) for dx in (-1, 0, 1) for dy in (-1, 0, 1) if dx or dy]

    def h(c):
        dx, dy = abs(c[0] - goal[0]), abs(c[1] - goal[1])
        return max(dx, dy) + (np.sqrt(2.0) - 1.0) * min(dx, dy)

    best = {start: 0.0}
    came: dict = {}
    heap = [(h(start), 0.0, start)]
    while heap:
        _, g, c = heapq.heappop(heap)
        if c == goal:
            out = [c]
            while c in came:
                c = came[c]
                out.append(c)
            return out[::-1]
        if g > best.get(c, np.inf):
            continue
        for dx, dy, w in steps:
            q = (c[0] + dx, c[1] + dy)
            if not (0 <= q[0] < nx and 0 <= q[1] < ny) or not grid[q]:
                continue
            if dx and dy and not (grid[c[0] + dx, c[1]] and grid[c[0], c[1] + dy]):
                continue
            gq = g + w
            if gq < best.get(q, np.inf) - 1e-12:
                best[q] = gq
                came[q] = c
                heapq.heappush(heap, (gq + h(q), gq, q))
    return None


def free_space(fused: Fused, M: np.ndarray, camera, cfg) -> FreeSpace:
    """The :class:`FreeSpace` of the fused depth in the room frame ``M`` (module docstring)."""
    cc = cfg.composite
    P = fused.points @ M[:3, :3].T + M[:3, 3]
    h = P[:, 2]
    body = (h >= cc.body_low_m) & (h <= cc.body_high_m)
    lo = np.floor(P[body, :2].min(axis=0) / cc.cell_m) * cc.cell_m - cc.room_margin_m
    hi = np.ceil(P[body, :2].max(axis=0) / cc.cell_m) * cc.cell_m + cc.room_margin_m
    shape = tuple(int(v) for v in np.round((hi - lo) / cc.cell_m))

    def count(sel):
        ij = np.floor((P[sel, :2] - lo) / cc.cell_m).astype(np.int64)
        inside = (ij >= 0).all(axis=1) & (ij[:, 0] < shape[0]) & (ij[:, 1] < shape[1])
        out = np.zeros(shape, np.int64)
        np.add.at(out, (ij[inside, 0], ij[inside, 1]), 1)
        return out

    occupied = count(body) >= cc.occupied_points
    # the camera's operator stands under the camera: within operator_radius_m of its centres on the floor
    centres = fused.row_poses[:, camera.height // 2, :3, 3] @ M[:3, :3].T + M[:3, 3]
    ix, iy = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
    cells = lo + (np.stack([ix, iy], axis=-1) + 0.5) * cc.cell_m
    for c in centres[:, :2]:
        occupied |= np.hypot(cells[..., 0] - c[0], cells[..., 1] - c[1]) <= cc.operator_radius_m
    floor_seen = count(np.abs(h) <= cc.floor_band_m) >= cc.floor_points
    through, probed, view, near_view = _seen_and_view(fused, M, camera, lo, shape, cfg)
    clear = through >= cc.seen_frames
    known = ~occupied & (floor_seen | ((clear | (probed == 0)).all(axis=0) & clear.any(axis=0)))  # probed: touched
    return FreeSpace(lo, cc.cell_m, occupied, known, view, near_view, cfg)


def _seen_and_view(fused: Fused, M, camera, origin, shape, cfg) -> tuple[np.ndarray, ...]:
    """((P, nx, ny) how many fused frames looked through the space ``probe_heights_m`` above each cell (a depth at
    least ``see_through_m`` beyond the probe, at the probe's pixel), (P, nx, ny) how many saw a surface at the probe
    (a depth within ``see_through_m`` of it), (nx, ny) the share of fused frames whose image
    holds any of the cell's points at ``view_heights_m``, (nx, ny) the same share with the image grown by
    ``view_margin_px``)."""
    cc = cfg.composite
    ix, iy = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
    xy = origin + (np.stack([ix.ravel(), iy.ravel()], axis=1) + 0.5) * cc.cell_m
    Minv = np.linalg.inv(M)
    heights = tuple(cc.probe_heights_m)
    m = cc.view_margin_px
    through = np.zeros((len(heights), len(xy)), np.int64)
    probed = np.zeros((len(heights), len(xy)), np.int64)
    in_view = np.zeros(len(xy), np.int64)
    near_view = np.zeros(len(xy), np.int64)
    for k, z in enumerate(fused.depths):
        mid = fused.row_poses[k][camera.height // 2]
        seen, near = np.zeros(len(xy), bool), np.zeros(len(xy), bool)
        for h in tuple(cc.view_heights_m):
            X = np.concatenate([xy, np.full((len(xy), 1), h)], axis=1) @ Minv[:3, :3].T + Minv[:3, 3]
            uv, zc = project(X, mid, camera)
            seen |= (zc > 0.1) & (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & \
                (uv[:, 1] < camera.height)
            near |= (zc > 0.1) & (uv[:, 0] >= -m) & (uv[:, 0] < camera.width + m) & (uv[:, 1] >= -m) & \
                (uv[:, 1] < camera.height + m)
        in_view += seen
        near_view += near
        for j, h in enumerate(heights):
            X = np.concatenate([xy, np.full((len(xy), 1), h)], axis=1) @ Minv[:3, :3].T + Minv[:3, 3]
            uv, zc = project(X, mid, camera)
            inside = (zc > 0.1) & (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & \
                (uv[:, 1] < camera.height)
            idx = np.flatnonzero(inside)
            d = z[uv[idx, 1].astype(np.int64), uv[idx, 0].astype(np.int64)]
            through[j, idx] += (d > 0) & (d >= zc[idx] + cc.see_through_m)
            probed[j, idx] += (d > 0) & (np.abs(d - zc[idx]) < cc.see_through_m)  # a surface at the probe
    n = max(len(fused.depths), 1)
    P = (len(heights),) + tuple(shape)
    return (through.reshape(P), probed.reshape(P), (in_view / n).reshape(shape), (near_view / n).reshape(shape))


def project(X: np.ndarray, T_world_camera: np.ndarray, camera) -> tuple[np.ndarray, np.ndarray]:
    """(pixels (N, 2) through the lens, depth (N,)) of world points X in the camera ``T_world_camera``; points behind
    the camera get depth <= 0."""
    Xc = (X - T_world_camera[:3, 3]) @ T_world_camera[:3, :3]
    zc = Xc[:, 2]
    x = Xc[:, :2] / np.where(np.abs(zc) > 1e-9, zc, 1e-9)[:, None]
    K = camera.K
    if camera.has_distortion:  # the lens polynomial folds back far outside the image: only rays the image can see
        reach = np.abs(_pixel_reach(camera))
        zc = np.where((np.abs(x) <= 1.2 * reach).all(axis=1), zc, -1.0)
        x = distort_normalised(np.clip(x, -1.2 * reach, 1.2 * reach), camera.dist)
    return np.stack([x[:, 0] * K[0, 0] + K[0, 2], x[:, 1] * K[1, 1] + K[1, 2]], axis=1), zc


@lru_cache(maxsize=4)
def _pixel_reach(camera) -> np.ndarray:
    """(2,) the largest |undistorted normalised coordinate| of the image's border pixels, x and y."""
    K, W, H = camera.K, camera.width, camera.height
    u = np.concatenate([np.arange(W), np.arange(W), np.zeros(H), np.full(H, W - 1.0)])
    v = np.concatenate([np.zeros(W), np.full(W, H - 1.0), np.arange(H), np.arange(H)])
    x = undistort_normalised(np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]], axis=1), camera.dist)
    return np.abs(x).max(axis=0)
