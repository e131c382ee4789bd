"""People and the objects they move: timelines planned per seed in the office's floor plane.

A person follows a list of *legs*: ``walk`` (along a smoothed route, accelerating and slowing down), ``turn`` (in
place, with small steps), ``stand``, ``sit_down``, ``sit`` and ``stand_up`` (on a desk chair, which shifts a little
as the person sits down and gets up), and, holding an object, ``walk`` / ``turn`` / ``stand`` with a box in the
arms (picked up and put down on the floor) or a chair pushed in front. :class:`Planner` draws the legs:

- ``walker``: the people of the TUM fr3 walking sequences: they walk through the office to points in view and out
  of it at the sides, stand for a moment, sit down on a free desk chair and get up again;
- ``carrier``: walks to a box on the floor, carries it across the view, puts it down, and again;
- ``pusher``: walks to a chair, pushes it across the view, leaves it, and again.

Routes avoid the furniture (rectangles), the chairs and the boxes (discs), and the people already planned (the
planner tries other targets, then waits). Every draw comes from the planner's generator, so the plan is a
deterministic function of the seed. Floor plane: world x (right) and y (away from the camera's home), metres;
headings from +x (``d2slam.synth.rigid.yaw_pose``).
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field

import numpy as np

from d2slam.synth import bodies
from d2slam.synth.config import ActorsConfig, BodyConfig
from d2slam.synth.rigid import rot_z, tf, yaw_pose


def smoothstep(u):
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def wrap(a: float) -> float:
    """Angle in [-pi, pi)."""
    return float((a + np.pi) % (2 * np.pi) - np.pi)


def unit(h: float) -> np.ndarray:
    return np.array([np.cos(h), np.sin(h)])


# --------------------------------------------------------------------------------------------------
# legs and states
# --------------------------------------------------------------------------------------------------
@dataclass
class ActorState:
    """Where a person is and what the body does at one instant."""

    xy: np.ndarray
    heading: float
    dist: float  # distance walked so far (m): the gait phase
    gait: float  # gait amplitude factor: 0 standing still, 1 walking at the leg's speed
    sit: float  # 0 standing, 1 seated
    hold: str | None  # "box" | "push" | None
    hold_w: float  # 0 arms free, 1 holding


@dataclass
class Leg:
    kind: str  # "walk" | "turn" | "stand" | "sit_down" | "sit" | "stand_up"
    t0: float
    t1: float
    d0: float  # distance walked at t0
    xy: np.ndarray  # start position (walk) or position
    h0: float = 0.0
    h1: float = 0.0  # turn: final heading (unwrapped near h0)
    hold: str | None = None
    hold_w: tuple[float, float] = (0.0, 0.0)  # holding weight at t0 and t1 (ramps on pick-up and put-down)
    route: "Route | None" = None
    speed: float = 0.0
    ramp: float = 0.0
    chair: "Chair | None" = None
    approach: float = 0.0  # sit legs: distance (m) of the standing position in front of the seat

    def distance(self, tau: float) -> tuple[float, float]:
        """Walk legs: (distance along the route, speed) tau seconds after t0 (trapezoidal speed profile)."""
        L, v, r = self.route.length, self.speed, self.ramp
        T = self.t1 - self.t0
        tau = min(max(tau, 0.0), T)
        acc = v / r
        if tau < r:
            return 0.5 * acc * tau * tau, acc * tau
        if tau > T - r:
            return L - 0.5 * acc * (T - tau) ** 2, acc * (T - tau)
        return v * (tau - r / 2), v

    def state(self, t: float, cfg: ActorsConfig) -> ActorState:
        T = max(self.t1 - self.t0, 1e-9)
        u = float(np.clip((t - self.t0) / T, 0.0, 1.0))
        w = self.hold_w[0] + (self.hold_w[1] - self.hold_w[0]) * float(smoothstep(u))
        if self.kind == "walk":
            s, v = self.distance(t - self.t0)
            xy, h = self.route.at(s)
            return ActorState(xy, h, self.d0 + s, v / self.speed if self.speed > 0 else 0.0, 0.0, self.hold, w)
        if self.kind == "turn":
            e = float(smoothstep(u))
            h = self.h0 + (self.h1 - self.h0) * e
            return ActorState(self.xy, h, self.d0 + cfg.turn_step_m * abs(self.h1 - self.h0) * e,
                              cfg.turn_gait * float(np.sin(np.pi * u)), 0.0, self.hold, w)
        if self.kind in ("sit_down", "sit", "stand_up"):
            sit = {"sit_down": float(smoothstep(u)), "sit": 1.0, "stand_up": 1.0 - float(smoothstep(u))}[self.kind]
            seat, h = self.chair.seat(t, cfg)
            xy = seat + (1.0 - sit) * self.approach * unit(h)
            return ActorState(xy, h, self.d0, 0.0, sit, None, 0.0)
        return ActorState(self.xy, self.h0, self.d0, 0.0, 0.0, self.hold, w)  # stand

    def end(self, cfg: ActorsConfig) -> ActorState:
        return self.state(self.t1, cfg)


class Route:
    """A polyline in the floor plane with rounded corners (resampled every ``step`` m and smoothed by a Gaussian of
    ``smooth`` m, the ends kept in place), parametrised by arc length."""

    def __init__(self, points: np.ndarray, smooth: float = 0.4, step: float = 0.02):
        P = np.asarray(points, float)
        seg = np.linalg.norm(np.diff(P, axis=0), axis=1)
        arc = np.concatenate([[0.0], np.cumsum(seg)])
        n = max(int(np.ceil(arc[-1] / step)), 1)
        s = np.linspace(0.0, arc[-1], n + 1)
        xy = np.stack([np.interp(s, arc, P[:, 0]), np.interp(s, arc, P[:, 1])], axis=1)
        if len(P) > 2 and smooth > 0:
            from scipy.ndimage import gaussian_filter1d

            sm = gaussian_filter1d(xy, smooth / step, axis=0, mode="nearest")
            w = (s / s[-1])[:, None]
            xy = sm + (1.0 - w) * (P[0] - sm[0]) + w * (P[-1] - sm[-1])
            seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
            s = np.concatenate([[0.0], np.cumsum(seg)])
        self.xy, self.arc, self.length = xy, s, float(s[-1])
        d = np.gradient(self.xy, axis=0) if len(self.xy) > 1 else np.array([[1.0, 0.0]])
        self.heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))

    def at(self, s: float) -> tuple[np.ndarray, float]:
        xy = np.array([np.interp(s, self.arc, self.xy[:, 0]), np.interp(s, self.arc, self.xy[:, 1])])
        return xy, float(np.interp(s, self.arc, self.heading))


class Timeline:
    """A person's legs, contiguous in time; before the first leg and after the last the end states hold."""

    def __init__(self, cfg: ActorsConfig):
        self.cfg = cfg
        self.legs: list[Leg] = []
        self._starts: list[float] = []

    def add(self, leg: Leg) -> None:
        self.legs.append(leg)
        self._starts.append(leg.t0)

    @property
    def t_end(self) -> float:
        return self.legs[-1].t1 if self.legs else 0.0

    def end_state(self) -> ActorState:
        return self.legs[-1].end(self.cfg)

    def state(self, t: float) -> ActorState:
        k = max(bisect.bisect_right(self._starts, t) - 1, 0)
        return self.legs[k].state(t, self.cfg)

    def positions(self, times: np.ndarray) -> np.ndarray:
        return np.array([self.state(float(t)).xy for t in times]).reshape(-1, 2)


