"""Child process that runs the real ORB-SLAM3 (pyorbslam3) on one sequence; started by
:func:`d2slam.baselines.orbslam3.orbslam3_report`, never by users.

ORB-SLAM3 calls ``exit(-1)`` on a bad settings file, accepts a garbage vocabulary and then crashes, and runs
threads: it lives in this process so that the caller survives and can time it out. Each run gets a fresh process
(a fresh ``ORB_SLAM3::System``): ``System::Reset`` leaves the loop closer's pending candidates and the previous
maps alive, so a reused system is not the system a fresh run gets.

Frames come from ``--frames DIR`` (a frame store: the frames decoded once by the caller, people already removed with
``--masks``, shared by the repeats: :func:`write_frame_store`) or are decoded here from ``--sequence``.

Protocol (files in ``--work``):

- ``loaded``: the vocabulary load's seconds, written once ORB-SLAM3 has started;
- ``progress.txt``: one line per frame, flushed: ``index timestamp state ms n_tracked pose(16 values | -)``
  where ``state`` is ORB-SLAM3's ``TrackingState`` value, ``ms`` the time of ``track_rgbd`` (plus removing the
  people with ``--masks``; a frame store's masking time is added by the caller) and ``pose`` is ``T_world_camera``
  (row-major);
- ``final.txt``: ORB-SLAM3's own ``SaveTrajectoryTUM`` after shutdown (final, BA-refined poses);
- ``done.json``: seconds ``start_s`` (the module's start to ORB-SLAM3's construction: imports, frame source),
  ``load_s`` (the construction: the vocabulary), ``loop_s`` (the frame loop), ``io_s`` (in it, decoding or mapping
  the frames), ``shutdown_s``, ``save_s``, and ``cpu_s`` (the process's CPU seconds, every thread) (with
  ``--masks``: ``segment_s`` reading the masks, ``mask_s`` removing them,
  :func:`d2slam.baselines.masking.mask_frame` with the ``--config`` JSON's ``masking``), or ``{"error": ...}`` on
  a Python-level failure.
ORB-SLAM3's console output goes to the log file the parent gives as stdout.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from d2slam.baselines.config import MaskedFramesConfig
from d2slam.baselines.masking import mask_frame
from d2slam.data import open_sequence
from d2slam.data.live import arrival_times, newest_arrived
from d2slam.errors import D2SlamError
from d2slam.ranges import build_section
from d2slam.segmentation import masks_for, stack_masks

T_START = time.perf_counter()  # the interpreter's own start-up precedes this; the parent measures the whole


def remove_people(seq, i: int, rgb, depth, kind: str, config):
    """Frame ``i``'s ``(rgb, depth)`` without its ``kind`` person masks (:func:`d2slam.segmentation.masks_for`,
    :func:`d2slam.baselines.masking.mask_frame` with ``config.masking``), seconds reading the masks, seconds removing
    them."""
    t = time.perf_counter()
    masks = stack_masks(masks_for(seq, i, kind, config), rgb.shape[:2])
    t_mask = time.perf_counter()
    rgb, depth, _ = mask_frame(rgb, depth, masks, config.masking)
    return rgb, depth, t_mask - t, time.perf_counter() - t_mask


def sequence_frame(seq, i: int, masks: str | None = None, config=None):
    """What ORB-SLAM3 is given for frame ``i``: ``(timestamp, rgb, depth, io_s, segment_s, mask_s)`` with the RGB
    image in RGB order (the settings say ``Camera.RGB: 1``) and the depth back in sensor units (ORB-SLAM3 divides by
    ``RGBD.DepthMapFactor``), the people removed when ``masks`` is given. Raises the reader's D2SlamError."""
    t = time.perf_counter()
    frame = seq[i]
    depth = frame.depth * np.float32(seq.camera.depth_factor)
    io_s = time.perf_counter() - t
    rgb, seg_s, mask_s = frame.rgb, 0.0, 0.0
    if masks is not None:
        rgb, depth, seg_s, mask_s = remove_people(seq, i, rgb, depth, masks, config)
    return frame.timestamp, rgb, depth, io_s, seg_s, mask_s


# --------------------------------------------------------------------------------------------------
# Frame store: frames decoded once, mapped by every repeat
# --------------------------------------------------------------------------------------------------
STORE_META = "frames.json"


