"""The synthetic world: an office-like room, articulated people, moved objects and fr3-like camera paths.

World frame: metres, Z up, the floor at Z = 0; the camera starts near (0, 0, 1.35) looking along +Y into the
room. Camera frame: the TUM / OpenCV optical frame (x right, y down, z forward); poses are 4x4
``T_world_camera`` of the optical centre. Everything is a deterministic function of ``(scenario, seed, frames)``
through separate seeded streams (room, people paths, camera, clock, each actor's textures), so the static twin shares the room, the camera
path and the clock of its dynamic sequence.
"""

from __future__ import annotations

import argparse

import numpy as np

from d2slam.errors import D2SlamError
from d2slam.synth import bodies
from d2slam.synth.actors import BOX_HALF, Chair, FloorPlan, HeldObject, Leg, Person, Planner, Timeline
from d2slam.synth.composite import RoomPlanner, box_rest, real_room
from d2slam.synth.config import SYNTH_CAMERA, SynthConfig
from d2slam.synth.render import Quad, QuadSet, box_quads, boxes
from d2slam.synth.rigid import look_at, rot_x, rot_y, rot_z, rots, tf, yaw_pose  # noqa: F401 (re-exported)
from d2slam.synth.textures import make_texture
from d2slam.synth.twin import LensMap, RecordedPath, placement, twin_config

# The fr3-named scenarios imitate the TUM fr3 sequences of the same name (camera motion and what the people do);
# the interaction scenarios are ours: a person carries a box / pushes a chair across the view (camera as w/xyz).
FR3_SCENARIOS = ("walking_xyz", "walking_halfsphere", "walking_static", "walking_rpy", "sitting_static")
INTERACTION_SCENARIOS = ("walking_carry", "walking_push")
# A sequence with a return (ours, for loop closing): the camera walks one loop round the office, looking across it at
# every wall in turn, comes back to where it started and goes round part of the loop again; people as in w/xyz.
LOOP_SCENARIOS = ("office_loop",)
SCENARIOS = FR3_SCENARIOS + INTERACTION_SCENARIOS + LOOP_SCENARIOS
# The synthetic twins of real recordings (d2slam.synth.twin): our office, static, along a real recording's ground
# truth (an input: ``d2slam synth fr1_rpy_twin --on-trajectory TUM_DIR``), through its camera, with the sensor
# calibrated against it (SynthConfig.twin). Not part of the study's grid.
TWIN_SCENARIOS = ("fr1_rpy_twin",)
# People composited into a real recording (d2slam.synth.composite, compositing; ours): the recording's images are the
# background and its ground truth the camera path (an input: ``d2slam synth real_walking --on-trajectory TUM_DIR``);
# two people walk in and out of view on its free floor (real_walking), or one of them carries a box (real_carry).
COMPOSITE_SCENARIOS = ("real_walking", "real_carry")
RECORDED_SCENARIOS = TWIN_SCENARIOS + COMPOSITE_SCENARIOS  # the scenarios that follow a real recording
ALL_SCENARIOS = SCENARIOS + TWIN_SCENARIOS + COMPOSITE_SCENARIOS
# ``--frames tum``: the durations (s) of the real TUM fr3 sequences as the dataset lists them; our interaction
# scenarios take 30 s, about the fr3 walking sequences' mean (office_loop: its default frames).
TUM_DURATIONS = {"walking_xyz": 28.83, "walking_halfsphere": 35.81, "walking_static": 24.83, "walking_rpy": 30.61,
                 "sitting_static": 23.63, "walking_carry": 30.0, "walking_push": 30.0}
# Frames of ``d2slam synth`` without --frames: 300 (10 s), office_loop 1200 (40 s: the return after 29 s).
DEFAULT_FRAMES = 300
SCENARIO_FRAMES = {"office_loop": 1200}
# office_loop's path as fractions of the sequence: still at home until LOOP_START, one turn of the loop done at
# LOOP_RETURN (29 s of 40), then on round the loop at the same speed; radius (m) of the circle the camera walks.
LOOP_START, LOOP_RAMP, LOOP_RETURN, LOOP_RADIUS = 0.1, 0.06, 0.72, 0.6