# --------------------------------------------------------------------------------------------------
# objects people move
# --------------------------------------------------------------------------------------------------
def chair_parts(T: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Office chair in frame T (origin on the floor under the seat, +y = the sitter's forward)."""
    return [(T @ tf(t=[0, 0, 0.46]), np.array([0.24, 0.24, 0.035])),
            (T @ tf(t=[0, -0.22, 0.76]), np.array([0.23, 0.03, 0.26])),
            (T @ tf(t=[0, 0, 0.25]), np.array([0.03, 0.03, 0.2])),
            (T @ tf(t=[0, 0, 0.04]), np.array([0.28, 0.28, 0.03]))]


@dataclass
class Chair:
    """A desk chair at ``xy`` facing ``heading`` (the sitter's forward) that shifts a little each time somebody sits
    down on it or gets up: ``shifts`` are ``(t0, t1, dxy, dheading)`` applied smoothly in [t0, t1]."""

    oid: int
    name: str
    xy: np.ndarray
    heading: float
    tex: int
    kind: str = "chair"
    shifts: list = field(default_factory=list)
    busy: list = field(default_factory=list)  # (t0, t1) a person is on it or about to be
    moved_by: list = field(default_factory=list)

    def pose2(self, t: float) -> tuple[np.ndarray, float]:
        xy, h = self.xy.copy(), self.heading
        for t0, t1, dxy, dh in self.shifts:
            if t <= t0:
                break
            e = float(smoothstep((t - t0) / max(t1 - t0, 1e-9)))
            xy, h = xy + e * dxy, h + e * dh
        return xy, h

    def pose(self, t: float) -> np.ndarray:
        xy, h = self.pose2(t)
        return yaw_pose(xy, h)

    def seat(self, t: float, cfg: ActorsConfig) -> tuple[np.ndarray, float]:
        """Where a seated person's root is (on the floor under the pelvis) and their heading."""
        xy, h = self.pose2(t)
        return xy - cfg.sitting.seat_offset_m * unit(h), h

    def parts(self, t: float) -> list[tuple[np.ndarray, np.ndarray, int]]:
        return [(T, half, self.tex) for T, half in chair_parts(self.pose(t))]

    @property
    def intervals(self) -> list[tuple[float, float]]:
        return [(a, b) for a, b, _, _ in self.shifts]

    def moving(self, t: float) -> bool:
        return any(a <= t <= b for a, b in self.intervals)

    def free(self, t0: float, t1: float) -> bool:
        return all(t1 < a or t0 > b for a, b in self.busy)


BOX_HALF = np.array([0.22, 0.16, 0.15])


@dataclass
class Hold:
    """One pick-up / carry / put-down of a held object: lifted (or grabbed) over [t0, t1], held by ``person`` until
    t2, put down (or released) over [t2, t3]."""

    t0: float
    t1: float
    t2: float
    t3: float
    person: "Person"


@dataclass
class HeldObject:
    """A box carried in the arms (``kind="box"``) or a chair pushed in front (``kind="chair"``): at rest at
    ``rest`` until a person takes it, then following that person at ``offset`` (their root frame), and at rest
    where they leave it."""

    oid: int
    name: str
    kind: str
    tex: int
    rest: np.ndarray  # 4x4 initial pose
    offset: np.ndarray  # 4x4 pose in the holder's root frame
    ground: float  # height of the pose's origin at rest (box: its half height; chair: 0)
    holds: list = field(default_factory=list)
    moved_by: list = field(default_factory=list)

    def _held(self, h: Hold, t: float) -> np.ndarray:
        T = h.person.root(t) @ self.offset
        a = float(smoothstep((t - h.t0) / max(h.t1 - h.t0, 1e-9))) if t < h.t1 else (
            float(smoothstep((h.t3 - t) / max(h.t3 - h.t2, 1e-9))) if t > h.t2 else 1.0)
        T[2, 3] = self.ground + a * (T[2, 3] - self.ground)
        return T

    def pose(self, t: float) -> np.ndarray:
        T = self.rest
        for h in self.holds:
            if t < h.t0:
                return T
            if t <= h.t3:
                return self._held(h, t)
            T = self._held(h, h.t3)
        return T

    def xy(self, t: float) -> np.ndarray:
        return self.pose(t)[:2, 3]

    def parts(self, t: float) -> list[tuple[np.ndarray, np.ndarray, int]]:
        T = self.pose(t)
        if self.kind == "box":
            return [(T, BOX_HALF, self.tex)]
        return [(Tp, half, self.tex) for Tp, half in chair_parts(T)]

    @property
    def intervals(self) -> list[tuple[float, float]]:
        return [(h.t0, h.t3) for h in self.holds]

    def moving(self, t: float) -> bool:
        return any(a <= t <= b for a, b in self.intervals)


# --------------------------------------------------------------------------------------------------
# people
# --------------------------------------------------------------------------------------------------
_BODIES: dict = {}


def body_model(shape: tuple, cfg: BodyConfig) -> bodies.BodyModel:
    """The ANNY body of a shape (six controls), built once per process."""
    key = (tuple(np.round(shape, 12)), cfg)
    if key not in _BODIES:
        _BODIES[key] = bodies.BodyModel(np.asarray(shape, float), cfg)
    return _BODIES[key]


def _blend(a: dict, b: dict, w: float) -> dict:
    if w <= 0.0:
        return a
    if w >= 1.0:
        return b
    zero = np.zeros(3)
    return {k: (1.0 - w) * a.get(k, zero) + w * b.get(k, zero) for k in set(a) | set(b)}


@dataclass
class Person:
    """An articulated MakeHuman body (``d2slam.synth.bodies``) following a :class:`Timeline`.

    ``role``: ``walk`` (the fr3 people), ``carry``, ``push`` or ``sit`` (seated throughout); ``shape``: the six ANNY
    shape controls; ``clothes``; ``tex``: the garments' textures; ``params``: gait style factor ``style``, stride ``stride`` (m), phases ``ph`` and
    periods ``f`` of the seated movements."""

    pid: int
    name: str
    role: str
    shape: tuple
    clothes: bodies.Clothes
    params: dict
    body_cfg: BodyConfig
    timeline: Timeline
    tex: np.ndarray  # (5,) texture index of each garment (bodies.PARTS)

    def state(self, t: float) -> ActorState:
        return self.timeline.state(t)

    def root(self, t: float) -> np.ndarray:
        """4x4 pose of the body root (on the floor under the pelvis; x right, y forward, z up)."""
        s = self.state(t)
        return yaw_pose(s.xy, s.heading)

    def mesh(self, t: float):
        """The posed body at time t (s): world vertices (R, 3), triangles, shading (R, 3) and per vertex its texture
        coordinates in [0, 1]^2 and texture index (``tex`` of its garment), for ``WorldRenderer``."""
        p, cfg = self.params, self.body_cfg
        s = self.state(t)
        body = body_model(self.shape, cfg)
        amp = bodies.amplitudes(cfg, p["style"] * s.gait)
        phase = 2 * np.pi * s.dist / p["stride"]
        rot = bodies.gait(phase, amp, t, None)
        if s.hold is not None and s.hold_w > 0.0:
            rot = _blend(rot, bodies.gait(phase, amp, t, s.hold), s.hold_w)
        if s.sit > 0.0:
            rot = _blend(rot, bodies.sitting(t, amp, p["ph"], p["f"]), s.sit)
        V = body.pose(rot)
        # the ANNY body faces -y; the root's forward is +y; seated, the body sits back on the seat
        T = yaw_pose(s.xy, s.heading) @ tf(rot_z(np.pi)) @ tf(t=[0.0, cfg.motion.seat_back * s.sit, 0.0])
        Vw = V @ T[:3, :3].T + T[:3, 3]
        light = np.asarray(cfg.light, float)
        shading = bodies.shade(np.ones_like(Vw), bodies.vertex_normals(Vw, body.triangles, body.incidence),
                               light / np.linalg.norm(light), cfg.ambient)
        lay = body.layout(self.clothes.long_sleeves)
        uv = lay.uv / np.array([1.0 + bodies.SEAM_PAD, 1.0])
        return Vw[lay.src], lay.triangles, shading[lay.src], (uv, self.tex[lay.part])


# --------------------------------------------------------------------------------------------------
# the floor plan and the planner
# --------------------------------------------------------------------------------------------------
@dataclass
class FloorPlan:
    """Where people can stand: inside ``bounds`` (xmin, xmax, ymin, ymax), outside the furniture rectangles
    ``rects`` (each (xmin, xmax, ymin, ymax)) grown by ``clearance``."""

    bounds: tuple[float, float, float, float]
    rects: list = field(default_factory=list)
    clearance: float = 0.2

    def free(self, P: np.ndarray) -> bool:
        P = np.atleast_2d(P)
        x0, x1, y0, y1 = self.bounds
        c = self.clearance
        ok = (P[:, 0] > x0 + c) & (P[:, 0] < x1 - c) & (P[:, 1] > y0 + c) & (P[:, 1] < y1 - c)
        for a, b, lo, hi in self.rects:
            ok &= ~((P[:, 0] > a - c) & (P[:, 0] < b + c) & (P[:, 1] > lo - c) & (P[:, 1] < hi + c))
        return bool(ok.all())


class Planner:
    """Draws the people's timelines of one scene (see the module docstring). ``duration``: seconds to plan (the
    sequence plus a margin); ``chairs``: the desk chairs people may sit on; ``objects``: held objects (obstacles
    for everybody, moved by their carrier or pusher)."""

    def __init__(self, rng: np.random.Generator, cfg: ActorsConfig, floor: FloorPlan, duration: float,
                 chairs: list[Chair], objects: list[HeldObject] = ()):
        self.rng, self.cfg, self.floor, self.duration = rng, cfg, floor, float(duration)
        self.chairs, self.objects = list(chairs), list(objects)
        self.people: list[Person] = []  # being planned (each avoids what the others will do)
        self._current: Person | None = None  # whose action is being planned
        self._relax = 1.0  # factor on the gaps: below 1 for a person boxed in for a while (see plan)
        self._objects_block = True
        self._times = np.arange(0.0, self.duration + cfg.check_dt, cfg.check_dt)
        self.route_smooth = 0.4  # the routes' corners are rounded by a Gaussian of this (m; ``Route``)

    # ---- sampling ----
    def in_view_point(self) -> np.ndarray:
        c = self.cfg
        y = self.rng.uniform(*c.view_y)
        return np.array([self.rng.uniform(-c.view_slope, c.view_slope) * y, y])

    def exit_point(self) -> np.ndarray:
        c = self.cfg
        return np.array([self.rng.choice([-1.0, 1.0]) * self.rng.uniform(*c.exit_x), self.rng.uniform(*c.exit_y)])

    # ---- collision tests ----
    def _static_free(self, P: np.ndarray, ignore=()) -> bool:
        if not self.floor.free(P):
            return False
        c = self.cfg
        for ch in self.chairs:
            if ch in ignore:
                continue
            if np.min(np.linalg.norm(P - ch.xy, axis=1)) < c.chair_radius:
                return False
        return True

    def _route_points(self, a: np.ndarray, b: np.ndarray, ignore=()) -> np.ndarray | None:
        """A polyline from a to b that keeps clear of the furniture and chairs: straight, else via one detour."""
        d = b - a
        L = float(np.linalg.norm(d))
        if L < 1e-6:
            return None
        n = np.array([-d[1], d[0]]) / L

        near = tuple(ch for ch in self.chairs if np.linalg.norm(a - ch.xy) < self.cfg.chair_radius + self.cfg.squeeze_m)
        # a chair the route starts next to (a person who just got up from it) does not block it; failing all else, a
        # person squeezes past the chairs near where they stand (pushing one aside a little)
        for skip in (tuple(ignore) + tuple(ch for ch in near if np.linalg.norm(a - ch.xy) < self.cfg.chair_radius),
                     tuple(ignore) + near):
            def ok(pts):
                return self._static_free(Route(pts, smooth=0.0).xy[1:], skip)

            if ok(np.stack([a, b])):
                return np.stack([a, b])
            for k in self.cfg.detours:
                for sign in (1.0, -1.0):
                    pts = np.stack([a, a + 0.5 * d + sign * k * n, b])
                    if ok(pts):
                        return pts
            for y in sorted(self.cfg.lanes, key=lambda y: abs(y - 0.5 * (a[1] + b[1]))):  # across the room
                pts = np.array([a, [a[0], y], [b[0], y], b])
                if ok(pts):
                    return pts
        return None

    def _clear_of_people(self, legs: list[Leg], holding: HeldObject | None = None, strict: bool = False) -> bool:
        """The candidate legs keep ``person_gap`` from everybody else and ``object_gap`` from held objects (a person
        who starts closer than that only has to get no closer)."""
        if not legs:
            return True
        # until the others' plans end: after its legs, the person stands where they end until its next action
        t1 = max([legs[-1].t1] + [o.timeline.t_end for o in self.people if o is not self._current and o.timeline.legs])
        times = self._times[(self._times >= legs[0].t0) & (self._times <= min(t1, self.duration))]
        if len(times) == 0:
            return True
        tl = Timeline(self.cfg)
        for leg in legs:
            tl.add(leg)
        P = tl.positions(times)
        for other in self.people:  # where their plans take them, standing there after their plans end so far
            if other is not self._current and other.timeline.legs and not self._apart(
                    P, other.timeline.positions(times), self.cfg.person_gap * self._relax, strict):
                return False
        for o in self.objects if self._objects_block else ():
            if o is not holding and not self._apart(P, np.array([o.xy(float(t)) for t in times]),
                                                    self.cfg.object_gap * self._relax, strict):
                return False
        return True

    @staticmethod
    def _apart(P: np.ndarray, Q: np.ndarray, gap: float, strict: bool = False) -> bool:
        """At least ``gap`` apart throughout, or, starting closer (unless ``strict``), never closer than at the
        start."""
        d = np.linalg.norm(P - Q, axis=1)
        return bool(np.min(d) >= (gap if strict else min(gap, d[0] - 1e-3)))

    # ---- legs ----
    def _turn(self, s: ActorState, t: float, heading: float, hold=None, w=0.0) -> Leg | None:
        dh = wrap(heading - s.heading)
        if abs(dh) < 1e-3:
            return None
        return Leg("turn", t, t + abs(dh) / self.cfg.turn_rate, s.dist, s.xy.copy(), s.heading, s.heading + dh,
                   hold=hold, hold_w=(w, w))

    def _walk(self, s: ActorState, t: float, target: np.ndarray, ignore=(), hold=None) -> list[Leg] | None:
        """Turn towards the route's first direction, then walk it; None when no clear route exists."""
        pts = self._route_points(s.xy, target, ignore)
        if pts is None:
            return None
        route = Route(pts, smooth=self.route_smooth)
        c = self.cfg
        v = float(self.rng.uniform(*c.walk_speed)) * (c.hold_speed if hold else 1.0)
        ramp = min(c.ramp_s, route.length / v)
        legs = []
        w = 1.0 if hold else 0.0
        turn = self._turn(s, t, float(route.heading[0]), hold, w)
        if turn is not None:
            legs.append(turn)
            t = turn.t1
        d0 = legs[-1].end(c).dist if legs else s.dist
        legs.append(Leg("walk", t, t + route.length / v + ramp, d0, route.xy[0].copy(), hold=hold, hold_w=(w, w),
                        route=route, speed=v, ramp=ramp))
        return legs

    def _stand(self, s: ActorState, t: float, seconds: float, hold=None, w=(0.0, 0.0)) -> Leg:
        return Leg("stand", t, t + seconds, s.dist, s.xy.copy(), s.heading, s.heading, hold=hold, hold_w=w)

    # ---- actions: lists of legs from a state, or None when they do not fit ----
    def _go(self, tl: Timeline, legs: list[Leg] | None, holding: HeldObject | None = None) -> bool:
        if legs is None or not self._clear_of_people(legs, holding):
            return False
        for leg in legs:
            tl.add(leg)
        return True

    def _wait(self, tl: Timeline, seconds: float, hold=None) -> None:
        """Stand still; a person who would be in somebody's way walks somewhere free instead, or steps away from
        the nearest person."""
        s = tl.end_state()
        w = 1.0 if hold else 0.0
        leg = self._stand(s, tl.t_end, seconds, hold, (w, w))
        if hold is None and not self._clear_of_people([leg]):
            if self._try_walk(tl, self.in_view_point) or self._try_walk(tl, self._step_away(s, tl.t_end)):
                return
        tl.add(leg)

    def _step_away(self, s: ActorState, t: float):
        """Targets a step (0.5-1.2 m) away from the nearest other person, in a direction within 60 degrees of
        straight away."""
        others = [o.timeline.state(t).xy for o in self.people if o is not self._current and o.timeline.legs]
        away = s.xy - min(others, key=lambda q: np.linalg.norm(q - s.xy)) if others else unit(s.heading)
        h = float(np.arctan2(away[1], away[0]))
        return lambda: s.xy + self.rng.uniform(0.5, 1.2) * unit(h + self.rng.uniform(-1.0, 1.0))

    def _sit_legs(self, s: ActorState, t: float, chair: Chair):
        """Walk beside the chair, step in front of it, turn to its heading, sit down, sit, get up. Returns the legs,
        the point beside the chair and the chair's shifts, or None."""
        c = self.cfg
        seat, h = chair.seat(t, c)
        front = seat + c.sitting.sit_approach_m * unit(h)
        side = np.array([-np.sin(h), np.cos(h)])
        side = side if (s.xy - front) @ side > 0 else -side
        beside = front + c.sitting.sit_side_m * side
        legs = self._walk(s, t, beside)
        if legs is None:
            return None
        step = self._walk(legs[-1].end(c), legs[-1].t1, front, ignore=(chair,))
        if step is None:
            return None
        legs += step
        turn = self._turn(legs[-1].end(c), legs[-1].t1, h)
        if turn is not None:
            legs.append(turn)
        ta = legs[-1].t1
        down, sit, up = (self.rng.uniform(*c.sitting.sit_down_s), self.rng.uniform(*c.sitting.sit_s),
                         self.rng.uniform(*c.sitting.sit_down_s))
        legs += self._seated(legs[-1].end(c).dist, chair, ta, down, sit, up)
        return legs, beside, self._shifts(h, ((ta, ta + down, c.sitting.sit_shift_m),
                                              (ta + down + sit, ta + down + sit + up, c.sitting.stand_shift_m)))

    def _seated(self, dist: float, chair: Chair, ta: float, down: float, sit: float, up: float) -> list[Leg]:
        c = self.cfg
        tb, tc, td = ta + down, ta + down + sit, ta + down + sit + up
        return ([Leg("sit_down", ta, tb, dist, chair.xy, chair=chair, approach=c.sitting.sit_approach_m)] if down > 0
                else []) + [Leg("sit", tb, tc, dist, chair.xy, chair=chair),
                            Leg("stand_up", tc, td, dist, chair.xy, chair=chair, approach=c.sitting.sit_approach_m)]

    def _shifts(self, h: float, spans) -> list:
        """The chair's small shifts while somebody sits down or gets up: pushed back, a little sideways, turned."""
        c = self.cfg
        out = []
        for a, b, m in spans:
            back = -self.rng.uniform(*m) * unit(h)
            out.append((a, b, back + self.rng.uniform(-1, 1, 2) * c.sitting.shift_jitter_m,
                        float(self.rng.uniform(-c.sitting.shift_yaw, c.sitting.shift_yaw))))
        return out

    def _occupy(self, chair: Chair, pid: int, t0: float, t1: float, shifts: list) -> None:
        chair.busy.append((t0, t1))
        chair.shifts = sorted(chair.shifts + shifts, key=lambda x: x[0])
        if pid not in chair.moved_by:
            chair.moved_by.append(pid)

    def _try_sit(self, tl: Timeline, pid: int) -> bool:
        s, t = tl.end_state(), tl.t_end
        for k in self.rng.permutation(len(self.chairs)):
            chair = self.chairs[int(k)]
            if not chair.free(t, t + 1.0):
                continue
            out = self._sit_legs(s, t, chair)
            if out is None:
                continue
            legs, beside, shifts = out
            if not chair.free(t, legs[-1].t1) or not self._go(tl, legs):
                continue
            self._occupy(chair, pid, t, legs[-1].t1, shifts)
            # back beside the chair before walking on (routes keep clear of chairs)
            self._go(tl, self._walk(tl.end_state(), tl.t_end, beside, ignore=(chair,)))
            return True
        return False

    def _start_seated(self, tl: Timeline, pid: int) -> bool:
        """Seated on a free chair when the sequence starts; gets up after a while."""
        c = self.cfg
        for k in self.rng.permutation(len(self.chairs)):
            chair = self.chairs[int(k)]
            if chair.busy:
                continue
            sit, up = self.rng.uniform(*c.sitting.sit_s), self.rng.uniform(*c.sitting.sit_down_s)
            legs = self._seated(0.0, chair, -c.check_dt, 0.0, sit + c.check_dt, up)
            if not self._go(tl, legs):
                continue
            self._occupy(chair, pid, -c.check_dt, legs[-1].t1,
                         self._shifts(chair.heading, ((legs[-1].t0, legs[-1].t1, c.sitting.stand_shift_m),)))
            h = chair.heading
            side = np.array([-np.sin(h), np.cos(h)]) * self.rng.choice([-1.0, 1.0])
            front = chair.seat(legs[-1].t1, c)[0] + c.sitting.sit_approach_m * unit(h)
            self._go(tl, self._walk(tl.end_state(), tl.t_end, front + c.sitting.sit_side_m * side, ignore=(chair,)))
            return True
        return False

    def _try_walk(self, tl: Timeline, target_fn, hold=None, holding=None) -> bool:
        for _ in range(self.cfg.tries):
            legs = self._walk(tl.end_state(), tl.t_end, target_fn(), hold=hold)
            if self._go(tl, legs, holding):
                return True
        return False

    def _start(self, tl: Timeline, side: float = 0.0) -> None:
        """The first leg: standing at a free point in view or at an exit (drawn; ``side`` +-1: on that side of the
        camera's axis)."""
        c = self.cfg
        for k in range(2 * c.tries):
            xy = self.exit_point() if self.rng.random() < c.p_start_exit else self.in_view_point()
            xy[0] = side * abs(xy[0]) if side and k < c.tries else xy[0]  # on that side if there is room
            s = ActorState(np.asarray(xy, float), float(self.rng.uniform(-np.pi, np.pi)), 0.0, 0.0, 0.0, None, 0.0)
            leg = self._stand(s, -c.check_dt, c.check_dt)
            if self._static_free(s.xy[None]) and self._clear_of_people([leg], strict=True):
                tl.add(leg)
                return
        raise RuntimeError("no free starting point for a person")  # the floor plan leaves room: a bug

    def _in_view(self, xy: np.ndarray) -> bool:
        return abs(xy[0]) <= self.cfg.view_slope * xy[1] + self.cfg.view_margin_m

    def plan(self, people: list[Person], moves: dict[int, HeldObject] | None = None) -> None:
        """Plan every person's timeline: ``moves[pid]`` is the object that person carries or pushes (a mover), the
        others are fr3 walkers. The plans grow one action at a time, always for the person whose plan ends first, so
        that every action keeps clear of what the others are known to do by then."""
        moves = moves or {}
        steps = {}
        for p in people:
            self.people.append(p)
            steps[p.pid] = self._mover(p, moves[p.pid]) if p.pid in moves else self._walker(p)
        active, stuck = list(people), dict.fromkeys(steps, 0)
        while active:
            p = min(active, key=lambda q: (q.timeline.t_end if q.timeline.legs else -np.inf, q.pid))
            self._current = p
            # a person whose last actions all failed squeezes past the others (bodies close, not overlapping), and
            # after twice as many past objects in the way too (pushing them aside a little)
            self._relax = self.cfg.relax_gap if stuck[p.pid] >= self.cfg.relax_after else 1.0
            self._objects_block = stuck[p.pid] < 2 * self.cfg.relax_after
            done = next(steps[p.pid], None)
            if done is None:
                active.remove(p)
            stuck[p.pid] = 0 if done else stuck[p.pid] + 1
        self._current, self._relax, self._objects_block = None, 1.0, True

    def _walker(self, person: Person):
        """The actions of one of the fr3 walking people (see the module docstring), one per step."""
        c, rng, tl = self.cfg, self.rng, person.timeline
        if not (rng.random() < c.p_start_seated and self._start_seated(tl, person.pid)):
            self._start(tl)
        yield True
        while tl.t_end < self.duration:
            u = rng.random()
            if not self._in_view(tl.end_state().xy):
                self._wait(tl, rng.uniform(*c.away_s))
                done = self._try_walk(tl, self.in_view_point)
            elif u < c.p_sit:
                done = self._try_sit(tl, person.pid)
            elif u < c.p_sit + c.p_exit:
                done = self._try_walk(tl, self.exit_point)
            elif u < c.p_sit + c.p_exit + c.p_stand:
                self._wait(tl, rng.uniform(*c.stand_s))
                done = True
            else:
                done = self._try_walk(tl, self.in_view_point)
            if not done:
                self._wait(tl, c.retry_wait_s)
            yield done

    def _mover(self, person: Person, obj: HeldObject):
        """The actions of the carrier of a box or the pusher of a chair (``obj.kind``): walk to it, take it, move it
        across the view, leave it, walk away or wait, and again; one per step."""
        c, rng, tl = self.cfg, self.rng, person.timeline
        hold = "box" if obj.kind == "box" else "push"
        obj.moved_by.append(person.pid)
        T = obj.pose(0.0)  # start on the side from which the object is taken
        self._start(tl, side=float(np.sign(T[0, 3] - T[0, 1]) or 1.0))
        yield True
        while tl.t_end < self.duration:
            if not self._take(tl, person, obj, hold):
                self._wait(tl, c.retry_wait_s)
                yield False
                continue
            yield True
            for _ in range(c.tries):
                if self._move(tl, obj, hold):
                    break
                self._wait(tl, c.retry_wait_s, hold)
                yield False
            yield True
            self._leave(tl, obj, hold)
            yield True
            if rng.random() < c.p_exit:
                if self._try_walk(tl, self.exit_point):
                    self._wait(tl, rng.uniform(*c.away_s))
            elif rng.random() < c.p_stand:
                self._wait(tl, rng.uniform(*c.stand_s))
            yield True

    def _take(self, tl: Timeline, person: Person, obj: HeldObject, hold: str) -> bool:
        """Walk to the object's back (along its facing direction), face it, take it: a new ``Hold`` opens."""
        c = self.cfg
        t = tl.t_end
        T = obj.pose(t)
        h = float(np.arctan2(T[1, 1], T[0, 1]))  # the object's +y axis: the holder's forward
        stand_at = T[:2, 3] - float(obj.offset[1, 3]) * unit(h)
        # the last step straight at it
        legs = self._walk(tl.end_state(), t, stand_at - c.holding.take_approach_m * unit(h))
        step = self._walk(legs[-1].end(c), legs[-1].t1, stand_at) if legs is not None else None
        legs = legs + step if step is not None else self._walk(tl.end_state(), t, stand_at)
        if legs is None:
            return False
        turn = self._turn(legs[-1].end(c), legs[-1].t1, h)
        legs += [turn] if turn is not None else []
        if not self._go(tl, legs, obj):
            return False
        t0 = tl.t_end
        tl.add(self._stand(tl.end_state(), t0, c.holding.take_s, hold, (0.0, 1.0)))
        obj.holds.append(Hold(t0, tl.t_end, np.inf, np.inf, person))
        return True

    def _move(self, tl: Timeline, obj: HeldObject, hold: str) -> bool:
        """Carry or push the held object across the view: to a point in view on the other side of the camera's
        axis, at least ``move_min_m`` away."""
        c = self.cfg
        s = tl.end_state()
        side = -1.0 if s.xy[0] > 0 else 1.0
        for _ in range(c.tries):
            target = self.move_target(side)
            d = target - s.xy
            if np.linalg.norm(d) < c.holding.move_min_m:
                continue
            if hold == "push" and abs(wrap(np.arctan2(d[1], d[0]) - s.heading)) > c.holding.push_max_turn:
                continue
            if self._go(tl, self._walk(s, tl.t_end, target, hold=hold), obj):
                return True
        return False

    def move_target(self, side: float) -> np.ndarray:
        """Where a held object is taken: a point in view on the ``side`` (+-1) of the camera's axis, y in
        ``HoldingConfig.move_y``, at least ``move_side`` of the way from the axis to the view's edge."""
        c = self.cfg
        y = self.rng.uniform(*c.holding.move_y)
        return np.array([side * self.rng.uniform(c.holding.move_side, 1.0) * c.view_slope * y, y])

    def _leave(self, tl: Timeline, obj: HeldObject, hold: str) -> None:
        """Put the object down (or let the chair go), then turn round and step away from it."""
        c = self.cfg
        obj.holds[-1].t2 = tl.t_end
        tl.add(self._stand(tl.end_state(), tl.t_end, c.holding.take_s, hold, (1.0, 0.0)))
        obj.holds[-1].t3 = tl.t_end
        s = tl.end_state()
        self._go(tl, self._walk(s, tl.t_end, s.xy - c.holding.leave_m * unit(s.heading)), obj)
