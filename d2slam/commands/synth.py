"""``d2slam synth SCENARIO --out DIR``: write a synthetic TUM-like dynamic sequence (format in CONTRIBUTING.md)."""

from __future__ import annotations

import glob
import json
import os
from pathlib import Path

import numpy as np

from d2slam.cachefiles import Damaged, read_json
from d2slam.errors import D2SlamError
from d2slam.outputs import check_output_dir, check_outputs, remove_stale_temps, staged_dir
from d2slam.progress import announce
from d2slam.synth.generate import estimated_seconds, generate, worker_count
from d2slam.synth.scene import ALL_SCENARIOS, Scene, frames_arg, resolve_frames
from d2slam.synth.twin import read_recording


def register(sub) -> None:
    p = sub.add_parser(
        "synth", help="generate a synthetic TUM-like dynamic RGB-D sequence",
        description="Write a sequence in the TUM RGB-D layout (rgb/ depth/ rgb.txt depth.txt groundtruth.txt) plus "
        "mask_gt/ (object ids), mask_sim/ (simulated segmenter) and scene.json. Camera motions mirror the fr3 "
        "sequences of the same name; 30 Hz frames, ground truth at 100 Hz. Same scenario, frames and seed give "
        "byte-identical files. fr1_rpy_twin is the static synthetic twin of a real recording: the office along its "
        "ground truth, at its frame times, through its camera (lens distortion) with the sensor calibrated against "
        "fr1/rpy (--on-trajectory). real_walking (two people walk in and out of view) and real_carry (one of them "
        "carries a box) composite the people into a real recording's own colour and depth images (--on TUM_DIR): "
        "its ground truth, camera and times, its floor and free space measured from its depth, a z-test against "
        "its depth; mask_depth/ holds what its depth images show of them.")
    p.add_argument("scenario", choices=ALL_SCENARIOS)
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output folder (created; a folder holding nothing but a sequence d2slam synth wrote is "
                   f"replaced, any other non-empty one refused, naming what would be deleted; the sequence's files "
                   f"are listed in DIR/{OWNER}). Written into DIR.tmp-PID@HOST beside it and renamed at the end: an "
                   "interrupted run leaves DIR as it was")
    p.add_argument("--frames", type=frames_arg, default=None, help="number of RGB-D frames at 30 Hz (default 300; "
                   "office_loop 1200; a twin: all of its recording's), or 'tum': the duration of the TUM fr3 sequence "
                   "of that name (walking_xyz 28.8 s, ...)")
    p.add_argument("--seed", type=int, default=0, help="seed of the room, people, paths and noise (default 0)")
    p.add_argument("--static-twin", action="store_true",
                   help="same camera path and room, no people and no moved objects (all masks 0)")
    p.add_argument("--on-trajectory", "--on", metavar="TUM_DIR", default=None, dest="on_trajectory",
                   help="the scenarios on a real recording: the real TUM folder (rgb.txt, depth.txt, groundtruth.txt) "
                   "whose ground truth, frame and depth times and camera fr1_rpy_twin takes; real_walking and "
                   "real_carry composite the people into its own images (docs/real_people.md)")
    p.add_argument("--workers", type=int, default=None,
                   help="processes rendering frames (default: min(2, cores)); the files do not depend on it")
    p.set_defaults(func=run)


def summarise(result: dict) -> str:
    stats = result["stats"]
    person = np.array([s["person_fraction"] for s in stats])
    moved = np.array([s["moved_fraction"] for s in stats])
    holes = np.array([s["hole_fraction"] for s in stats])
    lines = [
        f"wrote {result['frames']} frames of {result['scenario']} (seed {result['seed']}"
        f"{', static twin' if result['static_twin'] else ''}) to {result['out']}",
        f"  people ids {result['person_ids']}, moved objects {result['moved_object_ids']}",
    ]
    for o in result["objects"]:
        if o["kind"] == "object" and o["moving_intervals"]:
            spans = ", ".join(f"[{a:.3f}, {b:.3f}]" for a, b in o["moving_intervals"])
            who = ", ".join(str(p) for p in o["moved_by"])
            lines.append(f"  {o['name']} (id {o['id']}) moved by person {who} during {spans}")
    lines += [
        f"  person pixels per frame: mean {100 * person.mean():.1f} %, max {100 * person.max():.1f} %, frames with "
        f">= 20 %: {int((person >= 0.2).sum())}",
        f"  moved-object pixels per frame: mean {100 * moved.mean():.1f} %; depth holes: mean {100 * holes.mean():.1f} %",
        f"  {result['frames'] / result['seconds']:.1f} frames/s ({result['seconds']:.1f} s, {result['workers']} workers)",
    ]
    return "\n".join(lines)