def write_frame_store(seq, n: int, root: Path, masks: str | None = None, config=None, progress: bool = False) -> dict:
    """Decode frames ``0..n-1`` of ``seq`` once into ``root`` (``rgb.npy`` uint8 (n, H, W, 3), ``depth.npy``
    float32 (n, H, W) in sensor units, ``timestamps.npy``, ``mask_ms.npy`` and ``frames.json``): exactly the arrays
    :func:`sequence_frame` gives ORB-SLAM3. A frame that cannot be read ends the store there: ``frames`` counts the
    frames before it and ``error`` holds the reader's message (the worker tracks those, then fails with it, as it
    does when it decodes). Returns the meta dict (``io_s``, ``segment_s``, ``mask_s``, ``cpu_s``)."""
    cpu0 = time.process_time()
    root.mkdir(parents=True, exist_ok=True)
    h, w = int(seq.camera.height), int(seq.camera.width)
    rgb = np.lib.format.open_memmap(root / "rgb.npy", mode="w+", dtype=np.uint8, shape=(n, h, w, 3))
    depth = np.lib.format.open_memmap(root / "depth.npy", mode="w+", dtype=np.float32, shape=(n, h, w))
    stamps, mask_ms = np.zeros(n), np.zeros(n)
    meta = {"frames": 0, "frames_expected": n, "io_s": 0.0, "segment_s": 0.0, "mask_s": 0.0, "error": None}
    for i in tqdm(range(n), desc="decode frames", unit="frame", disable=None if progress else True):
        try:
            stamps[i], rgb[i], depth[i], io_s, seg_s, mask_s = sequence_frame(seq, i, masks, config)
        except D2SlamError as exc:
            meta["error"] = str(exc)
            break
        meta["io_s"] += io_s
        meta["segment_s"] += seg_s
        meta["mask_s"] += mask_s
        mask_ms[i] = 1000.0 * mask_s
        meta["frames"] = i + 1
    rgb.flush()
    depth.flush()
    del rgb, depth
    np.save(root / "timestamps.npy", stamps)
    np.save(root / "mask_ms.npy", mask_ms)
    meta["cpu_s"] = time.process_time() - cpu0
    (root / STORE_META).write_text(json.dumps(meta))
    return meta


def store_frames(root: Path):
    """The frames of a store (opened now), as :func:`sequence_frame` tuples (``io_s`` = mapping the arrays), then,
    if the store ended on an unreadable frame, its error as a D2SlamError."""
    meta = json.loads((root / STORE_META).read_text())
    rgb = np.load(root / "rgb.npy", mmap_mode="r")
    depth = np.load(root / "depth.npy", mmap_mode="r")
    stamps = np.load(root / "timestamps.npy")

    def frames():
        for i in range(meta["frames"]):
            t = time.perf_counter()
            frame = float(stamps[i]), np.ascontiguousarray(rgb[i]), np.ascontiguousarray(depth[i])
            yield (*frame, time.perf_counter() - t, 0.0, 0.0)
        if meta["error"]:
            raise D2SlamError(meta["error"])

    return frames()


def online_frames(root: Path, rate_hz: float, log):
    """The frames of a store (decoded before the clock starts, as a camera driver delivers them; memory-backed in
    ``/dev/shm`` where it has room) as a live camera gives them (:mod:`d2slam.data.live`): each time the tracker asks, the
    newest frame that has arrived (waiting for the next one when it has taken the newest), every older one dropped;
    ``log`` gets ``index arrival_s taken_s done_s`` per frame given (seconds from the first arrival; done: when the
    tracker asks again), then ``frames N``."""
    meta = json.loads((root / STORE_META).read_text())
    rgb = np.load(root / "rgb.npy", mmap_mode="r")
    depth = np.load(root / "depth.npy", mmap_mode="r")
    stamps = np.load(root / "timestamps.npy")[:meta["frames"]]
    arrival = arrival_times(stamps, rate_hz)

    def frames():
        t0 = time.perf_counter()
        nxt, given = 0, None
        while nxt < len(stamps):
            elapsed = time.perf_counter() - t0
            if given is not None:  # the tracker asks for the next frame: the one given is done
                log.write(f"{given[0]} {given[1]:.6f} {given[2]:.6f} {elapsed:.6f}\n")
                given = None
            i = newest_arrived(arrival, elapsed)
            if i < nxt:
                time.sleep(max(0.0, arrival[nxt] - elapsed))
                continue
            given = (i, arrival[i], time.perf_counter() - t0)
            yield float(stamps[i]), np.ascontiguousarray(rgb[i]), np.ascontiguousarray(depth[i]), 0.0, 0.0, 0.0
            nxt = i + 1
        if given is not None:
            log.write(f"{given[0]} {given[1]:.6f} {given[2]:.6f} {time.perf_counter() - t0:.6f}\n")
        log.write(f"frames {len(stamps)}\n")

    return frames()


