"""The synthetic world: an office-like room, articulated people, moved objects and fr3-like camera paths.

World frame: metres, Z up, the floor at Z = 0; the camera starts near (0, 0, 1.35) looking along +Y into the
room. Camera frame: the TUM / OpenCV optical frame (x right, y down, z forward); poses are 4x4
``T_world_camera`` of the optical centre. Everything is a deterministic function of ``(scenario, seed, frames)``
through separate seeded streams (room, people paths, camera, clock, each actor's textures), so the static twin shares the room, the camera
path and the clock of its dynamic sequence.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from d2slam.config import SynthConfig
from d2slam.errors import D2SlamError
from d2slam.synth import bodies
from d2slam.synth.render import Quad, QuadSet, box_quads, boxes
from d2slam.synth.textures import make_texture

SCENARIOS = ("walking_xyz", "walking_halfsphere", "walking_static", "walking_rpy", "sitting_static")

ROOM_X = 2.6  # half width (m)
ROOM_Y = (-1.6, 4.0)
ROOM_H = 2.7
CAMERA_HOME = np.array([0.0, 0.0, 1.35])
CAMERA_TARGET = np.array([0.0, 3.0, 1.0])

PERSON_IDS_START = 1
MOVED_BOX_ID = 11
MOVED_CHAIR_ID = 12


# --------------------------------------------------------------------------------------------------
# small rigid-body helpers
# --------------------------------------------------------------------------------------------------
def rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]], float)


def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]], float)


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], float)


def _rots(axis: int, a: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations about a coordinate axis by angles a (N,)."""
    a = np.asarray(a, float)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R[..., axis, axis] = 1.0
    R[..., i, i], R[..., j, j] = c, c
    R[..., i, j], R[..., j, i] = -s, s
    return R


def tf(R=None, t=None) -> np.ndarray:
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    if t is not None:
        T[:3, 3] = t
    return T


