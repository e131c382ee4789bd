"""``d2slam bench room TUM_DIR``: the room a composite's people are planned in (``d2slam synth real_walking --on
TUM_DIR``; ``d2slam.synth.realroom``, ``composite``; docs/real_people.md): the floor found in the recording's depth,
the free space's areas, how far from the camera a person can stand on seen-free floor, and how often the camera
looks at it: the share of the recording's frames in which a person standing on some free lattice cell would cover at
least ``--coverage`` of the image, over every such cell and over those a person can walk to from out of view (the
ceiling of how often people can be in view at fr3-like coverage)."""

from __future__ import annotations

import time

import cv2
import numpy as np

from d2slam.config import SynthConfig
from d2slam.synth.composite import RoomPlanner, real_room
from d2slam.synth.twin import RecordedPath, read_recording, twin_config

DESCRIPTION = ("a real recording's room for composites: floor, free space, distances, how often a person on its free "
               "floor would be in view")


def add_arguments(parser) -> None:
    parser.add_argument("recording", metavar="TUM_DIR", help="a real TUM recording with ground truth")
    parser.add_argument("--frames", type=int, default=None, help="its first N frames (default: all)")
    parser.add_argument("--coverage", type=float, default=0.03, help="image share counted as in view (default 0.03)")


def run(args) -> int:
    t0 = time.perf_counter()
    rec = read_recording(args.recording)
    if args.frames:
        rec = rec.part(0, min(int(args.frames), len(rec)))
    cfg = twin_config(SynthConfig())
    room = real_room(rec, cfg)
    s, v = room.space, room.visibility
    n, d = room.floor
    tilt = float(np.degrees(np.arccos(np.clip(n[2], -1.0, 1.0))))
    print(f"The room of {rec.name} ({len(rec)} frames, every {cfg.composite.fuse_stride}th depth image fused)")
    print(f"  floor: normal {np.round(n, 4).tolist()} ({tilt:.2f} deg from the vertical), {d:.3f} m along it")
    a = room.summary(cfg.composite.vis_min_coverage)["area_m2"]
    print(f"  areas (m^2): occupied {a['occupied']:.2f}, seen free {a['known_free']:.2f}, standable and seen free "
          f"{a['standable_known_free']:.2f}, standable out of view {a['out_of_view']:.2f}")
    centre = RecordedPath(rec, room.M, float(rec.rgb_times[0])).poses(rec.rgb_times - rec.rgb_times[0])[:, :3, 3]
    ix, iy = np.nonzero(s.standable & s.known_free)
    dist = np.linalg.norm(s.centre(ix, iy) - centre[:, :2].mean(axis=0), axis=1)
    print(f"  standable seen-free floor, distance from the camera (m) p10/p50/p90: "
          f"{'/'.join(f'{x:.2f}' for x in np.percentile(dist, (10, 50, 90)))}")
    planner = RoomPlanner(np.random.default_rng(0), cfg.actors, room, 1.0, [], cfg.composite)
    _, lab = cv2.connectedComponents(s.standable.astype(np.uint8), connectivity=8)
    ti, tj, _ = s.cells(v.xy[planner.targets])
    ei, ej, _ = s.cells(planner.exits)
    reach = planner.targets[np.isin(lab[ti, tj], np.unique(lab[ei, ej]))]
    for what, cells in (("any free lattice cell", np.arange(len(v.xy))), ("a cell reachable from out of view",
                                                                          reach)):
        best = v.coverage[cells].max(axis=0) if len(cells) else np.zeros(v.coverage.shape[1])
        print(f"  frames where a person on {what} ({len(cells)} of {len(v.xy)}) covers >= {100 * args.coverage:g} % "
              f"of the image: {100 * float((best >= args.coverage).mean()):.1f} % of {v.coverage.shape[1]} fused")
    print(f"({time.perf_counter() - t0:.1f} s)")
    return 0