# The marker ``d2slam synth`` writes into its sequence: the files it wrote (``files``, relative paths) and what it
# generated. A folder is replaced only when everything in it is listed there.
OWNER = ".d2slam-synth"
OWNER_FORMAT = "d2slam-synth-owner/1"
# A sequence written before the marker existed (``scene.json``, no marker): only the synthetic layout, PNGs in its
# image folders, counts as the sequence's.
LAYOUT_FILES = ("rgb.txt", "depth.txt", "groundtruth.txt", "scene.json")
LAYOUT_DIRS = ("rgb", "depth", "mask_gt", "mask_sim")


def _entries(folder: Path) -> tuple[list[str], list[str]]:
    """(files, folders) under ``folder``, relative, links not followed (a link counts as a file)."""
    files, dirs = [], []
    for top, subdirs, names in os.walk(folder, followlinks=False):
        rel = Path(top).relative_to(folder)
        for d in list(subdirs):
            if (Path(top) / d).is_symlink():
                subdirs.remove(d)
                files.append((rel / d).as_posix())
            else:
                dirs.append((rel / d).as_posix())
        files += [(rel / n).as_posix() for n in names]
    return sorted(files), sorted(dirs)


def foreign_entries(folder: Path) -> list[str]:
    """What replacing ``folder`` would delete that ``d2slam synth`` did not write: everything not listed in its
    marker (:data:`OWNER`); without a readable marker, everything outside the synthetic layout when it holds
    ``scene.json`` (a sequence of an earlier version), else everything."""
    files, dirs = _entries(folder)
    try:
        listed = read_json(folder / OWNER).get("files")
        ours = set(listed) | {OWNER} if isinstance(listed, list) else None
    except (FileNotFoundError, Damaged):
        ours = None
    if ours is None and (folder / "scene.json").is_file():
        ours = {f for f in files if f in LAYOUT_FILES or (
            f.count("/") == 1 and f.split("/")[0] in LAYOUT_DIRS and f.endswith(".png"))}
    ours = ours or set()
    holding = {q.as_posix() for f in ours for q in Path(f).parents}  # folders holding some of ours
    foreign_dirs = [d for d in dirs if d not in holding]
    top = [d for d in foreign_dirs if not any(Path(d).is_relative_to(o) and d != o for o in foreign_dirs)]
    inside = lambda f: any(Path(f).is_relative_to(d) for d in top)  # noqa: E731
    return sorted([d + "/" for d in top] + [f for f in files if f not in ours and not inside(f)])


def check_sequence_out(path) -> Path:
    """``--out`` before any work: a folder that is missing, empty, or holds nothing but a sequence ``d2slam synth``
    wrote (then replaced: :func:`foreign_entries` is empty); anything else is refused, naming what would be deleted.
    Not inside another sequence, the cache's own folders or the shared folder (:func:`d2slam.outputs.check_outputs`)."""
    path = check_output_dir(path, "--out")
    if path.is_symlink():  # write where the link points, not over the link
        path = path.resolve()
    check_outputs([("--out", path)], folders=True, own_sequence=path)
    if path.is_dir():
        foreign = foreign_entries(path)
        if foreign:
            shown = ", ".join(foreign[:5]) + (f" and {len(foreign) - 5} more" if len(foreign) > 5 else "")
            raise D2SlamError(f"--out: the folder holds what d2slam synth did not write ({shown}); replacing it would "
                              "delete them: move them away or give another --out", path=path)
    return path


def write_owner(folder: Path, result: dict) -> None:
    """The marker of a sequence just generated into ``folder``: every file there, and what was generated."""
    files, _ = _entries(folder)
    what = {k: result[k] for k in ("scenario", "seed", "frames", "static_twin") if k in result}
    (folder / OWNER).write_text(json.dumps({"format": OWNER_FORMAT, **what, "files": files}, indent=1) + "\n")


def run(args) -> int:
    out = check_sequence_out(args.out)
    Scene.check_recording(args.scenario, args.on_trajectory)
    Scene.check_static_twin(args.scenario, args.static_twin)
    recording = read_recording(args.on_trajectory) if args.on_trajectory is not None else None
    frames = resolve_frames(args.scenario, args.frames, recorded=len(recording) if recording is not None else None)
    remove_stale_temps(out.parent, f"{glob.escape(out.name)}.tmp-*")  # an earlier run killed before it cleaned up
    workers = worker_count(frames, args.workers)
    on = f" on {recording.name}" if recording is not None else ""
    announce(f"generating {frames} frames of {args.scenario}{on} (seed {args.seed}"
             f"{', static twin' if args.static_twin else ''}) into {out} with {workers} "
             f"worker{'s' if workers > 1 else ''}",
             estimated_seconds(frames, args.workers, twin=recording is not None, scenario=args.scenario))
    with staged_dir(out) as tmp:
        result = generate(args.scenario, tmp, frames=frames, seed=args.seed, static_twin=args.static_twin,
                          workers=args.workers, recording=recording)
        write_owner(tmp, result)
    print(summarise({**result, "out": out}))
    return 0