ROOM_X = 2.6  # half width (m)
ROOM_Y = (-1.6, 4.0)
ROOM_H = 2.7
CAMERA_HOME = np.array([0.0, 0.0, 1.35])
CAMERA_TARGET = np.array([0.0, 3.0, 1.0])

PERSON_IDS_START = 1
MOVED_BOX_ID = 11
MOVED_CHAIR_ID = 12
DESK_CHAIR_IDS = (13, 14)


def scenario_index(scenario: str) -> int:
    """The scenario's place in ``ALL_SCENARIOS``: part of every seeded stream of its sequences."""
    if scenario not in ALL_SCENARIOS:
        raise D2SlamError(f"unknown scenario {scenario!r}; choose one of {', '.join(ALL_SCENARIOS)}")
    return ALL_SCENARIOS.index(scenario)


def tum_frames(scenario: str, fps: float = 30.0) -> int:
    """Frames of the real TUM sequence of that name at ``fps`` (``--frames tum``; see ``TUM_DURATIONS``)."""
    if scenario not in TUM_DURATIONS:
        raise D2SlamError(f"unknown scenario {scenario!r}; choose one of {', '.join(SCENARIOS)}")
    return int(round(TUM_DURATIONS[scenario] * fps))


def frames_arg(value: str) -> int | str:
    """``--frames``: a number of frames, or ``tum`` (each scenario at its TUM duration)."""
    if str(value).lower() == "tum":
        return "tum"
    try:
        return int(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of frames or 'tum', got {value!r}") from None


def default_frames(scenario: str) -> int:
    """Frames of ``scenario`` when none are given (``SCENARIO_FRAMES``, else ``DEFAULT_FRAMES``)."""
    return SCENARIO_FRAMES.get(scenario, DEFAULT_FRAMES)


def resolve_frames(scenario: str, frames: int | str | None, fps: float = 30.0, recorded: int | None = None) -> int:
    """``frames`` as a number of frames for ``scenario`` (``tum``: its TUM duration; None, or ``tum`` for a scenario
    without one: ``default_frames``). A twin or a composite (``recorded``: its recording's frames) takes the
    recording's frames, at most ``frames``."""
    if scenario in RECORDED_SCENARIOS:
        return int(recorded) if frames in (None, "tum") else min(int(frames), int(recorded))
    if frames is None or (frames == "tum" and scenario in SCENARIO_FRAMES):
        return default_frames(scenario)
    return tum_frames(scenario, fps) if frames == "tum" else int(frames)


# --------------------------------------------------------------------------------------------------
# camera paths (fr3-like)
# --------------------------------------------------------------------------------------------------
class CameraPath:
    """Smooth analytic camera path of a scenario: ``poses(t)`` -> (N, 4, 4) ``T_world_camera``, t in seconds from
    the first frame. Both the 30 Hz frames and the 100 Hz ground truth sample this same function. ``duration``
    (s): the sequence's length, which office_loop's path is scaled to (its loop closes at ``LOOP_RETURN`` of it)."""

    def __init__(self, scenario: str, rng: np.random.Generator, duration: float | None = None):
        self.scenario = scenario
        self.duration = duration
        self.ph = rng.uniform(0, 2 * np.pi, size=12)
        self.per = rng.uniform(0.85, 1.15, size=12)  # period factors

    def _sin(self, t, k, period, amp):
        return amp * np.sin(2 * np.pi * t / (period * self.per[k]) + self.ph[k])

    def poses(self, t) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, float))
        n = len(t)
        S, deg = self.scenario, np.pi / 180
        yaw = pitch = roll = np.zeros(n)
        if S in ("walking_xyz",) + INTERACTION_SCENARIOS:  # translation along the three axes, small rotation
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
        elif S == "office_loop":
            C, R = self._loop(t)
            yaw, pitch, roll = (self._sin(t, 3, 7.0, 3 * deg), self._sin(t, 4, 5.7, 3 * deg),
                                self._sin(t, 5, 6.3, 2 * deg))
        else:
            raise D2SlamError(f"unknown scenario {S!r}; choose one of {', '.join(SCENARIOS)}")
        # extra rotation in the camera frame: yaw about y (down), pitch about x (right), roll about z (forward)
        R = R @ rots(1, yaw) @ rots(0, pitch) @ rots(2, roll)
        T = np.zeros((n, 4, 4))
        T[:, :3, :3] = R
        T[:, :3, 3] = C
        T[:, 3, 3] = 1.0
        return T

    def loop_angle(self, t) -> np.ndarray:
        """office_loop: the heading (rad, 0 = +Y, clockwise seen from above) at t: 0 until ``LOOP_START`` of the
        duration, a smooth start over ``LOOP_RAMP``, then a constant speed that completes the turn (2 pi) at
        ``LOOP_RETURN`` and goes on."""
        if not self.duration:
            raise D2SlamError("the office_loop camera path needs the sequence's duration")
        u = np.asarray(t, float) / self.duration
        a, r = LOOP_START, LOOP_RAMP
        x = np.clip((u - a) / r, 0.0, 1.0)
        # integral of the smoothstep ramp from a to u (in units of u), then linear: r (x^3 - x^4 / 2) below a + r
        ramp = r * (x ** 3 - 0.5 * x ** 4) + np.maximum(u - a - r, 0.0)
        return 2 * np.pi * ramp / (LOOP_RETURN - a - 0.5 * r)

    def _loop(self, t):
        """office_loop: the camera walks a circle of ``LOOP_RADIUS`` with its home on it, always looking across the
        circle's centre, so it faces each wall in turn (the desks at home, then the right wall, the front wall, the
        left wall, the desks again); its height bobs by a few cm."""
        th = self.loop_angle(t)
        look = np.stack([np.sin(th), np.cos(th), np.zeros_like(th)], axis=1)
        centre = CAMERA_HOME + np.array([0.0, LOOP_RADIUS, 0.0])
        C = centre - LOOP_RADIUS * look
        C[:, 2] += self._sin(t, 2, 5.1, 0.05)
        target = C + 3.0 * look + np.array([0.0, 0.0, -0.35])  # as CAMERA_TARGET from home: 3 m ahead, 35 cm down
        return C, look_at(C, target)