def look_at(C: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """(N, 3, 3) camera-to-world rotations whose optical axis (z) points from C (N, 3) to target (N, 3) or (3,),
    x to the right and y down (TUM / OpenCV optical frame)."""
    C = np.atleast_2d(C)
    f = np.broadcast_to(target, C.shape) - C
    f = f / np.linalg.norm(f, axis=1, keepdims=True)
    r = np.cross(f, np.asarray(up, float))
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    d = np.cross(f, r)
    return np.stack([r, d, f], axis=2)


# --------------------------------------------------------------------------------------------------
# camera paths (fr3-like)
# --------------------------------------------------------------------------------------------------
class CameraPath:
    """Smooth analytic camera path of a scenario: ``poses(t)`` -> (N, 4, 4) ``T_world_camera``, t in seconds from
    the first frame. Both the 30 Hz frames and the 100 Hz ground truth sample this same function."""

    def __init__(self, scenario: str, rng: np.random.Generator):
        self.scenario = scenario
        self.ph = rng.uniform(0, 2 * np.pi, size=12)
        self.per = rng.uniform(0.85, 1.15, size=12)  # period factors

    def _sin(self, t, k, period, amp):
        return amp * np.sin(2 * np.pi * t / (period * self.per[k]) + self.ph[k])

    def poses(self, t) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, float))
        n = len(t)
        S, deg = self.scenario, np.pi / 180
        yaw = pitch = roll = np.zeros(n)
        if S == "walking_xyz":  # translation along the three axes, small rotation
            C = CAMERA_HOME + np.stack([self._sin(t, 0, 6.5, 0.42), self._sin(t, 1, 8.3, 0.30),
                                        self._sin(t, 2, 5.1, 0.24)], axis=1)
            R = look_at(CAMERA_HOME[None], CAMERA_TARGET).repeat(n, axis=0)
            yaw, pitch, roll = (self._sin(t, 3, 7.0, 3 * deg), self._sin(t, 4, 5.7, 2.5 * deg),
                                self._sin(t, 5, 6.3, 2 * deg))
        elif S == "walking_rpy":  # roll / pitch / yaw swings, little translation
            C = CAMERA_HOME + np.stack([self._sin(t, 0, 4.1, 0.03), self._sin(t, 1, 5.3, 0.03),
                                        self._sin(t, 2, 3.7, 0.025)], axis=1)
            R = look_at(CAMERA_HOME[None], CAMERA_TARGET).repeat(n, axis=0)
            yaw, pitch, roll = (self._sin(t, 3, 6.2, 26 * deg), self._sin(t, 4, 7.1, 17 * deg),
                                self._sin(t, 5, 5.3, 22 * deg))
        elif S == "walking_halfsphere":  # on a ~1 m diameter half sphere, looking at the scene centre
            centre = CAMERA_HOME + np.array([0.0, 0.5, 0.0])
            az = self._sin(t, 0, 9.0, 70 * deg)
            el = 20 * deg + self._sin(t, 1, 6.3, 28 * deg)
            r = 0.5
            C = centre + r * np.stack([np.cos(el) * np.sin(az), -np.cos(el) * np.cos(az), np.sin(el)], axis=1)
            R = look_at(C, CAMERA_TARGET)
            roll = self._sin(t, 5, 5.0, 3 * deg)
        elif S in ("walking_static", "sitting_static"):  # nearly still: mm-level jitter
            a = 0.002 if S == "walking_static" else 0.0006
            ang = (0.15 if S == "walking_static" else 0.05) * deg
            C = CAMERA_HOME + np.stack([self._sin(t, 0, 1.7, a) + self._sin(t, 6, 0.43, a / 3),
                                        self._sin(t, 1, 2.3, a) + self._sin(t, 7, 0.57, a / 3),
                                        self._sin(t, 2, 1.9, a) + self._sin(t, 8, 0.37, a / 3)], axis=1)
            R = look_at(CAMERA_HOME[None], CAMERA_TARGET).repeat(n, axis=0)
            yaw, pitch, roll = self._sin(t, 3, 2.1, ang), self._sin(t, 4, 1.3, ang), self._sin(t, 5, 2.9, ang)
        else:
            raise D2SlamError(f"unknown scenario {S!r}; choose one of {', '.join(SCENARIOS)}")
        # extra rotation in the camera frame: yaw about y (down), pitch about x (right), roll about z (forward)
        R = R @ _rots(1, yaw) @ _rots(0, pitch) @ _rots(2, roll)
        T = np.zeros((n, 4, 4))
        T[:, :3, :3] = R
        T[:, :3, 3] = C
        T[:, 3, 3] = 1.0
        return T


# --------------------------------------------------------------------------------------------------
# people and moved objects
# --------------------------------------------------------------------------------------------------
BOX_HALF = np.array([0.22, 0.16, 0.15])


