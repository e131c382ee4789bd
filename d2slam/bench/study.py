"""``d2slam bench study``: what one study run costs, and the projected time of a study grid.

Measures, on one synthetic sequence (default walking_xyz, seed 101, 100 frames; generated into the study cache if
missing), the wall time of one grid cell per method exactly as ``d2slam study`` runs it
(:func:`d2slam.study.runner.execute_run`: open, masks, engine, evo, keypoint metrics; ORB-SLAM3 with its repeats),
``--repeat`` times (report every figure: the machine is shared), and the generation speed of the synthetic
generator (single process, as the study's cache uses it) on ``--gen-frames`` frames in a temporary folder.

Projection for a grid (default: the default study, 5 scenarios x methods x 3 seeds x 300 frames + static twins):
per method, (median s per frame) x frames x runs; plus generation of the uncached sequences; divided by --jobs
(an upper bound on the speed-up: jobs share the cores, and other users' load counts).
"""

from __future__ import annotations

import tempfile
import time

import numpy as np

from d2slam.study.grid import DEFAULT_FRAMES, SCENARIOS, TWIN_METHODS, RunSpec, default_methods
from d2slam.study.runner import execute_run, run_options
from d2slam.study.sequences import ensure_sequence, is_complete, sequence_dir
from d2slam.synth import generate

DESCRIPTION = "cost of one study run per method and projected time of the default study grid"


def add_arguments(parser) -> None:
    parser.add_argument("--scenario", choices=SCENARIOS, default="walking_xyz")
    parser.add_argument("--seed", type=int, default=101)
    parser.add_argument("--frames", type=int, default=100, help="frames of the measured sequence (default 100)")
    parser.add_argument("--methods", nargs="+", default=None, help="default: every method and orbslam3")
    parser.add_argument("--repeat", type=int, default=2, help="measurements per method (default 2)")
    parser.add_argument("--orbslam3-repeats", type=int, default=None, help="default: the config's (1)")
    parser.add_argument("--gen-frames", type=int, default=30, help="frames generated to time the generator (0: skip)")
    parser.add_argument("--grid-frames", type=int, default=DEFAULT_FRAMES, help="frames of the projected grid")
    parser.add_argument("--grid-seeds", type=int, default=3)
    parser.add_argument("--grid-scenarios", type=int, default=5)
    parser.add_argument("--jobs", type=int, default=2, help="jobs of the projected study (default 2)")


def run(args) -> int:
    methods = args.methods or default_methods()
    ensure_sequence(args.scenario, args.seed, args.frames, False, progress=True)
    options = run_options(orbslam3_repeats=args.orbslam3_repeats)
    per_frame = {}
    print(f"one study run, {args.scenario} seed {args.seed}, {args.frames} frames (wall s per run; s/frame):")
    for m in methods:
        walls, status = [], None
        for _ in range(args.repeat):
            r = execute_run(RunSpec(args.scenario, m, args.seed, args.frames), options)
            walls.append(r["row"]["wall_s"])
            status = r["row"]["status"]
        per_frame[m] = float(np.median(walls)) / args.frames
        print(f"  {m:<10} " + ", ".join(f"{w:6.1f} s" for w in walls)
              + f"   -> {1000 * per_frame[m]:.0f} ms/frame (status {status})")
    gen_s_per_frame = None
    if args.gen_frames > 0:
        with tempfile.TemporaryDirectory(prefix="d2slam-bench-study-") as tmp:
            t = time.perf_counter()
            generate(args.scenario, tmp, frames=args.gen_frames, seed=args.seed, workers=1, progress=False)
            gen_s_per_frame = (time.perf_counter() - t) / args.gen_frames
        print(f"  generator (1 process): {1000 * gen_s_per_frame:.0f} ms/frame")
    # projection
    n_seq_dyn = args.grid_scenarios * args.grid_seeds
    twin_methods = [m for m in methods if m in TWIN_METHODS]
    run_s = sum(per_frame[m] * args.grid_frames * n_seq_dyn for m in methods)
    run_s += sum(per_frame[m] * args.grid_frames * n_seq_dyn for m in twin_methods)
    n_runs = n_seq_dyn * (len(methods) + len(twin_methods))
    n_seqs = n_seq_dyn * (2 if twin_methods else 1)

    cached = sum(is_complete(sequence_dir(s, seed, args.grid_frames, tw)) for s in SCENARIOS[:args.grid_scenarios]
                 for seed in (101, 102, 103)[:args.grid_seeds] for tw in ((False, True) if twin_methods else (False,)))
    gen_s = (gen_s_per_frame or 0.0) * args.grid_frames * (n_seqs - cached)
    print(f"projected grid: {args.grid_scenarios} scenarios x {len(methods)} methods x {args.grid_seeds} seeds x "
          f"{args.grid_frames} frames + twins ({', '.join(twin_methods) or 'none'}) = {n_runs} runs on {n_seqs} "
          f"sequences ({cached} cached)")
    print(f"  runs: {run_s / 60:.1f} min serial, {run_s / 60 / args.jobs:.1f} min with --jobs {args.jobs} (ideal)")
    if gen_s_per_frame is not None:
        print(f"  generation of {n_seqs - cached} sequences: {gen_s / 60:.1f} min serial, "
              f"{gen_s / 60 / args.jobs:.1f} min with --jobs {args.jobs}")
    total = (run_s + gen_s) / args.jobs
    print(f"  total with --jobs {args.jobs}: {total / 60:.1f} min (target <= 30 min: "
          f"{'met' if total <= 1800 else 'NOT met'})")
    for m in methods:
        share = per_frame[m] * args.grid_frames * n_seq_dyn * (2 if m in twin_methods else 1)
        print(f"    {m:<10} {share / 60 / args.jobs:5.1f} min")
    return 0
