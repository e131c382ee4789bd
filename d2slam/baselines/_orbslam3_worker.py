"""Child process that runs the real ORB-SLAM3 (pyorbslam3) on one sequence; started by
:func:`d2slam.baselines.orbslam3.run_orbslam3`, never by users.

ORB-SLAM3 calls ``exit(-1)`` on a bad settings file, accepts a garbage vocabulary and then crashes, and runs
threads: it lives in this process so that the caller survives and can time it out. Protocol (files in ``--work``):

- ``progress.txt``: one line per frame, flushed: ``index timestamp state ms n_tracked pose(16 values | -)``
  where ``state`` is ORB-SLAM3's ``TrackingState`` value, ``ms`` the time of ``track_rgbd`` (plus removing the
  people with ``--masks``) and ``pose`` is ``T_world_camera`` (row-major);
- ``final.txt``: ORB-SLAM3's own ``SaveTrajectoryTUM`` after shutdown (final, BA-refined poses);
- ``done.json``: load / loop / shutdown seconds (with ``--masks``: ``segment_s`` reading the masks, ``mask_s``
  removing them, :func:`d2slam.baselines.masking.mask_frame` with the ``--config`` JSON's ``masking``), or
  ``{"error": ...}`` on a Python-level failure.
ORB-SLAM3's console output goes to the log file the parent gives as stdout.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def remove_people(seq, i: int, rgb, depth, kind: str, config):
    """Frame ``i``'s ``(rgb, depth)`` without its ``kind`` person masks (:func:`d2slam.segmentation.masks_for`,
    :func:`d2slam.baselines.masking.mask_frame` with ``config.masking``), seconds reading the masks, seconds removing
    them."""
    from d2slam.baselines.masking import mask_frame
    from d2slam.segmentation import masks_for, stack_masks

    t = time.perf_counter()
    masks = stack_masks(masks_for(seq, i, kind, config), rgb.shape[:2])
    t_mask = time.perf_counter()
    rgb, depth, _ = mask_frame(rgb, depth, masks, config.masking)
    return rgb, depth, t_mask - t, time.perf_counter() - t_mask


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--sequence", required=True)
    p.add_argument("--camera", default=None)
    p.add_argument("--vocab", required=True)
    p.add_argument("--settings", required=True)
    p.add_argument("--work", required=True)
    p.add_argument("--max-frames", type=int, default=0)
    p.add_argument("--masks", default=None, help="person masks to remove (d2slam.segmentation.masks_for kind)")
    p.add_argument("--config", default=None, help="d2slam Config as JSON (with --masks)")
    args = p.parse_args(argv)
    work = Path(args.work)
    done = work / "done.json"

    def fail(message: str, code: int) -> int:
        done.write_text(json.dumps({"error": message}))
        print(f"d2slam worker: {message}", file=sys.stderr, flush=True)
        return code

    import numpy as np

    from d2slam.data import open_sequence
    from d2slam.errors import D2SlamError

    try:
        seq = open_sequence(args.sequence, camera=args.camera) if args.camera else open_sequence(args.sequence)
    except D2SlamError as exc:
        return fail(str(exc), 3)
    config = None
    if args.masks:
        from d2slam.config import Config

        config = Config.from_dict(json.loads(Path(args.config).read_text()))
    import pyorbslam3

    t0 = time.perf_counter()
    try:
        slam = pyorbslam3.Slam(args.vocab, args.settings, pyorbslam3.Sensor.RGBD, use_viewer=False)
    except (OSError, ValueError, RuntimeError) as exc:
        return fail(f"ORB-SLAM3 did not start: {exc}", 4)
    load_s = time.perf_counter() - t0
    (work / "loaded").write_text(f"{load_s:.3f}")
    factor = np.float32(seq.camera.depth_factor)
    n = len(seq) if args.max_frames <= 0 else min(len(seq), args.max_frames)
    io_s = segment_s = mask_s = 0.0
    t_loop = time.perf_counter()
    with open(work / "progress.txt", "w") as prog:
        for i in range(n):
            t_io = time.perf_counter()
            try:
                frame = seq[i]
            except D2SlamError as exc:
                slam.shutdown()
                return fail(str(exc), 3)
            depth = frame.depth * factor  # back to sensor units: ORB-SLAM3 divides by RGBD.DepthMapFactor
            io_s += time.perf_counter() - t_io
            rgb, mask_ms = frame.rgb, 0.0
            if config is not None:
                try:
                    rgb, depth, seg_i, mask_i = remove_people(seq, i, rgb, depth, args.masks, config)
                except D2SlamError as exc:
                    slam.shutdown()
                    return fail(str(exc), 3)
                segment_s, mask_s, mask_ms = segment_s + seg_i, mask_s + mask_i, mask_i * 1000.0
            t = time.perf_counter()
            res = slam.track_rgbd(rgb, depth, frame.timestamp)
            ms = (time.perf_counter() - t) * 1000.0 + mask_ms
            pose = res.pose_wc
            pose_txt = "-" if pose is None else " ".join(f"{v:.9g}" for v in np.asarray(pose).ravel())
            prog.write(f"{i} {frame.timestamp:.6f} {int(res.state)} {ms:.3f} {int(res.num_tracked_points)} "
                       f"{pose_txt}\n")
            prog.flush()
    loop_s = time.perf_counter() - t_loop
    t = time.perf_counter()
    slam.shutdown()
    shutdown_s = time.perf_counter() - t
    # Written before saving: SaveTrajectoryTUM can crash on odd maps; the online poses are already on disk.
    info = {"load_s": load_s, "loop_s": loop_s, "io_s": io_s, "shutdown_s": shutdown_s, "frames": n}
    if config is not None:
        info.update(segment_s=segment_s, mask_s=mask_s)
    done.write_text(json.dumps(info))
    sys.stdout.flush()
    try:
        slam.save_trajectory_tum(str(work / "final.txt"))
    except Exception as exc:  # noqa: BLE001 - recorded, the online poses remain
        info["save_error"] = str(exc)
        done.write_text(json.dumps(info))
    return 0


if __name__ == "__main__":
    sys.exit(main())
