"""Object Interaction Module of D2SLAM (eq 9-10): static keypoints near people that move with them.

Interaction zone of person mask n (our reading of "related to the human depth",
docs/design.md#object-interaction-module-eq-9-10): the pixels within
``zone_factor * delta(z_n)`` = 2 delta(z_n) px of the mask whose depth differs from the mask's median depth z_n by
less than ``zone_depth`` = 1 m. For each keypoint p_i still static inside a zone, its neighbours are the keypoints
p_id the geometric module marked dynamic (err > alpha, eq 5, or our pose test) with

    ||p_i - p_id|| < delta(z_i)   and   Delta = |z_i - z_id| < rho = 0.7 m                             (eq 9)
    G(p_i) = sum w p_id / sum w,   w = (rho - Delta) / rho                                                (eq 10)

and p_i becomes dynamic when ||p_i - G|| < gamma(z_i).

Depth tests with an invalid depth on either side fail (the OIM only turns keypoints dynamic on evidence): a
keypoint without depth is in no zone, is no neighbour, and a mask with no valid depth pixel has no zone. In the
"no-depth" ablation (``use_depth=False``) the depth tests are dropped, delta/gamma sit at their midpoints (29.5 px,
19 px) and every weight is 1 (a plain centroid). A keypoint is never its own neighbour.

Neighbour search: ``scipy.spatial.cKDTree.sparse_distance_matrix`` between the candidates and the matched keypoints
(one call, ndarray output; the dynamic keypoints are matched ones, and the frame's ``MatchedPoints`` tree is shared
with ``neighbour_p_g``), then eq 9 filters and eq 10 weighted sums by ``np.bincount``: no Python loop.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from d2slam.dynamics.config import DynamicsConfig
from d2slam.dynamics.depth import DepthMaps, delta, gamma, valid_depth
from d2slam.dynamics.semantic import FrameMasks, MaskEdges, mask_edges

_DEFAULT = DynamicsConfig()


def _tree(pts: np.ndarray) -> cKDTree:
    """cKDTree of keypoints: unbalanced, non-compacted, 32 points per leaf (faster to build, the same answers;
    measured: docs/deviations.md, ``interaction._tree``)."""
    return cKDTree(pts, leafsize=32, balanced_tree=False, compact_nodes=False)


class MatchedPoints:
    """A frame's matched keypoints (``observed``, finite, with a valid depth when ``valid`` is given): ``idx`` (M,)
    their indices and ``tree`` their cKDTree, built on first use. Shared by ``neighbour_p_g`` (the matched
    neighbours of unmatched keypoints) and ``object_interaction`` (eq 9's dynamic neighbours, which are matched
    keypoints), so one tree per frame serves both."""

    __slots__ = ("kps", "finite", "idx", "_tree")

    def __init__(self, kps: np.ndarray, observed: np.ndarray, finite: np.ndarray, valid: np.ndarray | None = None):
        self.kps = kps
        self.finite = finite  # (N,) bool, finite keypoint coordinates
        ok = np.asarray(observed, dtype=bool) & finite
        if valid is not None:
            ok &= valid
        self.idx = np.flatnonzero(ok)
        self._tree = None

    @property
    def tree(self) -> cKDTree:
        if self._tree is None:
            self._tree = _tree(self.kps[self.idx])
        return self._tree


def mask_depths(depth: np.ndarray, masks: np.ndarray | list[MaskEdges] | None,
                cfg: DynamicsConfig = _DEFAULT) -> np.ndarray:
    """eq 9: z_n, the median of the valid depths of each mask (n,), NaN for a mask without valid depth.

    ``masks`` (n, H, W) bool, the frame's ``mask_edges`` or ``FrameMasks`` (their bounding boxes are reused).
    Deviation, for speed: the median is taken over the mask pixels of a grid of stride ``zone_median_stride`` (4:
    1/16 of the pixels) inside the mask's bounding box; it differs from the full median by far less than the zone's
    1 m tolerance (the tests bound the difference; measured: docs/deviations.md, ``OursConfig.zone_median_stride``).
    Stride 1 = every pixel. A mask the grid misses entirely falls back to every pixel."""
    edges = masks.edges if isinstance(masks, FrameMasks) else masks if isinstance(masks, list) else mask_edges(masks)
    s = max(int(cfg.ours.zone_median_stride), 1)
    depth = np.asarray(depth)
    out = np.full(len(edges), np.nan)
    for k, e in enumerate(edges):  # loop over masks only
        if e.empty:
            continue
        x, y, w, h = e.bbox
        m = e.mask.view(bool)
        vals = depth[y:y + h:s, x:x + w:s][m[y:y + h:s, x:x + w:s]]
        with np.errstate(invalid="ignore"):
            vals = vals[np.isfinite(vals) & (vals > 0)]  # valid_depth without the float64 copy
        if len(vals) == 0 and s > 1:
            vals = depth[y:y + h, x:x + w][m[y:y + h, x:x + w]]
            vals = vals[valid_depth(vals)]
        if len(vals):
            out[k] = _median(vals)
    return out


def _median(vals: np.ndarray) -> float:
    """``np.median`` of a non-empty 1-D array with the same result (one ``np.partition``, the mean of the two middle
    values in the array's dtype), without ``np.median``'s overhead (measured: docs/deviations.md,
    ``interaction._median``)."""
    if vals.dtype.kind != "f":
        vals = vals.astype(np.float64)  # integer depths: np.median averages in float64 (and a uint16 sum overflows)
    h = len(vals) // 2
    if len(vals) % 2:
        return float(np.partition(vals, h)[h])
    part = np.partition(vals, (h - 1, h))
    return float((part[h - 1] + part[h]) / 2)


def interaction_zone(d: np.ndarray, z: np.ndarray, z_n: np.ndarray, cfg: DynamicsConfig = _DEFAULT,
                     use_depth: bool = True) -> np.ndarray:
    """eq 9 (zone): (N,) bool, keypoint within ``zone_factor * delta(z_n)`` px of some mask n (signed distance
    ``d`` (N, n) from the semantic module, > -2 delta(z_n); inside the mask counts) and |z - z_n| < ``zone_depth``."""
    d = np.asarray(d, dtype=np.float64)
    n_kp, n_masks = d.shape
    if n_masks == 0 or n_kp == 0:
        return np.zeros(n_kp, dtype=bool)
    z_n = np.asarray(z_n, dtype=np.float64)
    reach = cfg.zone_factor * delta(z_n, cfg, use_depth)
    with np.errstate(invalid="ignore"):
        near = np.nan_to_num(d, nan=-np.inf) > -reach[None, :]
        if use_depth:
            z = np.asarray(z, dtype=np.float64)
            both = valid_depth(z)[:, None] & valid_depth(z_n)[None, :]
            near &= both & (np.abs(np.where(both, z[:, None] - z_n[None, :], np.inf)) < cfg.zone_depth)
    return near.any(axis=1)


def oim_candidates(belief: np.ndarray, observed: np.ndarray, geo_dynamic: np.ndarray,
                   cfg: DynamicsConfig = _DEFAULT, p_nb: np.ndarray | None = None) -> np.ndarray:
    """eq 10: (N,) bool, the keypoints the OIM may turn dynamic: still static after eq 8 (belief <= 0.5) and, with
    ``oim_skip_observed_static`` (ours, the default), not matched with a passed geometric test this frame (matched
    and not ``geo_dynamic``: epipolar error <= alpha and, with the pose test on, its residuals under threshold).

    Deviation: with the paper's candidates the OIM flips many more static keypoints than dynamic ones, and each flip
    takes a static keypoint out of tracking and mapping. A keypoint whose own epipolar test passed has direct
    evidence of being static, which its neighbours' should not override; keeping it out of the OIM costs some recall
    and lowers the ATE (measured: docs/deviations.md, ``OursConfig.oim_skip_observed_static``). Unmatched
    keypoints (most of an object's keypoints while it is carried) stay candidates.
    ``oim_skip_observed_static=False`` gives the paper's reading.

    ``oim_skip_neighbour_static`` (ours, off by default) also drops the unmatched keypoints whose matched neighbours
    say static, ``p_nb`` (``neighbour_p_g``) <= 0.5: it trades recall for precision (measured: docs/deviations.md,
    ``OursConfig.oim_skip_neighbour_static``)."""
    cand = np.asarray(belief, dtype=np.float64) <= cfg.dynamic_threshold
    if cfg.ours.oim_skip_observed_static:
        cand &= ~(np.asarray(observed, dtype=bool) & ~np.asarray(geo_dynamic, dtype=bool))
    if cfg.ours.oim_skip_neighbour_static and p_nb is not None:
        with np.errstate(invalid="ignore"):
            cand &= ~(np.asarray(p_nb, dtype=np.float64) <= cfg.dynamic_threshold)  # NaN compares False
    return cand


def object_interaction(kps: np.ndarray, z: np.ndarray, candidate: np.ndarray, dynamic: np.ndarray,
                       cfg: DynamicsConfig = _DEFAULT, use_depth: bool = True, maps: DepthMaps | None = None,
                       finite: np.ndarray | None = None,
                       matched: MatchedPoints | None = None) -> tuple[np.ndarray, np.ndarray]:
    """eq 9-10: (flip (N,) bool, G (N, 2) centroid, NaN where p_i has no neighbour or is no candidate).

    ``candidate`` (N,) bool: static keypoints inside an interaction zone; ``dynamic`` (N,) bool: the geometric
    module's flag (err > alpha, or the pose test). ``maps`` (the frame's ``DepthMaps`` of ``z`` with the same
    ``use_depth``) and ``finite`` (finite keypoint coordinates) are reused when given instead of being recomputed.
    ``matched`` (optional): the frame's ``MatchedPoints`` built with the same depth validity; every ``dynamic``
    keypoint must be among them (the geometric module only flags matched keypoints), and their tree is then searched
    instead of building one over the dynamic keypoints."""
    kps = np.asarray(kps, dtype=np.float64).reshape(-1, 2)
    z = np.asarray(z, dtype=np.float64).reshape(-1)
    n = len(kps)
    flip = np.zeros(n, dtype=bool)
    centroid = np.full((n, 2), np.nan)
    if finite is None:
        finite = np.isfinite(kps[:, 0]) & np.isfinite(kps[:, 1])
    if use_depth:
        finite = finite & (maps.valid if maps is not None else valid_depth(z))
    dynamic = np.asarray(dynamic, bool)
    ci = np.flatnonzero(np.asarray(candidate, bool) & finite)
    if len(ci) == 0 or not (dynamic & finite).any():
        return flip, centroid
    if matched is None:
        matched = MatchedPoints(kps, dynamic, finite)
    # delta(z_i) of each candidate (eq 9)
    radius = maps.delta[ci] if maps is not None else delta(z[ci], cfg, use_depth)
    pairs = _tree(kps[ci]).sparse_distance_matrix(matched.tree, float(radius.max()), output_type="ndarray")
    i, j, dist = pairs["i"], matched.idx[pairs["j"]], pairs["v"]
    keep = dynamic[j] & (dist < radius[i]) & (ci[i] != j)
    if use_depth:
        dz = np.abs(z[ci[i]] - z[j])
        keep &= dz < cfg.rho
        w = (cfg.rho - dz) / cfg.rho  # eq 10 weights
    else:
        w = np.ones(len(i))
    i, j, w = i[keep], j[keep], w[keep]
    wsum = np.bincount(i, weights=w, minlength=len(ci))
    gx = np.bincount(i, weights=w * kps[j, 0], minlength=len(ci))
    gy = np.bincount(i, weights=w * kps[j, 1], minlength=len(ci))
    has = wsum > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        g = np.stack([gx / wsum, gy / wsum], axis=1)  # eq 10
    dist_g = np.hypot(kps[ci, 0] - g[:, 0], kps[ci, 1] - g[:, 1])
    gam = maps.gamma[ci] if maps is not None else gamma(z[ci], cfg, use_depth)
    with np.errstate(invalid="ignore"):
        flip[ci] = has & (dist_g < gam)
    centroid[ci[has]] = g[has]
    return flip, centroid


def binomial():
    """scipy.stats' binomial distribution of eq 9's moving test, imported at the first call: importing scipy.stats
    takes about half a second, which the command line should not pay at start, nor a run in its first frame (the
    filter asks for it when it is built: ``D2SlamFilter``)."""
    from scipy.stats import binom

    return binom


def moving_masks(fm: FrameMasks, observed: np.ndarray, dynamic: np.ndarray,
                 cfg: DynamicsConfig = _DEFAULT) -> np.ndarray:
    """eq 9 (ours, ``OursConfig.oim_moving_test``): (n,) bool, whether each person moves this frame: of the m
    matched keypoints on its mask (``observed``), d failed the geometric test (``dynamic``), and a binomial tail
    P(X >= d | m, 1 - noise_confidence) below ``oim_moving_alpha`` says more failed than the thresholds' false alarms
    explain. A mask with fewer than ``oim_moving_min`` matched keypoints counts as moving (it cannot be told still);
    an empty mask as still. Without the test every mask moves (the paper's OIM)."""
    n = len(fm.edges)
    ours = cfg.ours
    if not ours.oim_moving_test:
        return np.ones(n, dtype=bool)
    observed = np.asarray(observed, dtype=bool)
    dynamic = np.asarray(dynamic, dtype=bool) & observed
    out = np.zeros(n, dtype=bool)
    for k, inside in enumerate(fm.inside):  # loop over masks only
        if inside is None:
            continue
        m, d = int((inside & observed).sum()), int((inside & dynamic).sum())
        out[k] = m < ours.oim_moving_min or binomial().sf(d - 1, m, 1.0 - ours.noise_confidence) < ours.oim_moving_alpha
    return out


def oim_frame(fm: FrameMasks, kps: np.ndarray, maps: DepthMaps, z_n: np.ndarray, d: np.ndarray, known: float,
              candidates: np.ndarray, dynamic: np.ndarray, cfg: DynamicsConfig = _DEFAULT,
              use_depth: bool = True, matched: MatchedPoints | None = None,
              moving: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """eq 9-10 for one frame, reusing the semantic module's work: (zone (N,) bool, oim (N,) bool).

    ``fm`` the frame's ``FrameMasks`` (edges, trees, pixel lookups, bounding-box distances), ``maps`` its
    ``DepthMaps``, ``z_n`` the mask depths, ``d`` the semantic module's signed distances (exact within ``known`` px of
    each mask), ``candidates`` the keypoints the OIM may flip (``oim_candidates``), ``dynamic`` the geometric module's
    flag (err > alpha, or the pose test), ``matched`` the frame's ``MatchedPoints`` (optional, see
    ``object_interaction``). Order of the tests (same result as zone first, far fewer edge searches):

    1. candidates passing a necessary condition of the zone (within 2 delta(z_n) px of some mask's
       bounding box, a lower bound of the distance to the mask, and |z - z_n| < ``zone_depth``);
    2. eq 10's centroid test on them (``object_interaction``) -> the keypoints that would flip;
    3. the exact zone (eq 9, the test of ``interaction_zone``) on those rows only: distances beyond ``known`` are
       searched again up to the zone's reach with the mask's cached edge trees.

    ``moving`` (optional (n,) bool, :func:`moving_masks`): only these masks have a zone.

    ``zone`` is the zone flag where step 3 ran (False elsewhere), and ``oim = zone`` (those keypoints flip)."""
    n = len(maps.z)
    zone = np.zeros(n, dtype=bool)
    if not fm.edges or n == 0:
        return zone, zone.copy()
    reach = cfg.zone_factor * delta(z_n, cfg, use_depth)
    zn_ok = valid_depth(z_n)
    still = np.zeros(len(fm.edges), dtype=bool) if moving is None else ~np.asarray(moving, dtype=bool)
    if still.all():  # a still person has no zone
        return zone, zone.copy()
    with np.errstate(invalid="ignore"):
        near_depth = [maps.valid & (np.abs(maps.z - z_n[k]) < cfg.zone_depth) for k in range(len(fm.edges))] \
            if use_depth else None
    # 1. candidates
    cand = _near_a_mask(fm, reach, zn_ok, near_depth, still) & fm.kp.finite & candidates
    # 2. eq 10
    would_flip, _ = object_interaction(kps, maps.z, cand, dynamic, cfg, use_depth, maps=maps, finite=fm.kp.finite,
                                       matched=matched)
    rows = np.flatnonzero(would_flip)
    if len(rows) == 0:
        return zone, zone.copy()
    # 3. eq 9 on the rows that would flip
    zone[rows] = _in_a_zone(fm, d, rows, reach, zn_ok, near_depth, known, still)
    return zone, zone.copy()


def _near_a_mask(fm: FrameMasks, reach: np.ndarray, zn_ok: np.ndarray, near_depth: list | None,
                 still: np.ndarray) -> np.ndarray:
    """(N,) bool, ``oim_frame``'s step 1: within ``reach`` px of the bounding box of some mask not ``still`` (a lower
    bound of the distance to the mask) and, with the depths (``near_depth`` given), at that mask's depth."""
    cand = np.zeros(len(fm.kp.finite), dtype=bool)
    for k, e in enumerate(fm.edges):  # loop over masks only
        if e.empty or still[k] or (near_depth is not None and not zn_ok[k]):
            continue
        ok = fm.box[k] <= reach[k]
        if near_depth is not None:
            ok &= near_depth[k]
        cand |= ok
    return cand


def _in_a_zone(fm: FrameMasks, d: np.ndarray, rows: np.ndarray, reach: np.ndarray, zn_ok: np.ndarray,
               near_depth: list | None, known: float, still: np.ndarray) -> np.ndarray:
    """(len(rows),) bool, ``oim_frame``'s step 3: eq 9's zone (of the masks not ``still``) for the keypoints ``rows``;
    signed distances ``d`` beyond ``known`` px are searched again up to the zone's reach with the mask's cached edge
    trees."""
    finite = fm.kp.finite
    hit = np.zeros(len(rows), dtype=bool)
    for k, e in enumerate(fm.edges):  # loop over masks only
        dk = d[rows, k]
        depth_ok = near_depth[k][rows] if near_depth is not None else None
        if still[k]:
            continue
        if not (e.empty or e.full or reach[k] <= known) and (zn_ok[k] or near_depth is None):
            sel = (dk <= -known) & finite[rows]
            if near_depth is not None:
                sel &= depth_ok
            sel &= fm.box[k][rows] <= reach[k]
            if sel.any():
                dk = dk.copy()
                dk[sel] = fm.signed(k, float(reach[k]), rows[sel])
        with np.errstate(invalid="ignore"):
            zk = dk > -reach[k]
        if near_depth is not None:
            zk &= depth_ok & zn_ok[k]
        hit |= zk
    return hit


def neighbour_p_g(kps: np.ndarray, maps: DepthMaps, observed: np.ndarray, p_g: np.ndarray,
                  cfg: DynamicsConfig = _DEFAULT, skip: np.ndarray | None = None,
                  matched: MatchedPoints | None = None) -> np.ndarray:
    """eq 7 (ours): (N,) mean P_g (eq 6) of each unmatched keypoint's matched neighbours: of its
    ``neighbour_k`` nearest matched keypoints, those within delta(z_i) px (eq 9's radius) and |z_i - z_j| <
    ``neighbour_depth`` m. NaN for matched keypoints, keypoints without valid depth and keypoints with fewer than
    ``neighbour_min`` such neighbours, and where ``skip`` (optional (N,) bool; the classifier skips the keypoints
    inside a mask, whose P = P_S > 0.5 already says dynamic). ``fusion.fuse`` gives an unmatched keypoint max(P, this).

    Why: eq 7 gives an unmatched keypoint outside every mask area P = 0.5, so its belief only keeps its prior. Many
    of the dynamic keypoints the classifier misses are such keypoints (on people the masks missed and on carried
    objects), and their matched neighbours on the same surface usually carry the motion. It raises the recall at an
    unchanged ATE (measured: docs/deviations.md, ``OursConfig.neighbour_p_g``).

    One ``cKDTree.query`` (k nearest, bounded by the largest radius) over the matched keypoints: no Python loop.
    ``matched`` (optional): the frame's ``MatchedPoints`` of ``observed`` with a valid depth, whose tree the OIM
    reuses; built here when not given. ``p_g`` must be finite where ``observed`` (the geometric module's output is).
    """
    kps = np.asarray(kps, dtype=np.float64).reshape(-1, 2)
    out = np.full(len(kps), np.nan)
    observed = np.asarray(observed, dtype=bool)
    if matched is None:
        matched = MatchedPoints(kps, observed, np.isfinite(kps[:, 0]) & np.isfinite(kps[:, 1]), maps.valid)
    oi = matched.idx
    ok = ~observed & maps.valid & matched.finite
    qi = np.flatnonzero(ok if skip is None else ok & ~np.asarray(skip, dtype=bool))
    k = min(int(cfg.ours.neighbour_k), len(oi))
    if len(qi) == 0 or k == 0:
        return out
    radius = maps.delta[qi]
    dist, j = matched.tree.query(kps[qi], k=k, distance_upper_bound=float(radius.max()))
    dist, j = dist.reshape(len(qi), k), j.reshape(len(qi), k)
    found = j < len(oi)  # missing neighbours come back as index len(oi), distance inf
    nb = oi[np.where(found, j, 0)]
    keep = found & (dist < radius[:, None]) & (np.abs(maps.z[qi, None] - maps.z[nb]) < cfg.ours.neighbour_depth)
    count = keep.sum(axis=1)
    total = np.where(keep, np.asarray(p_g, dtype=np.float64)[nb], 0.0).sum(axis=1)  # finite: nb are observed
    has = count >= max(int(cfg.ours.neighbour_min), 1)
    out[qi[has]] = total[has] / count[has]
    return out