# --------------------------------------------------------------------------------------------------
# the scene
# --------------------------------------------------------------------------------------------------
class Scene:
    """Room, people, moved objects, camera path (``camera``) and clock of one synthetic sequence, and the camera its
    images are taken through (``intrinsics``: ``SYNTH_CAMERA``, or a twin's recording's)."""

    def __init__(self, scenario: str, seed: int = 0, frames: int = 300, static_twin: bool = False,
                 cfg: SynthConfig | None = None, recording=None):
        sidx = scenario_index(scenario)
        twin = scenario in TWIN_SCENARIOS
        self.composite = scenario in COMPOSITE_SCENARIOS
        self.check_recording(scenario, recording)
        self.check_static_twin(scenario, static_twin)
        if int(frames) < 1:
            raise D2SlamError(f"--frames must be at least 1 (got {frames})")
        if int(seed) < 0:
            raise D2SlamError(f"--seed must be a non-negative integer (got {seed})")
        self.cfg = cfg or SynthConfig()
        self.recording = recording
        self.sidx = sidx
        if twin or self.composite:
            self._twin_clock(recording, int(frames))
        else:
            self.scenario, self.seed, self.frames = scenario, int(seed), int(frames)
            self.static_twin = bool(static_twin)
            c, cam = self.cfg, SYNTH_CAMERA
            self.intrinsics = cam
            self.K = np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1.0]])
            self.canvas_K, self.canvas_size = self.K, (cam.width, cam.height)
            # clock: frame times (relative) with small jitter, depth a few ms later (rendered at the RGB instant)
            clock = np.random.default_rng([self.seed, 4, sidx])
            jit = clock.uniform(-c.frame_jitter, c.frame_jitter, size=frames)
            jit[0] = 0.0
            self.t_rel = np.arange(frames) / c.fps + jit
            self.depth_offset = clock.uniform(*c.depth_time_offset, size=frames)
            self.duration = frames / c.fps
            self.t0 = c.start_time
            self.camera = CameraPath(scenario, np.random.default_rng([self.seed, 3, sidx]), self.duration)
        self.scenario, self.seed = scenario, int(seed)
        self.textures: list[np.ndarray] = []
        self.static_quads: list[Quad] = []
        self.floor_rects: list[tuple[float, float, float, float]] = []  # furniture on the floor (people avoid it)
        if not self.composite:  # a composite's room is the recording's own
            self._build_room(np.random.default_rng([self.seed, 1]))
        self.people: list[Person] = []
        self.objects: list[Chair | HeldObject] = []  # everything people move (ids in mask_gt)
        self._build_actors(np.random.default_rng([self.seed, 2, sidx]))
        if self.static_twin:  # nothing moves: no people, every object frozen where it is at the first frame
            for o in self.objects:
                for T, half, tex in o.parts(float(self.t_rel[0])):
                    self.static_quads += box_quads(T, half, tex, 0)

    @staticmethod
    def check_recording(scenario: str, recording) -> None:
        """A twin or composite scenario needs its recording, and only they take one."""
        scenario_index(scenario)
        if scenario in RECORDED_SCENARIOS and recording is None:
            raise D2SlamError(f"{scenario} follows a real recording's trajectory: give its TUM folder "
                              "(--on-trajectory TUM_DIR, or --on)")
        if scenario not in RECORDED_SCENARIOS and recording is not None:
            raise D2SlamError(f"{scenario} has its own camera path; --on (--on-trajectory) is for the scenarios on a "
                              f"real recording ({', '.join(RECORDED_SCENARIOS)})")

    @staticmethod
    def check_static_twin(scenario: str, static_twin: bool) -> None:
        """A composite has no static twin to generate: it is its recording."""
        if scenario in COMPOSITE_SCENARIOS and static_twin:
            raise D2SlamError(f"the static twin of {scenario} is its recording itself (the TUM folder given to --on): "
                              "nothing to generate")

    def _twin_clock(self, rec, frames: int) -> None:
        """The camera, clock and path of a scene on a real recording: the recording's camera and first ``frames``
        frames (RGB and depth times); a twin: its ground truth placed in the office (d2slam.synth.twin), static (no
        people); a composite: its ground truth in the room frame of the recording's own room
        (d2slam.synth.composite), the room measured from its depth."""
        tw = self.cfg.twin
        self.cfg = twin_config(self.cfg)
        self.frames = min(frames, len(rec))
        self.static_twin = not self.composite
        c, cam = self.cfg, rec.camera
        self.intrinsics = cam
        self.K = np.array([[float(cam.fx), 0, float(cam.cx)], [0, float(cam.fy), float(cam.cy)], [0, 0, 1.0]])
        self.lens = LensMap(rec.camera, tw.distortion)
        self.canvas_K, self.canvas_size = self.lens.K, (self.lens.width, self.lens.height)
        ts = np.asarray(rec.rgb_times[:self.frames], float)
        self.t0 = float(ts[0])
        self.t_rel = ts - self.t0
        self.depth_offset = np.asarray(rec.depth_times[:self.frames], float) - ts
        self.duration = float(self.t_rel[-1]) + 1.0 / c.fps
        if self.composite:
            self.room = real_room(rec, self.cfg)
            self.camera = RecordedPath(rec, self.room.M, self.t0)
            return
        first = RecordedPath(rec, np.eye(4), self.t0).poses([0.0])[0]
        self.camera = RecordedPath(rec, placement(first, tw.anchor_xy, tw.anchor_heading_deg), self.t0)

    # ---- textures ----
    def _tex(self, rng, kind, w_m, h_m, tpm) -> int:
        w = int(np.clip(w_m * tpm, 24, 1400))
        h = int(np.clip(h_m * tpm, 24, 1400))
        self.textures.append(make_texture(rng, kind, w, h, self.cfg, tpm))
        return len(self.textures) - 1

    def _box(self, rng, centre, half, kind, front=None, front_kind=None, R=None, floor=False):
        """A textured box (``front``: one face with its own texture); ``floor``: it stands on the floor and people
        walk round it (its footprint's bounding rectangle)."""
        if floor:
            r = np.abs((R if R is not None else np.eye(3))[:2, :2]) @ np.asarray(half, float)[:2]
            self.floor_rects.append((centre[0] - r[0], centre[0] + r[0], centre[1] - r[1], centre[1] + r[1]))
        tpm = self.cfg.room_texels_per_m
        tex = self._tex(rng, kind, 2 * max(half[0], half[1]), 2 * max(half[1], half[2]), tpm)
        texs = [tex] * 6
        if front is not None:
            a = {0: (1, 2), 1: (1, 2), 2: (0, 2), 3: (0, 2), 4: (0, 1), 5: (0, 1)}[front]
            texs[front] = self._tex(rng, front_kind, 2 * half[a[0]], 2 * half[a[1]], tpm * 1.3)
        self.static_quads += box_quads(tf(R, centre), np.asarray(half, float), texs, 0)

    def _build_room(self, rng):
        """An office corner in a hall: plain painted walls, a plain floor, a structured hall ceiling, a cork
        partition behind two white desks with monitors and keyboards, shelves with books, a cabinet, a whiteboard,
        a few posters and cardboard boxes. Plain surfaces are most of the view, as in the TUM fr3 office. One ``rng``
        draws everything, in this order: the walls, the desks, the furniture, the desks' clutter."""
        self._walls(rng)
        self._desks(rng)
        self._furniture(rng)
        self._clutter(rng)

    def _walls(self, rng):
        """The walls, floor and ceiling, the partition behind the desks with its posters, the whiteboard."""
        tpm = self.cfg.room_texels_per_m
        X, (Y0, Y1), Hh = ROOM_X, ROOM_Y, ROOM_H
        W, D = 2 * X, Y1 - Y0
        walls = [  # (O, U, V, kind): U = right, V = down as seen from inside
            ((-X, Y1, Hh), (W, 0, 0), (0, 0, -Hh), "hall"),  # back: the hall beyond the office
            ((-X, Y0, Hh), (0, D, 0), (0, 0, -Hh), "hall"),  # left
            ((X, Y1, Hh), (0, -D, 0), (0, 0, -Hh), "hall"),  # right
            ((X, Y0, Hh), (-W, 0, 0), (0, 0, -Hh), "paint"),  # front (behind the camera)
            ((-X, Y1, 0.0), (W, 0, 0), (0, -D, 0), "floor_plain"),
            ((-X, Y0, Hh), (W, 0, 0), (0, D, 0), "beams"),
        ]
        for O, U, V, kind in walls:
            U, V = np.array(U, float), np.array(V, float)
            tex = self._tex(rng, kind, np.linalg.norm(U), np.linalg.norm(V), tpm)
            self.static_quads.append(Quad(np.array(O, float), U, V, tex))
        # the partition behind the desks and its posters (1 cm in front)
        self._box(rng, (0.0, 3.88, 0.8), (1.95, 0.03, 0.8), "cork", floor=True)
        posters = [((-1.5, 3.84, 1.45), (0.45, 0, 0), (0, 0, -0.6)), ((0.55, 3.84, 1.5), (0.4, 0, 0), (0, 0, -0.55)),
                   ((-X + 0.01, 0.4, 1.9), (0, 0.6, 0), (0, 0, -0.8)),
                   ((X - 0.01, 3.0, 1.8), (0, -0.7, 0), (0, 0, -0.5))]
        for O, U, V in posters:
            U, V = np.array(U, float), np.array(V, float)
            tex = self._tex(rng, "poster", np.linalg.norm(U), np.linalg.norm(V), tpm * 1.5)
            self.static_quads.append(Quad(np.array(O, float), U, V, tex))
        # white boards in dark frames on the back wall, above the partition
        self._box(rng, (1.2, Y1 - 0.02, 1.95), (0.7, 0.01, 0.45), "plastic", front=2, front_kind="panels")

    def _desks(self, rng):
        """Two white desks with a modesty panel, a monitor (dark frame, screen) and a keyboard each."""
        for x in (-1.0, 1.05):
            self._box(rng, (x, 3.42, 0.735), (0.8, 0.4, 0.02), "desk")
            self.floor_rects.append((x - 0.8, x + 0.8, 3.02, 3.82))  # under the desk: its legs and panel
            self._box(rng, (x, 3.75, 0.36), (0.78, 0.015, 0.35), "cork")
            for dx in (-0.4, 0.4):
                self._box(rng, (x + dx, 3.42, 0.36), (0.02, 0.38, 0.36), "plastic")
            mx = x + rng.uniform(-0.3, 0.3)
            self._box(rng, (mx, 3.6, 0.98), (0.25, 0.025, 0.18), "plastic", front=2, front_kind="screen")
            self._box(rng, (mx, 3.62, 0.78), (0.04, 0.04, 0.04), "plastic")
            self._box(rng, (mx + rng.uniform(-0.05, 0.05), 3.3, 0.765), (0.22, 0.07, 0.012), "keyboard")

    def _furniture(self, rng):
        """Shelves with books, a cabinet, cardboard boxes on the floor, small boxes on the desks."""
        self._box(rng, (-ROOM_X + 0.2, 2.0, 1.0), (0.2, 0.75, 1.0), "plastic", front=1, front_kind="books", floor=True)
        self._box(rng, (ROOM_X - 0.2, 1.3, 0.9), (0.2, 0.8, 0.9), "plastic", front=0, front_kind="books", floor=True)
        self._box(rng, (ROOM_X - 0.25, 3.4, 0.55), (0.25, 0.4, 0.55), "plastic", floor=True)
        spots = [(-2.0, 3.6), (-1.95, 0.6), (2.0, 2.4), (1.95, -0.3), (-2.05, -0.5), (2.1, 0.2)]
        for k in rng.permutation(len(spots))[:3]:
            x, y = spots[k]
            h = rng.uniform(0.15, 0.3)
            half = (rng.uniform(0.15, 0.28), rng.uniform(0.15, 0.28), h)
            self._box(rng, (x, y, h), half, "box", R=rot_z(rng.uniform(-0.4, 0.4)), floor=True)
        # small things on the desks
        for x in (-1.6, -0.3, 0.6, 1.7):
            h = rng.uniform(0.04, 0.1)
            self._box(rng, (x + rng.uniform(-0.1, 0.1), 3.25, 0.755 + h), (rng.uniform(0.05, 0.12), 0.08, h), "box")

    def _clutter(self, rng):
        """The clutter of a used desk, as on the TUM fr3 desks: sheets of paper, a stack of books, a mug, a tool; under
        each desk a computer and beside it a waste bin."""
        for x in (-1.0, 1.05):
            for _ in range(int(rng.integers(2, 4))):
                self._box(rng, (x + rng.uniform(-0.65, 0.65), rng.uniform(3.1, 3.5), 0.757), (rng.uniform(0.1, 0.15),
                          rng.uniform(0.07, 0.105), 0.002), "plastic", front=5, front_kind="paper",
                          R=rot_z(rng.uniform(-0.5, 0.5)))
            h = rng.uniform(0.05, 0.12)
            self._box(rng, (x + rng.uniform(-0.6, 0.6), rng.uniform(3.15, 3.5), 0.755 + h), (0.12, 0.09, h), "books",
                      R=rot_z(rng.uniform(-0.4, 0.4)))
            self._box(rng, (x + rng.uniform(-0.6, 0.6), rng.uniform(3.1, 3.3), 0.805), (0.04, 0.04, 0.05), "box")
            self._box(rng, (x + rng.uniform(-0.6, 0.6), rng.uniform(3.1, 3.4), 0.79), (0.1, 0.04, 0.035), "chair",
                      R=rot_z(rng.uniform(-1.0, 1.0)))
            self._box(rng, (x + rng.uniform(-0.3, 0.3), 3.5, 0.22), (0.1, 0.22, 0.22), "plastic", front=2,
                      front_kind="screen")
            bx = x + rng.choice([-0.95, 0.95])
            if abs(bx) < ROOM_X - 0.4:
                self._box(rng, (bx, 3.5, 0.17), (0.14, 0.14, 0.17), "plastic", floor=True)

    def _texture_rng(self, k: int) -> np.random.Generator:
        """Texture stream of actor k (its clothes and the object it moves), apart from the paths' stream so that
        the clothes can change without moving anyone."""
        return np.random.default_rng([self.seed, 5, self.sidx, k])

    def _person_look(self, rng) -> tuple[tuple, bodies.Clothes, float, np.ndarray]:
        """Body shape (six ANNY controls), clothes, gait style factor and garment textures of one person."""
        b = self.cfg.body
        shape = tuple(float(v) for v in rng.uniform(b.shape_low, b.shape_high))
        clothes = bodies.random_clothes(rng, b)
        return shape, clothes, float(rng.uniform(*b.motion.gait_jitter)), self._garments(rng, clothes)

    def _garments(self, rng, clothes: bodies.Clothes) -> np.ndarray:
        """One texture per garment (shirt, trousers, shoes, skin with the face in front, hair) in its colour: one turn
        round the body wide (``BodyConfig.turn_m``) plus the seam pad, the body's height tall; indices (5,)."""
        c, b = self.cfg, self.cfg.body
        out = []
        for part, kind in enumerate(("cloth", "trousers", "trousers", "skin", "hair")):
            tpm = c.body_texels_per_m * b.garment_texels[part]
            w, h = int(b.turn_m * tpm), int(b.height_m * tpm)
            face = (0.5 * w, b.eyes_m * tpm, tpm * b.turn_m / (2 * np.pi * b.head_radius_m)) if kind == "skin" else None
            img = make_texture(rng, kind, w, h, c, tpm, base=tuple(255.0 * clothes.colours[part]), face=face)
            self.textures.append(np.concatenate([img, img[:, :int(bodies.SEAM_PAD * w)]], axis=1))
            out.append(len(self.textures) - 1)
        return np.asarray(out)

    def _new_person(self, k: int, role: str, rng, timeline: Timeline) -> Person:
        """Person k (id k + 1): look from its own texture stream, gait stride and seated movements from ``rng``."""
        shape, clothes, style, tex = self._person_look(self._texture_rng(k))
        params = {"style": style, "stride": float(rng.uniform(*self.cfg.body.motion.stride_m)),
                  "f": rng.uniform(2.0, 6.0, size=8), "ph": rng.uniform(0, 2 * np.pi, size=8)}
        return Person(k + PERSON_IDS_START, f"person_{k + 1}", role, shape, clothes, params, self.cfg.body, timeline,
                      tex)

    def _build_actors(self, rng):
        c, a = self.cfg, self.cfg.actors
        if self.scenario in TWIN_SCENARIOS:  # a static twin: nobody, nothing moved
            return
        if self.composite:
            self._composite_actors(rng)
            return
        if self.scenario == "sitting_static":  # two people seated throughout, their chairs part of the room
            seats = [(-0.55, 2.55, -np.pi / 2 + 0.35), (0.6, 2.45, -np.pi / 2 - 0.35)]
            for k, (x, y, hd) in enumerate(seats):
                x, y, hd = x + rng.uniform(-0.1, 0.1), y + rng.uniform(-0.15, 0.15), hd + rng.uniform(-0.15, 0.15)
                seat = np.array([x, y]) + a.sitting.seat_offset_m * np.array([np.cos(hd), np.sin(hd)])
                tex = self._tex(self._texture_rng(k), "seat", 0.5, 0.5, c.room_texels_per_m)
                chair = Chair(0, "chair", seat, hd, tex)
                tl = Timeline(a)
                tl.add(Leg("sit", -1.0, self.duration + 1.0, 0.0, chair.xy, chair=chair))
                self.people.append(self._new_person(k, "sit", rng, tl))
                for T, half, tex in chair.parts(0.0):
                    self.static_quads += box_quads(T, half, tex, 0)
            return
        # two desk chairs that shift a little when somebody sits down or gets up
        jx, jy = a.sitting.desk_chair_jitter
        chairs = []
        for j, (oid, side) in enumerate(zip(DESK_CHAIR_IDS, (-1.0, 1.0))):
            chair_x = side * a.sitting.desk_chair_x + rng.uniform(-jx, jx)  # drawn before y
            xy = np.array([chair_x, a.sitting.desk_chair_y + rng.uniform(-jy, jy)])
            h = np.pi / 2 + rng.uniform(-a.sitting.desk_chair_turn, a.sitting.desk_chair_turn)
            tex = self._tex(self._texture_rng(10 + j), "seat", 0.5, 0.5, c.body_texels_per_m)
            chairs.append(Chair(oid, f"desk_chair_{j + 1}", xy, float(h), tex))
        held = []
        if self.scenario in INTERACTION_SCENARIOS:  # the box / chair on one side of the view, taken from the camera's side
            side = rng.choice([-1.0, 1.0])
            xy = np.array([side * rng.uniform(*a.holding.object_x), rng.uniform(*a.holding.object_y)])
            h = np.pi / 2 + rng.uniform(-a.holding.object_turn, a.holding.object_turn)
            trng = self._texture_rng(0)
            if self.scenario == "walking_carry":
                tex = self._tex(trng, "box", 0.45, 0.32, c.body_texels_per_m)
                held.append(HeldObject(MOVED_BOX_ID, "carried_box", "box", tex, yaw_pose(xy, h, BOX_HALF[2]),
                                       tf(t=a.holding.box_offset), float(BOX_HALF[2])))
            else:
                tex = self._tex(trng, "seat", 0.5, 0.5, c.body_texels_per_m)
                held.append(HeldObject(MOVED_CHAIR_ID, "pushed_chair", "chair", tex, yaw_pose(xy, h),
                                       tf(t=a.holding.push_offset), 0.0))
        floor = FloorPlan((-ROOM_X, ROOM_X, ROOM_Y[0], ROOM_Y[1]), self.floor_rects, a.floor_clearance)
        for k in range(2):  # with an object to move, the first person moves it
            role = ("carry" if held[0].kind == "box" else "push") if held and k == 0 else "walk"
            self.people.append(self._new_person(k, role, rng, Timeline(a)))
        Planner(rng, a, floor, self.duration + 1.0, chairs, held).plan(
            self.people, {self.people[0].pid: held[0]} if held else None)
        self.objects = chairs + held

    def _composite_actors(self, rng):
        """The people of a composite (d2slam.synth.composite): two walkers on the recording's free floor, the first
        carrying a box in real_carry, planned together."""
        c = self.cfg
        held = []
        planner = RoomPlanner(rng, c.actors, self.room, self.duration + 1.0, held, c.composite)
        if self.scenario == "real_carry":
            xy, h = box_rest(rng, planner, c)
            tex = self._tex(self._texture_rng(0), "box", 0.45, 0.32, c.body_texels_per_m)
            held.append(HeldObject(MOVED_BOX_ID, "carried_box", "box", tex, yaw_pose(xy, h, BOX_HALF[2]),
                                   tf(t=c.actors.holding.box_offset), float(BOX_HALF[2])))
            planner.objects = list(held)
        for k in range(2):
            self.people.append(self._new_person(k, "carry" if held and k == 0 else "walk", rng, Timeline(c.actors)))
        planner.plan(self.people, {self.people[0].pid: held[0]} if held else None)
        self.objects = held

    # ---- per-frame ----
    @property
    def static_set(self) -> QuadSet:
        if getattr(self, "_static_set", None) is None:
            self._static_set = QuadSet.from_quads(self.static_quads)
        return self._static_set

    def dynamic_meshes(self, t: float) -> list[tuple[int, object]]:
        """(object id, mesh) of every person (``(vertices, triangles, shading, (uv, texture index) per vertex)``,
        ``Person.mesh``) and moved object (a ``QuadSet``) at time t (seconds from the first frame); none in the
        static twin."""
        if self.static_twin:
            return []
        out: list[tuple[int, object]] = [(p.pid, p.mesh(t)) for p in self.people]
        for o in self.objects:
            parts = o.parts(t)
            T = np.stack([q[0] for q in parts])
            half = np.stack([q[1] for q in parts])
            out.append((o.oid, boxes(T, half, np.array([q[2] for q in parts]), np.full(len(parts), o.oid))))
        return out

    def _intervals(self, o) -> list[tuple[float, float]]:
        """An object's moving intervals within the sequence (relative seconds)."""
        a, b = float(self.t_rel[0]), float(self.t_rel[-1])
        return [(max(x, a), min(y, b)) for x, y in o.intervals if y >= a and x <= b]

    @property
    def person_ids(self) -> list[int]:
        return [] if self.static_twin else [p.pid for p in self.people]

    @property
    def moved_object_ids(self) -> list[int]:
        return [] if self.static_twin else [o.oid for o in self.objects if self._intervals(o)]

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
            iv = self._intervals(o)
            out.append({"id": o.oid, "kind": "object", "name": o.name, "object": o.kind, "moved": bool(iv),
                        "moved_by": sorted(o.moved_by),
                        "moving_intervals": [[round(self.t0 + x, 6), round(self.t0 + y, 6)] for x, y in iv]})
        return out