def _sequence_frames(args):
    """The frames of ``--sequence`` (opened now: a bad folder fails before ORB-SLAM3 starts), decoded one by one."""
    seq = open_sequence(args.sequence, camera=args.camera) if args.camera else open_sequence(args.sequence)
    config = None
    if args.masks:
        config = build_section(MaskedFramesConfig, json.loads(Path(args.config).read_text()), "config")
    n = len(seq) if args.max_frames <= 0 else min(len(seq), args.max_frames)
    return (sequence_frame(seq, i, args.masks, config) for i in range(n))


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    work = Path(args.work)
    done = work / "done.json"

    def fail(message: str, code: int) -> int:
        done.write_text(json.dumps({"error": message}))
        print(f"d2slam worker: {message}", file=sys.stderr, flush=True)
        return code

    online_log = None
    try:
        if args.online_rate is not None:
            if not args.frames:
                return fail("--online-rate needs --frames", 3)
            online_log = open(work / "online.txt", "w")
        else:
            frames = store_frames(Path(args.frames)) if args.frames else _sequence_frames(args)
    except D2SlamError as exc:
        return fail(str(exc), 3)
    import pyorbslam3

    t0 = time.perf_counter()
    start_s = t0 - T_START
    try:
        slam = pyorbslam3.Slam(args.vocab, args.settings, pyorbslam3.Sensor.RGBD, use_viewer=False)
    except (OSError, ValueError, RuntimeError) as exc:
        return fail(f"ORB-SLAM3 did not start: {exc}", 4)
    load_s = time.perf_counter() - t0
    (work / "loaded").write_text(f"{load_s:.3f}")
    if online_log is not None:  # the camera starts once ORB-SLAM3 is ready, as ours starts after its warm-up
        frames = online_frames(Path(args.frames), args.online_rate, online_log)
    t_loop = time.perf_counter()
    try:
        n, io_s, segment_s, mask_s = _track(slam, frames, work / "progress.txt")
    except D2SlamError as exc:
        slam.shutdown()
        return fail(str(exc), 3)
    loop_s = time.perf_counter() - t_loop
    if online_log is not None:
        online_log.close()
    t = time.perf_counter()
    slam.shutdown()
    shutdown_s = time.perf_counter() - t
    # Written before saving: SaveTrajectoryTUM can crash on odd maps; the online poses are already on disk.
    info = {"start_s": start_s, "load_s": load_s, "loop_s": loop_s, "io_s": io_s, "shutdown_s": shutdown_s,
            "frames": n}
    if args.masks:
        info.update(segment_s=segment_s, mask_s=mask_s)
    done.write_text(json.dumps(info))
    sys.stdout.flush()
    t = time.perf_counter()
    try:
        slam.save_trajectory_tum(str(work / "final.txt"))
    except Exception as exc:  # noqa: BLE001 - recorded, the online poses remain
        info["save_error"] = str(exc)
    usage = resource.getrusage(resource.RUSAGE_SELF)
    info.update(save_s=time.perf_counter() - t, cpu_s=usage.ru_utime + usage.ru_stime)
    done.write_text(json.dumps(info))
    return 0


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser()
    p.add_argument("--sequence", default=None)
    p.add_argument("--frames", default=None, help="a frame store (write_frame_store) instead of --sequence")
    p.add_argument("--camera", default=None)
    p.add_argument("--vocab", required=True)
    p.add_argument("--settings", required=True)
    p.add_argument("--work", required=True)
    p.add_argument("--max-frames", type=int, default=0)
    p.add_argument("--masks", default=None, help="person masks to remove (d2slam.segmentation.masks_for kind)")
    p.add_argument("--config", default=None,
                   help="the masks' and the fill's settings (MaskedFramesConfig) as JSON (with --masks)")
    p.add_argument("--online-rate", type=float, default=None,
                   help="with --frames: replay the store as a live camera at this rate (0: its timestamps), "
                   "dropping the frames that arrive while ORB-SLAM3 is busy (d2slam.data.live); online.txt")
    return p


def _track(slam, frames, progress: Path) -> tuple[int, float, float, float]:
    """Every frame through ORB-SLAM3, one line each in ``progress`` (index, timestamp, state, milliseconds, tracked
    points, the pose or -) as it is tracked; (frames, seconds reading, segmenting, removing the people). A frame
    that cannot be read raises the reader's D2SlamError."""
    n = io_s = segment_s = mask_s = 0.0
    with open(progress, "w") as prog:
        i = 0
        for timestamp, rgb, depth, io_i, seg_i, mask_i in frames:
            io_s, segment_s, mask_s = io_s + io_i, segment_s + seg_i, mask_s + mask_i
            t = time.perf_counter()
            res = slam.track_rgbd(rgb, depth, timestamp)
            ms = (time.perf_counter() - t + mask_i) * 1000.0
            pose = res.pose_wc
            pose_txt = "-" if pose is None else " ".join(f"{v:.9g}" for v in np.asarray(pose).ravel())
            prog.write(f"{i} {timestamp:.6f} {int(res.state)} {ms:.3f} {int(res.num_tracked_points)} {pose_txt}\n")
            prog.flush()
            i += 1
        n = i
    return n, io_s, segment_s, mask_s


if __name__ == "__main__":
    sys.exit(main())
