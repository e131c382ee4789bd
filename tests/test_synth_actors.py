"""What the synthetic people do (d2slam.synth.actors), checked on their planned timelines without rendering: the fr3
people walk in and out of view, stand, sit down on desk chairs that shift a little and get up, and never carry or
push anything; the interaction scenarios' box and chair move only while a person moves them; nobody walks through
furniture or another person; every motion is continuous; the plan is a function of the seed."""

from __future__ import annotations

import numpy as np
import pytest

from d2slam.config import ActorsConfig
from d2slam.synth.actors import Chair, HeldObject, Route, smoothstep
from d2slam.synth.scene import FR3_SCENARIOS, INTERACTION_SCENARIOS, TUM_DURATIONS, Scene, tum_frames

A = ActorsConfig()
SEEDS = (0, 1, 2)
WALKING = [s for s in FR3_SCENARIOS if s.startswith("walking")]


@pytest.fixture(scope="module")
def scenes():
    return {(sc, sd): Scene(sc, sd, 300) for sc in WALKING + list(INTERACTION_SCENARIOS) for sd in SEEDS}


def _times(scene, dt=0.01):
    return np.arange(0.0, scene.duration, dt)


def test_fr3_people_walk_sit_and_leave_the_view_but_never_move_objects(scenes):
    sat = left = 0
    walks = []
    for (sc, sd), scene in scenes.items():
        if sc not in WALKING:
            continue
        assert [p.role for p in scene.people] == ["walk", "walk"]
        assert all(isinstance(o, Chair) for o in scene.objects)  # the desk chairs only: nothing carried or pushed
        for p in scene.people:
            kinds = [leg.kind for leg in p.timeline.legs]
            t = _times(scene, 0.1)
            xy = np.array([p.state(float(x)).xy for x in t])
            walks.append(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum())
            sat += "sit_down" in kinds and "stand_up" in kinds
            left += bool((np.abs(xy[:, 0]) > A.view_slope * xy[:, 1] + A.view_margin_m).any())
    assert sat >= 3 and left >= 2  # over the 12 sequences: people sit down and get up, and walk out of view
    assert min(walks) > 0.5 and np.median(walks) > 2.0  # metres in 10 s: whoever sits a while still walks


def test_people_keep_apart_and_off_the_furniture(scenes):
    for (sc, sd), scene in scenes.items():
        t = _times(scene, 0.1)
        P = [np.array([p.state(float(x)).xy for x in t]) for p in scene.people]
        gap = np.linalg.norm(P[0] - P[1], axis=1)
        assert gap.min() >= A.person_gap * A.relax_gap - 0.05, (sc, sd)  # boxed in, people squeeze past
        for xy in P:
            for a, b, lo, hi in scene.floor_rects:  # the room's furniture (people may brush chairs aside)
                inside = (xy[:, 0] > a) & (xy[:, 0] < b) & (xy[:, 1] > lo) & (xy[:, 1] < hi)
                assert not inside.any(), (sc, sd, (a, b, lo, hi))


def test_motions_are_continuous(scenes):
    for (sc, sd), scene in list(scenes.items())[::3]:
        t = _times(scene, 0.01)
        for p in scene.people:
            s = [p.state(float(x)) for x in t]
            xy = np.array([q.xy for q in s])
            h = np.unwrap([q.heading for q in s])
            sit = np.array([q.sit for q in s])
            assert np.abs(np.diff(xy, axis=0)).max() < 0.03, (sc, sd, p.name)  # < 3 m/s
            assert np.abs(np.diff(h)).max() < 0.06, (sc, sd, p.name)  # < 6 rad/s
            assert np.abs(np.diff(sit)).max() < 0.03
        for o in scene.objects:
            T = np.array([o.pose(float(x))[:3, 3] for x in t])
            assert np.abs(np.diff(T, axis=0)).max() < 0.03, (sc, sd, o.name)


