"""``d2slam bench synth``: generation speed of the synthetic benchmark, PNG writing included.

Generates a sequence (default: 300 frames of walking_xyz, 640x480) into a temporary folder with the normal process
pool and prints frames per second over the whole run (scene set-up, worker start, rendering, sensor model,
simulated segmenter, PNG writing), the mean per-frame time of each stage (measured inside the workers, so
the stages of concurrent workers overlap in wall time) and the CPU time: by stage (bodies: posing and uploading the
people; gl: the two OpenGL passes; sensor; segmenter; write: the four PNGs), per frame inside the workers (median: a
frame in the steady state; mean: with each worker's first frame, which loads the body model and compiles the
shaders) and in all (this process and its workers, start-up included), which a loaded machine does not inflate as
it does the wall times. Target: >= 10 frames/s on a 2-core machine."""

from __future__ import annotations

import resource
import tempfile

import numpy as np

from d2slam.synth.generate import generate
from d2slam.synth.scene import SCENARIOS

DESCRIPTION = "synthetic sequence generation speed (frames/s including PNG writing; ms per stage)"
TARGET_FPS = 10.0


def add_arguments(parser) -> None:
    parser.add_argument("--scenario", choices=SCENARIOS, default="walking_xyz")
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=None, help="default: min(2, cores)")
    parser.add_argument("--static-twin", action="store_true")


def cpu_seconds() -> float:
    """User + system CPU time of this process and of its children that ended (the generator's workers)."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def run(args) -> int:
    cpu0 = cpu_seconds()
    with tempfile.TemporaryDirectory(prefix="d2slam-bench-synth-") as tmp:
        r = generate(args.scenario, tmp, frames=args.frames, seed=args.seed, static_twin=args.static_twin,
                     workers=args.workers, progress=False)
    cpu_all = cpu_seconds() - cpu0
    fps = r["frames"] / r["seconds"]
    ms = {k: float(np.mean([s["ms"][k] for s in r["stats"]])) for k in r["stats"][0]["ms"]}
    per_frame = sum(ms.values())
    print(f"synth {args.scenario}{' (static twin)' if args.static_twin else ''}: {r['frames']} frames 640x480, "
          f"{r['workers']} workers")
    print(f"  total {r['seconds']:.2f} s (scene set-up {r['seconds_scene']:.2f} s) -> {fps:.1f} frames/s "
          f"(target >= {TARGET_FPS:.0f}: {'met' if fps >= TARGET_FPS else 'NOT met'})")
    print("  per frame and worker: " + ", ".join(f"{k} {v:.1f} ms" for k, v in ms.items())
          + f" = {per_frame:.1f} ms")
    split = {k: float(np.median([s["stage_cpu_ms"][k] for s in r["stats"]])) for k in r["stats"][0]["stage_cpu_ms"]}
    print("  CPU per frame by stage (median): " + ", ".join(f"{k} {v:.1f} ms" for k, v in split.items())
          + " (gl: the colour and id passes, their read-back included)")
    cpu = np.array([s["cpu_ms"] for s in r["stats"]])
    print(f"  CPU time per frame inside the workers: median {np.median(cpu):.1f} ms, mean {cpu.mean():.1f} ms "
          f"(with each worker's first frame); wall/CPU ratio {per_frame / cpu.mean():.2f} (> 1 when other processes "
          f"compete for the cores)")
    print(f"  CPU time in all (this process and its workers, start-up included): {cpu_all:.1f} s = "
          f"{1e3 * cpu_all / r['frames']:.1f} ms per frame")
    person = np.array([s["person_fraction"] for s in r["stats"]])
    print(f"  person pixels: mean {100 * person.mean():.1f} %, max {100 * person.max():.1f} %")
    return 0