def chair_parts(T: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Office chair in frame T (origin on the floor under the seat, +y = the sitter's forward)."""
    return [(T @ tf(t=[0, 0, 0.46]), np.array([0.24, 0.24, 0.035])),
            (T @ tf(t=[0, -0.22, 0.76]), np.array([0.23, 0.03, 0.26])),
            (T @ tf(t=[0, 0, 0.25]), np.array([0.03, 0.03, 0.2])),
            (T @ tf(t=[0, 0, 0.04]), np.array([0.28, 0.28, 0.03]))]


_BODIES: dict = {}


def body_model(shape: tuple, cfg) -> bodies.BodyModel:
    """The ANNY body of a shape (six controls), built once per process."""
    key = (tuple(np.round(shape, 12)), cfg)
    if key not in _BODIES:
        _BODIES[key] = bodies.BodyModel(np.asarray(shape, float), cfg)
    return _BODIES[key]


@dataclass
class Person:
    """An articulated MakeHuman body (``d2slam.synth.bodies``) on a path, posed by a sinusoidal gait.

    ``role``: ``walk`` (a closed path with turns), ``carry`` (walks and carries ``box`` during ``interval``),
    ``push`` (walks and pushes ``chair`` during ``interval``) or ``sit`` (on a chair, shifting and gesturing).
    ``shape``: the six ANNY shape controls; ``clothes``: colours and patterns; ``style``: gait amplitude factor."""

    pid: int
    name: str
    role: str
    shape: tuple
    clothes: bodies.Clothes
    params: dict
    body_cfg: object
    interval: tuple[float, float] | None = None
    _path: tuple | None = field(default=None, repr=False)

    # ---- walking path: a wobbly ellipse in the floor plane, parametrised by arc length ----
    def _table(self):
        if self._path is None:
            p = self.params
            phi = np.linspace(0, 2 * np.pi, 4001)
            r = 1.0 + p["wobble"] * np.sin(2 * phi + p["wobble_ph"])
            x, y = p["ax"] * r * np.cos(phi), p["ay"] * r * np.sin(phi)
            c, s = np.cos(p["rot"]), np.sin(p["rot"])
            xy = np.stack([p["cx"] + c * x - s * y, p["cy"] + s * x + c * y], axis=1)
            seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
            arc = np.concatenate([[0], np.cumsum(seg)])
            self._path = (arc, xy)
        return self._path

    def _walk_state(self, t: float):
        p = self.params
        arc, xy = self._table()
        L = arc[-1]
        # speed varies slowly (people slow down, speed up); distance = integral of it (analytic)
        w = 2 * np.pi / p["speed_period"]
        s = p["s0"] + p["speed"] * (t - p["speed_var"] / w * (np.cos(w * t + p["speed_ph"]) - np.cos(p["speed_ph"])))
        s = p["direction"] * s
        sm = np.mod(s, L)
        x = np.interp(sm, arc, xy[:, 0])
        y = np.interp(sm, arc, xy[:, 1])
        ds = 0.02 * p["direction"]
        x2 = np.interp(np.mod(s + ds, L), arc, xy[:, 0])
        y2 = np.interp(np.mod(s + ds, L), arc, xy[:, 1])
        heading = np.arctan2(y2 - y, x2 - x)
        return np.array([x, y]), heading, abs(s)

    def root(self, t: float) -> np.ndarray:
        """4x4 pose of the body root (on the floor under the pelvis; x right, y forward, z up)."""
        if self.role == "sit":
            p = self.params
            return tf(rot_z(p["heading"] - np.pi / 2), [p["x"], p["y"], 0.0])
        (x, y), heading, _ = self._walk_state(t)
        return tf(rot_z(heading - np.pi / 2), [x, y, 0.0])

    def active(self, t: float) -> bool:
        return self.interval is not None and self.interval[0] <= t <= self.interval[1]

    def mesh(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World vertices (V, 3), triangles and shaded vertex colours of the posed body at time t (s)."""
        p, cfg = self.params, self.body_cfg
        body = body_model(self.shape, cfg)
        amp = bodies.amplitudes(cfg, p["style"])
        if self.role == "sit":
            rot = bodies.sitting(t, amp, p["ph"], p["f"])
        else:
            _, _, dist = self._walk_state(t)
            carry = {"carry": "box", "push": "push"}.get(self.role) if self.active(t) else None
            rot = bodies.gait(2 * np.pi * dist / p["stride"], amp, t, carry)
        V = body.pose(rot)
        T = self.root(t) @ tf(rot_z(np.pi))  # the ANNY body faces -y; the root's forward is +y
        if self.role == "sit":
            T = T @ tf(t=[0.0, p["seat_back"], 0.0])
        Vw = V @ T[:3, :3].T + T[:3, 3]
        light = np.asarray(cfg.light, float)
        col = bodies.shade(body.colours(self.clothes), bodies.vertex_normals(Vw, body.triangles, body.incidence),
                           light / np.linalg.norm(light), cfg.ambient)
        return Vw, body.triangles, col

    # ---- carried box / pushed chair poses ----
    def carried_pose(self, t: float) -> np.ndarray:
        if self.role == "carry":
            return self.root(t) @ tf(t=[0, 0.42, 0.91 + 0.26])
        return self.root(t) @ tf(t=[0, 0.72, 0.0])


@dataclass
class MovedObject:
    """An inert textured object (box or chair) moved by ``carrier`` during ``interval`` (seconds from start)."""

    oid: int
    name: str
    kind: str  # "box" | "chair"
    carrier: Person
    interval: tuple[float, float]
    tex: int
    lift: float = 0.5

    def pose(self, t: float) -> np.ndarray:
        t0, t1 = self.interval
        tc = min(max(t, t0), t1)
        T = self.carrier.carried_pose(tc).copy()
        if self.kind == "box":
            lifted = T[2, 3]
            ground = BOX_HALF[2]
            lift = min(self.lift, (t1 - t0) / 3)
            a = np.clip(min(tc - t0, t1 - tc) / max(lift, 1e-6), 0.0, 1.0)  # 0 on the floor, 1 carried
            a = 0.5 - 0.5 * np.cos(np.pi * a)
            T[2, 3] = ground + a * (lifted - ground)
        return T

    def moving(self, t: float) -> bool:
        return self.interval[0] <= t <= self.interval[1]

    def parts(self, t: float) -> list[tuple[np.ndarray, np.ndarray, int]]:
        T = self.pose(t)
        if self.kind == "box":
            return [(T, BOX_HALF, self.tex)]
        return [(Tp, half, self.tex) for Tp, half in chair_parts(T)]


# --------------------------------------------------------------------------------------------------
# the scene
# --------------------------------------------------------------------------------------------------
class Scene:
    """Room, people, moved objects, camera path and clock of one synthetic sequence."""

    def __init__(self, scenario: str, seed: int = 0, frames: int = 300, static_twin: bool = False,
                 cfg: SynthConfig | None = None):
        if scenario not in SCENARIOS:
            raise D2SlamError(f"unknown scenario {scenario!r}; choose one of {', '.join(SCENARIOS)}")
        if int(frames) < 1:
            raise D2SlamError(f"--frames must be at least 1 (got {frames})")
        if int(seed) < 0:
            raise D2SlamError(f"--seed must be a non-negative integer (got {seed})")
        self.cfg = cfg or SynthConfig()
        self.scenario, self.seed, self.frames, self.static_twin = scenario, int(seed), int(frames), bool(static_twin)
        sidx = SCENARIOS.index(scenario)
        c = self.cfg
        self.K = np.array([[c.fx, 0, c.cx], [0, c.fy, c.cy], [0, 0, 1.0]])
        # clock: frame times (relative) with small jitter, depth a few ms later (rendered at the RGB instant)
        clock = np.random.default_rng([self.seed, 4, sidx])
        jit = clock.uniform(-c.frame_jitter, c.frame_jitter, size=frames)
        jit[0] = 0.0
        self.t_rel = np.arange(frames) / c.fps + jit
        self.depth_offset = clock.uniform(*c.depth_time_offset, size=frames)
        self.duration = frames / c.fps
        self.t0 = c.start_time
        self.camera = CameraPath(scenario, np.random.default_rng([self.seed, 3, sidx]))
        self.textures: list[np.ndarray] = []
        self.static_quads: list[Quad] = []
        self._build_room(np.random.default_rng([self.seed, 1]))
        self.people: list[Person] = []
        self.objects: list[MovedObject] = []
        self._build_actors(np.random.default_rng([self.seed, 2, sidx]))

    # ---- textures ----
    def _tex(self, rng, kind, w_m, h_m, tpm) -> int:
        w = int(np.clip(w_m * tpm, 24, 1400))
        h = int(np.clip(h_m * tpm, 24, 1400))
        self.textures.append(make_texture(rng, kind, w, h, self.cfg, tpm))
        return len(self.textures) - 1

    def _box(self, rng, centre, half, kind, front=None, front_kind=None, R=None):
        tpm = self.cfg.room_texels_per_m
        tex = self._tex(rng, kind, 2 * max(half[0], half[1]), 2 * max(half[1], half[2]), tpm)
        texs = [tex] * 6
        if front is not None:
            a = {0: (1, 2), 1: (1, 2), 2: (0, 2), 3: (0, 2)}[front]
            texs[front] = self._tex(rng, front_kind, 2 * half[a[0]], 2 * half[a[1]], tpm * 1.3)
        self.static_quads += box_quads(tf(R, centre), np.asarray(half, float), texs, 0)

    def _build_room(self, rng):
        """An office corner in a hall: plain painted walls, a plain floor, a structured hall ceiling, a cork
        partition behind two white desks with monitors and keyboards, shelves with books, a cabinet, a whiteboard,
        a few posters and cardboard boxes. Plain surfaces are most of the view, as in the TUM fr3 office."""
        tpm = self.cfg.room_texels_per_m
        X, (Y0, Y1), Hh = ROOM_X, ROOM_Y, ROOM_H
        W, D = 2 * X, Y1 - Y0
        walls = [  # (O, U, V, kind): U = right, V = down as seen from inside
            ((-X, Y1, Hh), (W, 0, 0), (0, 0, -Hh), "paint"),  # back
            ((-X, Y0, Hh), (0, D, 0), (0, 0, -Hh), "paint"),  # left
            ((X, Y1, Hh), (0, -D, 0), (0, 0, -Hh), "paint"),  # right
            ((X, Y0, Hh), (-W, 0, 0), (0, 0, -Hh), "paint"),  # front (behind the camera)
            ((-X, Y1, 0.0), (W, 0, 0), (0, -D, 0), "floor_plain"),
            ((-X, Y0, Hh), (W, 0, 0), (0, D, 0), "beams"),
        ]
        for O, U, V, kind in walls:
            U, V = np.array(U, float), np.array(V, float)
            tex = self._tex(rng, kind, np.linalg.norm(U), np.linalg.norm(V), tpm)
            self.static_quads.append(Quad(np.array(O, float), U, V, tex))
        # the partition behind the desks and its posters (1 cm in front)
        self._box(rng, (0.0, 3.88, 0.8), (1.95, 0.03, 0.8), "cork")
        posters = [((-1.5, 3.84, 1.45), (0.45, 0, 0), (0, 0, -0.6)), ((0.55, 3.84, 1.5), (0.4, 0, 0), (0, 0, -0.55)),
                   ((-X + 0.01, 0.4, 1.9), (0, 0.6, 0), (0, 0, -0.8)),
                   ((X - 0.01, 3.0, 1.8), (0, -0.7, 0), (0, 0, -0.5))]
        for O, U, V in posters:
            U, V = np.array(U, float), np.array(V, float)
            tex = self._tex(rng, "poster", np.linalg.norm(U), np.linalg.norm(V), tpm * 1.5)
            self.static_quads.append(Quad(np.array(O, float), U, V, tex))
        # a whiteboard on the back wall, above the partition
        self._box(rng, (1.2, Y1 - 0.02, 1.95), (0.7, 0.01, 0.45), "desk")
        # two white desks with a modesty panel, a monitor (dark frame, screen) and a keyboard each
        for x in (-1.0, 1.05):
            self._box(rng, (x, 3.42, 0.735), (0.8, 0.4, 0.02), "desk")
            self._box(rng, (x, 3.75, 0.36), (0.78, 0.015, 0.35), "cork")
            for dx in (-0.4, 0.4):
                self._box(rng, (x + dx, 3.42, 0.36), (0.02, 0.38, 0.36), "plastic")
            mx = x + rng.uniform(-0.3, 0.3)
            self._box(rng, (mx, 3.6, 0.98), (0.25, 0.025, 0.18), "plastic", front=2, front_kind="screen")
            self._box(rng, (mx, 3.62, 0.78), (0.04, 0.04, 0.04), "plastic")
            self._box(rng, (mx + rng.uniform(-0.05, 0.05), 3.3, 0.765), (0.22, 0.07, 0.012), "keyboard")
        self._box(rng, (-ROOM_X + 0.2, 2.0, 1.0), (0.2, 0.75, 1.0), "plastic", front=1, front_kind="books")
        self._box(rng, (ROOM_X - 0.2, 1.3, 0.9), (0.2, 0.8, 0.9), "plastic", front=0, front_kind="books")
        self._box(rng, (ROOM_X - 0.25, 3.4, 0.55), (0.25, 0.4, 0.55), "plastic")
        spots = [(-2.0, 3.6), (-1.95, 0.6), (2.0, 2.4), (1.95, -0.3), (-2.05, -0.5), (2.1, 0.2)]
        for k in rng.permutation(len(spots))[:3]:
            x, y = spots[k]
            h = rng.uniform(0.15, 0.3)
            half = (rng.uniform(0.15, 0.28), rng.uniform(0.15, 0.28), h)
            self._box(rng, (x, y, h), half, "box", R=rot_z(rng.uniform(-0.4, 0.4)))
        # small things on the desks
        for x in (-1.6, -0.3, 0.6, 1.7):
            h = rng.uniform(0.04, 0.1)
            self._box(rng, (x + rng.uniform(-0.1, 0.1), 3.25, 0.755 + h), (rng.uniform(0.05, 0.12), 0.08, h), "box")

    def _texture_rng(self, k: int) -> np.random.Generator:
        """Texture stream of actor k (its clothes and the object it moves), apart from the paths' stream so that
        the clothes can change without moving anyone."""
        return np.random.default_rng([self.seed, 5, SCENARIOS.index(self.scenario), k])

    def _person_look(self, rng) -> tuple[tuple, bodies.Clothes, float]:
        """Body shape (six ANNY controls), clothes and gait style factor of one person."""
        b = self.cfg.body
        shape = tuple(float(v) for v in rng.uniform(b.shape_low, b.shape_high))
        return shape, bodies.random_clothes(rng, b), float(rng.uniform(*b.gait_jitter))

    def _build_actors(self, rng):
        c = self.cfg
        D = self.duration
        if self.scenario == "sitting_static":
            seats = [(-0.55, 2.55, -np.pi / 2 + 0.35), (0.6, 2.45, -np.pi / 2 - 0.35)]
            for k, (x, y, hd) in enumerate(seats):
                x, y, hd = x + rng.uniform(-0.1, 0.1), y + rng.uniform(-0.15, 0.15), hd + rng.uniform(-0.15, 0.15)
                trng = self._texture_rng(k)
                shape, clothes, style = self._person_look(trng)
                params = {"x": x, "y": y, "heading": hd, "f": rng.uniform(2.0, 6.0, size=8),
                          "ph": rng.uniform(0, 2 * np.pi, size=8), "style": style, "seat_back": c.body.seat_back}
                self.people.append(Person(k + 1, f"person_{k + 1}", "sit", shape, clothes, params, c.body))
                chair_tex = self._tex(trng, "seat", 0.5, 0.5, c.room_texels_per_m)
                for Tp, half in chair_parts(tf(rot_z(hd - np.pi / 2), [x, y, 0.0]) @ tf(t=[0, 0.02, 0])):
                    self.static_quads += box_quads(Tp, half, chair_tex, 0)
            return
        roles = ["walk", "carry", "push"]
        n = len(roles)
        base_phase = rng.uniform(0, 2 * np.pi)
        for k, role in enumerate(roles):
            ax, ay = rng.uniform(0.9, 1.3), rng.uniform(0.35, 0.6)
            params = {
                "cx": rng.uniform(-0.3, 0.3), "cy": rng.uniform(1.8, 2.2), "ax": ax, "ay": ay,
                "rot": rng.uniform(-0.25, 0.25), "wobble": rng.uniform(0.0, 0.15),
                "wobble_ph": rng.uniform(0, 2 * np.pi), "direction": float(rng.choice([-1.0, 1.0])),
                "speed": rng.uniform(*c.walk_speed), "speed_var": rng.uniform(0.1, 0.35),
                "speed_period": rng.uniform(3.0, 7.0), "speed_ph": rng.uniform(0, 2 * np.pi),
                "stride": rng.uniform(*c.body.stride_m),
                "f": rng.uniform(3.0, 9.0, size=8), "ph": rng.uniform(0, 2 * np.pi, size=8),
            }
            # start on the near part of the loop, the people spread around it
            perim = np.pi * (3 * (ax + ay) - np.sqrt((3 * ax + ay) * (ax + 3 * ay)))
            frac = ((base_phase + 2 * np.pi * k / n + rng.uniform(-0.4, 0.4)) / (2 * np.pi)) % 1.0
            params["s0"] = frac * perim
            interval = None
            if role != "walk":
                a = rng.uniform(0.1, 0.25)
                b = rng.uniform(0.65, 0.85)
                interval = (a * D, b * D)
            trng = self._texture_rng(k)
            shape, clothes, params["style"] = self._person_look(trng)
            person = Person(k + 1, f"person_{k + 1}", role, shape, clothes, params, c.body, interval)
            self.people.append(person)
            if role == "carry":
                tex = self._tex(trng, "box", 0.45, 0.32, c.body_texels_per_m)
                self.objects.append(MovedObject(MOVED_BOX_ID, "carried_box", "box", person, interval, tex))
            elif role == "push":
                tex = self._tex(trng, "seat", 0.5, 0.5, c.body_texels_per_m)
                self.objects.append(MovedObject(MOVED_CHAIR_ID, "pushed_chair", "chair", person, interval, tex))

    # ---- per-frame ----
    @property
    def static_set(self) -> QuadSet:
        if getattr(self, "_static_set", None) is None:
            self._static_set = QuadSet.from_quads(self.static_quads)
        return self._static_set

    def dynamic_meshes(self, t: float) -> list[tuple[int, object]]:
        """(object id, mesh) of every person (``(vertices, triangles, colours)``) and moved object (a ``QuadSet``)
        at time t (seconds from the first frame); none in the static twin."""
        if self.static_twin:
            return []
        out: list[tuple[int, object]] = [(p.pid, p.mesh(t)) for p in self.people]
        for o in self.objects:
            parts = o.parts(t)
            T = np.stack([q[0] for q in parts])
            half = np.stack([q[1] for q in parts])
            out.append((o.oid, boxes(T, half, np.full(len(parts), o.tex), np.full(len(parts), o.oid))))
        return out

    @property
    def person_ids(self) -> list[int]:
        return [] if self.static_twin else [p.pid for p in self.people]

    @property
    def moved_object_ids(self) -> list[int]:
        return [] if self.static_twin else [o.oid for o in self.objects]

    def objects_info(self) -> list[dict]:
        """Per-object records of scene.json (intervals in absolute timestamps, the clock of rgb.txt)."""
        if self.static_twin:
            return []
        t_first, t_last = self.t0 + self.t_rel[0], self.t0 + self.t_rel[-1]
        out = []
        for p in self.people:
            out.append({"id": p.pid, "kind": "person", "name": p.name, "role": p.role, "moved": True,
                        "moving_intervals": [[round(t_first, 6), round(t_last, 6)]]})
        for o in self.objects:
            a, b = o.interval
            out.append({"id": o.oid, "kind": "object", "name": o.name, "object": o.kind, "moved": True,
                        "moved_by": o.carrier.pid,
                        "moving_intervals": [[round(self.t0 + a, 6), round(self.t0 + b, 6)]]})
        return out