def test_chairs_shift_a_little_when_people_sit_down_and_get_up(scenes):
    shifted = 0
    for (sc, sd), scene in scenes.items():
        for ch in (o for o in scene.objects if isinstance(o, Chair)):
            t = _times(scene, 0.05)
            xy = np.array([ch.pose2(float(x))[0] for x in t])
            moving = np.array([ch.moving(float(x)) for x in t])
            still = np.linalg.norm(np.diff(xy, axis=0), axis=1)[~moving[:-1] & ~moving[1:]]
            assert still.max(initial=0.0) < 1e-9  # it moves only while somebody sits down or gets up
            assert np.linalg.norm(xy - xy[0], axis=1).max() < 0.5  # a few cm each time
            shifted += bool(ch.intervals)
        for p in scene.people:  # seated, a person sits on the chair
            for leg in p.timeline.legs:
                if leg.kind == "sit":
                    tm = 0.5 * (leg.t0 + leg.t1)
                    seat = leg.chair.seat(tm, A)[0]
                    assert np.linalg.norm(p.state(tm).xy - seat) < 1e-9
    assert shifted >= 3


@pytest.mark.parametrize("scenario", INTERACTION_SCENARIOS)
def test_the_box_and_the_chair_move_only_while_a_person_moves_them(scenes, scenario):
    travel = []
    for sd in SEEDS:
        scene = scenes[(scenario, sd)]
        held = [o for o in scene.objects if isinstance(o, HeldObject)]
        assert len(held) == 1 and scene.people[0].role == ("carry" if scenario == "walking_carry" else "push")
        obj = held[0]
        assert obj.holds and obj.moved_by == [scene.people[0].pid]
        t = _times(scene, 0.05)
        T = np.array([obj.pose(float(x))[:3, 3] for x in t])
        moving = np.array([obj.moving(float(x)) for x in t])
        step = np.linalg.norm(np.diff(T, axis=0), axis=1)
        assert step[~moving[:-1] & ~moving[1:]].max(initial=0.0) < 1e-9
        travel.append(step.sum())
        assert (T[:, 2] >= 0).all()  # on the floor or above it
        for h in obj.holds:  # it follows its carrier while carried or pushed
            for x in np.linspace(h.t1, h.t2, 8):
                assert np.linalg.norm(obj.pose(x)[:2, 3] - h.person.root(x)[:2, 3]) < 1.0
    assert min(travel) > 0.3 and np.median(travel) > 1.5  # moved across the view (metres)


def test_plans_are_a_function_of_the_seed():
    a, b, c = Scene("walking_xyz", 5, 120), Scene("walking_xyz", 5, 120), Scene("walking_xyz", 6, 120)
    for x in np.linspace(0, 4, 9):
        for pa, pb in zip(a.people, b.people):
            np.testing.assert_array_equal(pa.root(x), pb.root(x))
    assert any(not np.allclose(pa.root(2.0), pc.root(2.0)) for pa, pc in zip(a.people, c.people))


def test_routes_and_speed_profiles():
    r = Route(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]))
    assert 1.6 < r.length < 2.0  # the corner is rounded
    xy, h = r.at(0.0)
    np.testing.assert_allclose(xy, [0, 0], atol=1e-12)
    assert abs(h) < 0.3 and abs(r.at(r.length)[1] - np.pi / 2) < 0.3  # leaving and arriving along the segments
    assert smoothstep(0.0) == 0.0 and smoothstep(1.0) == 1.0 and smoothstep(0.5) == 0.5


def test_tum_durations():
    from d2slam.errors import D2SlamError
    from d2slam.study.grid import expand_grid
    from d2slam.synth.scene import frames_arg, resolve_frames

    assert tum_frames("walking_xyz") == round(TUM_DURATIONS["walking_xyz"] * 30) == 865
    assert all(700 <= tum_frames(s) <= 1100 for s in TUM_DURATIONS)
    assert frames_arg("tum") == "tum" and frames_arg("120") == 120 and resolve_frames("sitting_static", "tum") == 709
    with pytest.raises(D2SlamError, match="unknown scenario"):
        tum_frames("walking_sideways")
    specs = expand_grid(["walking_static", "walking_carry"], ["none"], [0], "tum", (), online_methods=())
    assert [s.frames for s in specs] == [745, 900]
    with pytest.raises(D2SlamError, match="not a TUM sequence"):
        expand_grid(["walking_carry"], ["none"], [0], "tum", (), source="tum")
