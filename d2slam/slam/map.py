"""The map: map points as growable column arrays, keyframes, and one global observation table
(keyframe, point, keypoint, octave) from which covisibility, local-BA edges and culling are computed with numpy
(no per-point Python containers)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from d2slam.slam.matching import Gridded, medoid_descriptors
from d2slam.slam.projection import inv


class Columns:
    """Growable struct-of-arrays (capacity doubling)."""

    def __init__(self, spec: dict[str, tuple[tuple, type, float]]):
        self._spec = spec
        self.n = 0
        self._cap = 0
        for name, (shape, dtype, _fill) in spec.items():
            setattr(self, name, np.zeros((0, *shape), dtype=dtype))

    def append(self, count: int, **values) -> np.ndarray:
        start = self.n
        need = self.n + count
        if need > self._cap:
            cap = max(need, 2 * self._cap, 1024)
            for name, (shape, dtype, fill) in self._spec.items():
                old = getattr(self, name)
                new = np.full((cap, *shape), fill, dtype=dtype)
                new[: self.n] = old[: self.n]
                setattr(self, name, new)
            self._cap = cap
        for name, (shape, dtype, fill) in self._spec.items():
            arr = getattr(self, name)
            arr[start:need] = values.get(name, fill)
        self.n = need
        return np.arange(start, need)

    def view(self, name: str) -> np.ndarray:
        return getattr(self, name)[: self.n]


@dataclass
class KeyFrame(Gridded):
    id: int
    frame_index: int
    timestamp: float
    Tcw: np.ndarray
    kps: np.ndarray
    octave: np.ndarray
    angle: np.ndarray
    desc: np.ndarray
    depth: np.ndarray
    ur: np.ndarray
    inv_sigma2: np.ndarray
    mp: np.ndarray  # (N,) map point ids, -1 none
    bad: bool = False
    dynamic: np.ndarray | None = None  # (N,) bool: the hook's verdict when the keyframe was made (None: no filter)
    fv_nodes: np.ndarray | None = field(default=None, repr=False)  # (N,) vocabulary feature-vector nodes, when needed
    grids: dict = field(default_factory=dict, repr=False)  # cell size -> KeypointGrid (``Gridded.grid``)


class Map:
    def __init__(self):
        self.points = Columns({
            "pos": ((3,), np.float64, 0.0),
            "desc": ((32,), np.uint8, 0),
            "normal": ((3,), np.float64, 0.0),
            "dmin": ((), np.float64, 0.0),
            "dmax": ((), np.float64, 0.0),
            "belief": ((), np.float64, 0.0),
            "visible": ((), np.int64, 1),
            "found": ((), np.int64, 1),
            "nobs": ((), np.int64, 0),  # ORB-SLAM counting: 2 per observation with depth (uR), 1 otherwise
            "alive": ((), bool, True),
            "first_kf": ((), np.int64, -1),
            "angle": ((), np.float32, 0.0),
            "octave": ((), np.int64, 0),
        })
        self.obs = Columns({
            "kf": ((), np.int64, -1),
            "pt": ((), np.int64, -1),
            "kp": ((), np.int64, -1),
            "octave": ((), np.int64, 0),
            "weight": ((), np.int64, 1),
            "valid": ((), bool, True),
        })
        self.keyframes: list[KeyFrame] = []
        self.recent_points: np.ndarray = np.zeros(0, dtype=np.int64)

    # ------------------------------------------------------------------ points
    @property
    def n_points(self) -> int:
        return int(self.points.view("alive").sum())

    def add_points(self, pos, desc, normal, dmin, dmax, belief, first_kf, angle, octave) -> np.ndarray:
        ids = self.points.append(len(pos), pos=pos, desc=desc, normal=normal, dmin=dmin, dmax=dmax, belief=belief,
                                 first_kf=first_kf, angle=angle, octave=octave)
        self.recent_points = np.r_[self.recent_points, ids]
        return ids

    def add_observations(self, kf: KeyFrame, kp_idx: np.ndarray, pt_ids: np.ndarray) -> None:
        if len(kp_idx) == 0:
            return
        w = np.where(kf.depth[kp_idx] > 0, 2, 1)  # ORB-SLAM counts an observation with depth twice
        self.obs.append(len(kp_idx), kf=kf.id, pt=pt_ids, kp=kp_idx, octave=kf.octave[kp_idx], weight=w)
        kf.mp[kp_idx] = pt_ids
        np.add.at(self.points.nobs, pt_ids, w)

    def erase_observations(self, rows: np.ndarray) -> None:
        """Invalidate observation rows (and the keyframes' keypoint -> point links)."""
        rows = rows[self.obs.valid[rows]]
        if len(rows) == 0:
            return
        self.obs.valid[rows] = False
        np.add.at(self.points.nobs, self.obs.pt[rows], -self.obs.weight[rows])
        kfs = self.obs.kf[rows]
        for kid in np.unique(kfs):
            sel = rows[kfs == kid]
            self.keyframes[kid].mp[self.obs.kp[sel]] = -1
        # A point left without observations is dead.
        pts = np.unique(self.obs.pt[rows])
        self.points.alive[pts[self.points.nobs[pts] <= 0]] = False

    def drop_depth(self, rows: np.ndarray) -> None:
        """Observation rows whose keyframe's depth at the keypoint is dropped: the keyframe's ``u_R`` there becomes
        -1 (a monocular observation from now on) and the row counts once, as ORB-SLAM counts an observation without
        depth."""
        rows = rows[self.obs.valid[rows]]
        if len(rows) == 0:
            return
        kfs = self.obs.kf[rows]
        for kid in np.unique(kfs):
            kf = self.keyframes[kid]
            kf.ur[self.obs.kp[rows[kfs == kid]]] = -1.0
            kf.grids.clear()  # the search grids hold u_R
        np.add.at(self.points.nobs, self.obs.pt[rows], 1 - self.obs.weight[rows])
        self.obs.weight[rows] = 1

    def update_points(self, ids: np.ndarray, scales: np.ndarray) -> None:
        """ORB-SLAM ``MapPoint::ComputeDistinctiveDescriptors`` and ``UpdateNormalAndDepth`` for the live points
        ``ids``, from their valid observations: the descriptor becomes the medoid of the observing keypoints'
        (``medoid_descriptors``); the normal the mean of the unit rays from the observing keyframes' centres (not
        normalised again, as ORB-SLAM3); the distance range ``dmax = |X - O_ref| x scales[level in ref]``, ``dmin =
        dmax / scales[-1]``, ref being the keyframe that made the point while it observes it (``first_kf``), else
        the observing keyframe of the lowest id (ORB-SLAM3 takes the first of its observations then)."""
        P = self.points
        ids = np.unique(np.asarray(ids, dtype=np.int64))
        ids = ids[P.alive[ids]]
        if len(ids) == 0:
            return
        mask = np.zeros(P.n, dtype=bool)
        mask[ids] = True
        rows = self.observation_rows(mask)
        rows = rows[np.lexsort((self.obs.kf[rows], self.obs.pt[rows]))]  # by point, then keyframe
        pt, kf, kp = self.obs.pt[rows], self.obs.kf[rows], self.obs.kp[rows]
        ids, start = np.unique(pt, return_index=True)
        desc = np.empty((len(rows), 32), dtype=np.uint8)
        centre = np.empty((len(rows), 3))
        for k in np.unique(kf):
            sel = kf == k
            K_ = self.keyframes[k]
            desc[sel] = K_.desc[kp[sel]]
            centre[sel] = inv(K_.Tcw)[:3, 3]
        P.desc[ids] = desc[medoid_descriptors(desc, np.r_[start, len(rows)])]
        ray = P.pos[pt] - centre
        dist = np.linalg.norm(ray, axis=1)
        count = np.diff(np.r_[start, len(rows)])
        P.normal[ids] = np.add.reduceat(ray / np.maximum(dist, 1e-12)[:, None], start, axis=0) / count[:, None]
        ref = np.where(kf == P.first_kf[pt], 0, 1) * (1 << 40) + kf  # the maker first, else the lowest id
        first = np.flatnonzero(ref == np.repeat(np.minimum.reduceat(ref, start), count))  # one row per point
        P.dmax[ids] = dist[first] * scales[self.obs.octave[rows[first]]]
        P.dmin[ids] = P.dmax[ids] / scales[-1]

    def cull_points(self, ids: np.ndarray) -> None:
        """Set points bad and erase all their observations."""
        ids = np.asarray(ids, dtype=np.int64)
        if len(ids) == 0:
            return
        self.points.alive[ids] = False
        dead = np.zeros(self.points.n, dtype=bool)
        dead[ids] = True
        rows = np.flatnonzero(self.obs.view("valid") & dead[self.obs.view("pt")])
        self.erase_observations(rows)

    def replace_points(self, old: np.ndarray, new: np.ndarray) -> None:
        """ORB-SLAM MapPoint::Replace for pairs (old[i] -> new[i]) (no point may be both old and new): every
        observation of an old point moves to its new point, unless that keyframe already sees the new point (then
        it is erased); visible/found counts are added; old points die."""
        old, new = np.asarray(old, dtype=np.int64), np.asarray(new, dtype=np.int64)
        if len(old) == 0:
            return
        P = self.points
        target = np.full(P.n, -1, dtype=np.int64)
        target[old] = new
        valid, pt, kf = self.obs.view("valid"), self.obs.view("pt"), self.obs.view("kf")
        rows = np.flatnonzero(valid & (target[pt] >= 0))
        is_new = np.zeros(P.n, dtype=bool)
        is_new[new] = True
        new_rows = np.flatnonzero(valid & is_new[pt])
        stride = P.n
        seen = np.isin(kf[rows] * stride + target[pt[rows]], kf[new_rows] * stride + pt[new_rows])
        move = rows[~seen]
        dest = target[pt[move]]
        # Two old points of one keyframe with the same new point: the first observation moves, the others are erased
        # (ORB-SLAM3 replaces one point after the other, and the second then finds the new point in that keyframe).
        first = np.zeros(len(move), dtype=bool)
        first[np.unique(kf[move] * stride + dest, return_index=True)[1]] = True
        self.erase_observations(np.r_[rows[seen], move[~first]])
        move, dest = move[first], dest[first]
        np.add.at(P.nobs, pt[move], -self.obs.weight[move])
        np.add.at(P.nobs, dest, self.obs.weight[move])
        self.obs.pt[move] = dest
        for kid in np.unique(kf[move]):
            sel = move[kf[move] == kid]
            self.keyframes[kid].mp[self.obs.kp[sel]] = self.obs.pt[sel]
        np.add.at(P.visible, new, P.visible[old])
        np.add.at(P.found, new, P.found[old])
        P.alive[old] = False
        P.nobs[old] = 0

    # ------------------------------------------------------------------ keyframes
    def add_keyframe(self, kf: KeyFrame) -> None:
        assert kf.id == len(self.keyframes)
        self.keyframes.append(kf)

    def good_keyframes(self) -> list[KeyFrame]:
        return [k for k in self.keyframes if not k.bad]

    def observation_rows(self, point_mask: np.ndarray) -> np.ndarray:
        """Valid observation rows of the points selected by a (n_points,) bool mask."""
        valid = self.obs.view("valid")
        return np.flatnonzero(valid & point_mask[self.obs.view("pt")])

    def covisibility(self, kf_id: int) -> np.ndarray:
        """(n_keyframes,) number of points each keyframe shares with ``kf_id`` (0 for itself and bad ones)."""
        kf = self.keyframes[kf_id]
        mask = np.zeros(self.points.n, dtype=bool)
        pts = kf.mp[kf.mp >= 0]
        mask[pts[self.points.alive[pts]]] = True
        rows = self.observation_rows(mask)
        counts = np.bincount(self.obs.kf[rows], minlength=len(self.keyframes))
        counts[kf_id] = 0
        return counts

    def points_of(self, kf_ids) -> np.ndarray:
        """Sorted ids of the points the keyframes ``kf_ids`` observe (a mask over the points, no sort)."""
        mask = np.zeros(self.points.n, dtype=bool)
        for k in kf_ids:
            m = self.keyframes[k].mp
            mask[m[m >= 0]] = True
        return np.flatnonzero(mask)

    def covisible(self, kf_id: int, n: int, min_shared: int) -> list[int]:
        """The (at most ``n``) good keyframes sharing the most points with ``kf_id``, at least ``min_shared`` each,
        best first (ties: lower id first)."""
        w = self.covisibility(kf_id)
        order = np.argsort(-w, kind="stable")[:n]
        return [int(k) for k in order if w[k] >= min_shared and not self.keyframes[k].bad]

    def keyframe_counts(self, pt_ids: np.ndarray) -> np.ndarray:
        """(n_keyframes,) number of the given points each keyframe observes."""
        mask = np.zeros(self.points.n, dtype=bool)
        mask[pt_ids] = True
        rows = self.observation_rows(mask)
        return np.bincount(self.obs.kf[rows], minlength=len(self.keyframes))

    def set_keyframe_bad(self, kf_id: int) -> None:
        kf = self.keyframes[kf_id]
        kf.bad = True
        rows = np.flatnonzero(self.obs.view("valid") & (self.obs.view("kf") == kf_id))
        self.erase_observations(rows)
