"""People composited into a real recording: the scene (``d2slam synth real_walking --on-trajectory TUM_DIR``).

The composite scenarios put the benchmark's people (``d2slam.synth.actors``, ``bodies``) into a real TUM recording:
its images are the background, its ground truth the camera path, its camera and the twin's calibrated sensor timing
(``TwinConfig``) those of the renders. This module plans the people in the recording's room; the images are made by
``d2slam.synth.compositing``.

- **The room** (:func:`real_room`, ``d2slam.synth.realroom``): the recording's depth fused along its ground truth,
  its floor, the room frame the people are planned in (floor at Z = 0, the cameras' mean centre above the origin,
  their mean view along +y) and the free space (where a person can stand).
- **Where people are seen** (:func:`person_visibility`): for a lattice of standable, known-free cells (every
  ``vis_cell_m``) and every fused frame, an estimate of the image share a person standing there covers: a body-sized
  cylinder's points projected into the frame, the part of their outline (convex hull) within the image, times
  ``body_fill``, times the share of the points in the image that are seen (nearer than the real depth, or over one of
  its holes, over which the composite draws them).
- **The people** (:class:`RoomPlanner`, the benchmark's planner on the room's free space): targets "in view" are the
  lattice cells where a person is ever seen (at least ``vis_min_coverage``), drawn with weights by how often a person
  there is seen (the share of the frames, to the power ``vis_weight_power``: the camera of a hand-held recording
  sweeps back and forth, so people keep to where it keeps coming back to); exits are standable cells never in view, within ``exit_reach_m`` of a target and
  reachable from it; routes follow the shortest chain of standable cells (A*). ``real_walking``: two walkers, as the
  fr3 walking people (without chairs to sit on: the room's chairs are part of the real background);
  ``real_carry``: one carries a box (resting on a target cell at the start; the box, too, keeps to standable cells),
  the other walks.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from d2slam.data.tum import TumSequence
from d2slam.errors import D2SlamError
from d2slam.synth import realroom
from d2slam.synth.actors import ActorState, Planner, Route, unit
from d2slam.synth.rigid import pose_rows


@dataclass(frozen=True)
class Visibility:
    """``xy`` (L, 2) lattice cells in the room frame, ``t`` (F,) instants (s after the recording's first frame),
    ``coverage`` (L, F) the estimated image share of a person standing at each cell at each instant."""

    xy: np.ndarray
    t: np.ndarray
    coverage: np.ndarray


@dataclass(frozen=True)
class RealRoom:
    """A recording's room (module docstring): ``M`` (4x4, the recording's world to the room frame), ``floor``
    ((normal, offset) in the recording's world), ``space`` (``realroom.FreeSpace``), ``visibility``."""

    M: np.ndarray
    floor: tuple
    space: object
    visibility: Visibility

    def summary(self, min_coverage: float) -> dict:
        """What ``scene.json`` records of the room: the floor, the room frame, the free space's areas (m^2) and the
        lattice cells where a person is ever seen (at least ``min_coverage``)."""
        s = self.space
        cov = self.visibility.coverage
        return {"floor_normal": [round(float(v), 6) for v in self.floor[0]], "floor_offset_m": round(self.floor[1], 4),
                "room_frame": self.M.round(9).tolist(),
                "area_m2": {"occupied": round(s.area(s.occupied), 3), "known_free": round(s.area(s.known_free), 3),
                            "standable_known_free": round(s.area(s.standable & s.known_free), 3),
                            "never_in_view": round(s.area(s.never_in_view & s.standable), 3),
                            "out_of_view": round(s.area(s.out_of_view & s.standable), 3)},
                "seen_cells": int((cov.max(axis=1, initial=0.0) >= min_coverage).sum()) if cov.size else 0}


def person_visibility(space, fused, M: np.ndarray, camera, t0: float, rgb_times: np.ndarray, cfg) -> Visibility:
    """The :class:`Visibility` of the standable known-free cells (module docstring) over the fused frames."""
    cc = cfg.composite
    k = max(int(round(cc.vis_cell_m / space.cell)), 1)
    ok = space.standable & space.known_free
    ix, iy = np.nonzero(ok)
    keep = (ix % k == k // 2) & (iy % k == k // 2)
    xy = space.centre(ix[keep], iy[keep])
    a = np.linspace(0.0, 2 * np.pi, 12, endpoint=False)
    h = np.linspace(0.05, cc.body_height_m, 18)
    ring = np.stack([cc.body_half_width_m * np.cos(a), cc.body_half_depth_m * np.sin(a)], axis=1)
    offsets = np.concatenate([np.repeat(ring, len(h), axis=0), np.tile(h, len(a))[:, None]], axis=1)  # (S, 3)
    Minv = np.linalg.inv(M)
    cov = np.zeros((len(xy), len(fused.frames)))
    W, H = camera.width, camera.height
    frame = np.array([[0, 0], [W, 0], [W, H], [0, H]], np.float32)
    S = len(offsets)
    for f, z in enumerate(fused.depths):
        T = fused.row_poses[f][camera.height // 2]
        P = (np.concatenate([xy, np.zeros((len(xy), 1))], axis=1)[:, None] + offsets[None]).reshape(-1, 3)
        uv, zc = realroom.project(P @ Minv[:3, :3].T + Minv[:3, 3], T, camera)
        front = zc > 0.1
        inside = front & (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
        idx = np.flatnonzero(inside)
        d = z[uv[idx, 1].astype(np.int64), uv[idx, 0].astype(np.int64)]
        seen = np.zeros(len(P), bool)
        seen[idx] = (d <= 0) | (zc[idx] < d)  # the composite draws people over the real depth's holes
        for j in np.flatnonzero(inside.reshape(len(xy), S).any(axis=1)):
            pts = uv[j * S:(j + 1) * S][front[j * S:(j + 1) * S]].astype(np.float32)
            hull = cv2.convexHull(pts)
            area = cv2.intersectConvexConvex(hull, frame)[0]  # the body's outline within the image
            n_in = int(inside[j * S:(j + 1) * S].sum())
            cov[j, f] = area * cc.body_fill * seen[j * S:(j + 1) * S].sum() / max(n_in, 1) / (W * H)
    return Visibility(xy, np.asarray(rgb_times, float)[fused.frames] - t0, np.clip(cov, 0.0, 1.0))


_ROOMS: dict = {}


def _room(rec, cfg) -> RealRoom:
    seq = TumSequence(rec.root, camera=rec.camera)
    fused = realroom.fuse_depth(rec, lambda i: seq.depth_image(int(rec.frame_index[i])), cfg)
    normal, offset = realroom.estimate_floor(fused.points, cfg)
    M = realroom.room_frame(normal, offset, fused.row_poses[:, rec.camera.height // 2])
    space = realroom.free_space(fused, M, rec.camera, cfg)
    vis = person_visibility(space, fused, M, rec.camera, float(rec.rgb_times[0]), rec.rgb_times, cfg)
    return RealRoom(M, (normal, offset), space, vis)


def real_room(rec, cfg) -> RealRoom:
    """The room of the recording ``rec`` (``d2slam.synth.twin.Recording``, read from its folder: its frames, which may
    be a part of the folder's), measured once per process (module docstring). ``cfg``: the ``SynthConfig``."""
    if rec.root is None or rec.frame_index is None:
        raise D2SlamError("the composite needs the recording's folder (d2slam.synth.twin.read_recording)")
    key = (str(rec.root), np.asarray(rec.frame_index).tobytes(), np.asarray(rec.rgb_times).tobytes(), cfg)
    if key not in _ROOMS:
        _ROOMS.clear()
        _ROOMS[key] = _room(rec, cfg)
    return _ROOMS[key]


# --------------------------------------------------------------------------------------------------
# the people
# --------------------------------------------------------------------------------------------------
class RoomPlanner(Planner):
    """The benchmark's planner (``d2slam.synth.actors.Planner``) on a real room (module docstring): ``room`` gives
    the free space (the floor plan) and where people are seen; no chairs."""

    def __init__(self, rng, cfg, room: RealRoom, duration: float, objects=(), composite=None):
        super().__init__(rng, cfg, room.space, duration, [], objects)
        self.room, self.cc = room, composite
        vis = room.visibility
        # how often a person at each lattice cell would be seen (the share of the fused frames)
        self.seen_share = (vis.coverage >= composite.vis_min_coverage).mean(axis=1) if vis.coverage.size else \
            np.zeros(0)
        self.targets = np.flatnonzero(self.seen_share > 0)
        if not len(self.targets):
            raise D2SlamError("no free floor of the recording is ever in view: no person could be seen there")
        self.exits = self._exit_cells()
        self.route_smooth = composite.route_smooth_m
        s = room.space  # the floor's connected parts: a person draws targets and exits on their own part
        _, self.part = cv2.connectedComponents(s.standable.astype(np.uint8), connectivity=8)
        self.target_part = self._part_of(vis.xy[self.targets])
        self.exit_part = self._part_of(self.exits)
        self._moves: dict = {}
        self._within = None  # the part the next draw keeps to (None: the current person's)

    def _part_of(self, xy) -> np.ndarray:
        ix, iy, inside = self.room.space.cells(np.asarray(xy, float).reshape(-1, 2))
        return np.where(inside, self.part[ix, iy], 0)

    def _here(self) -> int | None:
        """The floor part the draws keep to: ``_within``, else that of where the current person's plan ends (None
        before it starts)."""
        if self._within is not None:
            return self._within
        p = self._current
        if p is None or not p.timeline.legs:
            return None
        return int(self._part_of(p.timeline.end_state().xy)[0])

    def plan(self, people, moves=None) -> None:
        self._moves = dict(moves or {})
        super().plan(people, moves)

    def _start(self, tl, side: float = 0.0) -> None:
        """The first leg: standing at a free point in view or out of view (``p_start_exit``); whoever moves an object
        starts on the floor part where it rests."""
        c = self.cfg
        obj = self._moves.get(self._current.pid) if self._current is not None else None
        self._within = int(self._part_of(obj.pose(0.0)[:2, 3])[0]) if obj is not None else None
        try:
            for _ in range(4 * c.tries):
                out = self.rng.random() < c.p_start_exit
                xy = self.exit_point() if out else self.in_view_point()
                st = ActorState(np.asarray(xy, float), float(self.rng.uniform(-np.pi, np.pi)), 0.0, 0.0, 0.0, None,
                                0.0)
                leg = self._stand(st, -c.check_dt, c.check_dt)
                if self._static_free(st.xy[None]) and self._clear_of_people([leg], strict=True):
                    tl.add(leg)
                    return
        finally:
            self._within = None
        raise D2SlamError("no free floor in view to start a person on")

    def _exit_cells(self) -> np.ndarray:
        """Standable cells out of view within ``exit_reach_m`` of a target and connected to it (floor points); the
        targets are left with those connected to an exit."""
        s = self.room.space
        n, lab = cv2.connectedComponents(s.standable.astype(np.uint8), connectivity=8)
        ti, tj, _ = s.cells(self.room.visibility.xy[self.targets])
        comps = set(lab[ti, tj].tolist())
        ix, iy = np.nonzero(s.standable & s.out_of_view & np.isin(lab, list(comps)))
        xy = s.centre(ix, iy)
        tx = self.room.visibility.xy[self.targets]
        near = np.min(np.linalg.norm(xy[:, None] - tx[None], axis=2), axis=1) <= self.cc.exit_reach_m
        if not near.any():
            raise D2SlamError(f"no standable floor out of view within {self.cc.exit_reach_m:g} m of where people are "
                              "seen: they could not walk in and out of view")
        return xy[near]

    def _now(self) -> float:
        p = self._current
        return p.timeline.t_end if p is not None and p.timeline.legs else 0.0

    def in_view_point(self) -> np.ndarray:
        """A point in view, drawn by how often it is seen, on the current person's floor part when that holds any."""
        vis = self.room.visibility
        here = self._here()
        keep = self.target_part == here if here is not None else np.ones(len(self.targets), bool)
        keep = keep if keep.any() else np.ones(len(self.targets), bool)
        w = np.where(keep, self.seen_share[self.targets], 0.0) ** self.cc.vis_weight_power
        k = self.targets[int(self.rng.choice(len(self.targets), p=w / w.sum()))]
        return vis.xy[k] + self.rng.uniform(-0.5, 0.5, 2) * self.cc.vis_cell_m

    def exit_point(self) -> np.ndarray:
        """A point out of view on the current person's floor part; where that part has none (the legroom between
        desks), a point in view."""
        here = self._here()
        cand = np.flatnonzero(self.exit_part == here) if here is not None else np.arange(len(self.exits))
        if not len(cand):
            return self.in_view_point()
        return self.exits[int(cand[self.rng.integers(len(cand))])].copy()

    def move_target(self, side: float) -> np.ndarray:
        return self.in_view_point()

    def _route_points(self, a, b, ignore=()) -> np.ndarray | None:
        pts = self.room.space.path(a, b)
        if pts is None or len(pts) < 2 or np.linalg.norm(pts[-1] - pts[0]) < 1e-6:
            return None
        # the walked route is the smoothed one
        return pts if self.room.space.passes(Route(pts, smooth=self.route_smooth).xy) else None

    def _in_view(self, xy: np.ndarray) -> bool:
        vis = self.room.visibility
        d = np.linalg.norm(vis.xy[self.targets] - np.asarray(xy)[None], axis=1)
        return bool(d.min() <= self.cc.vis_cell_m)

    def _go(self, tl, legs, holding=None) -> bool:
        """As the planner's, and a carried box keeps to passable cells too (``FreeSpace.passes``)."""
        if legs is not None and any(leg.hold == "box" for leg in legs):
            off = np.asarray(self.cfg.holding.box_offset[:2], float)
            for leg in legs:
                if leg.hold != "box":
                    continue
                for t in np.arange(leg.t0, leg.t1 + self.cfg.check_dt, self.cfg.check_dt):
                    st = leg.state(min(t, leg.t1), self.cfg)
                    c, s = np.cos(st.heading - np.pi / 2), np.sin(st.heading - np.pi / 2)
                    if not self.room.space.passes(st.xy + np.array([c * off[0] - s * off[1], s * off[0] + c * off[1]])):
                        return False
        return super()._go(tl, legs, holding)


def box_rest(rng, planner: RoomPlanner, cfg) -> tuple[np.ndarray, float]:
    """(xy, heading) where the carried box rests at the start: a point in view where the box, the carrier standing
    behind it to take it (``box_offset`` behind, along the box's heading) and the step up to it (``take_approach_m``
    further) are on standable cells (the first of 16 headings from a random one that allows it)."""
    a = cfg.actors
    reach = a.holding.box_offset[1] + a.holding.take_approach_m  # the carrier stands behind it, and steps up from further back
    for _ in range(a.tries * 5):
        xy = planner.in_view_point()
        for h in rng.uniform(-np.pi, np.pi) + np.arange(16) * (np.pi / 8):  # every direction the room allows
            if planner.room.space.free(xy - np.linspace(0.0, reach, 6)[:, None] * unit(float(h))):
                return xy, float(h)
    raise D2SlamError("no free floor in view holds the carried box and its carrier")


def composite_groundtruth(scene) -> tuple[np.ndarray, np.ndarray]:
    """(timestamps, (N, 7) tx ty tz qx qy qz qw): the recording's own ground truth samples over the frames plus
    ``gt_margin``, in its own world (the composite's camera is the recording's)."""
    rec = scene.recording
    a = scene.t0 + scene.t_rel[0] - scene.cfg.gt_margin
    b = scene.t0 + scene.t_rel[-1] + scene.cfg.gt_margin
    sel = (rec.gt_times >= a) & (rec.gt_times <= b)
    return rec.gt_times[sel], pose_rows(rec.gt_poses[sel])
