"""``d2slam bench calibration``: the fr3-named scenarios against the published record on the real TUM sequences.

Runs ``orbslam3`` and ``orbslam3-masked`` (the real ORB-SLAM3, raw and on frames with the people removed), ``semantic``
(our engine, masks only), ``none`` and ``d2slam`` on the given scenarios and seeds (a small ``d2slam study`` grid, the
real segmenter's masks, no twins) and prints, per scenario, ORB-SLAM3's ATE beside its published values and each
method's improvement over ``orbslam3`` (paired by seed) beside the published mask-based methods' (DynaSLAM, DS-SLAM,
CFP-SLAM) and the paper's Table 1, then the benchmark's targets (d2slam.study.calibration). Development seeds by
default: the study's seeds are never used to tune the benchmark."""

from __future__ import annotations

import time

from d2slam.paths import cache_dir
from d2slam.study import run_study
from d2slam.study.calibration import METHODS, calibration_checks, calibration_markdown, calibration_table
from d2slam.study.grid import FR3_SCENARIOS, ORBSLAM3
from d2slam.synth.scene import frames_arg

DESCRIPTION = "the fr3 scenarios' baselines (raw and masked ORB-SLAM3, masks-only) against the published TUM record"


def add_arguments(parser) -> None:
    parser.add_argument("--scenario", action="append", choices=FR3_SCENARIOS,
                        help="fr3 scenario (repeatable; default: all five)")
    parser.add_argument("--seed", action="append", type=int, help="seed (repeatable; default 0 1 2, development)")
    parser.add_argument("--frames", type=frames_arg, default=300, help="frames per sequence, or 'tum' (default 300)")
    parser.add_argument("--orbslam3-repeats", type=int, default=None,
                        help="ORB-SLAM3 runs per sequence (default: the study's, config baseline.orbslam3_repeats)")
    parser.add_argument("--jobs", type=int, default=2, help="parallel runs (default 2)")
    parser.add_argument("--out", default=None, help="where the runs go (default: the cache, bench/calibration)")


def run(args) -> int:
    t0 = time.perf_counter()
    scenarios = args.scenario or list(FR3_SCENARIOS)
    seeds = args.seed or [0, 1, 2]
    out = args.out or cache_dir("bench", "calibration")
    study = run_study(out, scenarios=scenarios, methods=[ORBSLAM3, *METHODS], seeds=seeds, frames=args.frames,
                      twin_methods=(), jobs=args.jobs, orbslam3_repeats=args.orbslam3_repeats, plots=False)
    table = calibration_table(study.runs)
    print(f"Improvement over `orbslam3` = (1 - ATE / ATE of orbslam3) x 100, paired by seed: median [min, max] over "
          f"seeds {', '.join(map(str, seeds))}; the real segmenter's masks. Published: the real TUM fr3 sequences "
          "(data/published_absolute.csv, data/paper_tables.csv).")
    print(calibration_markdown(table))
    checks = calibration_checks(table)
    if checks:
        print("targets:")
        for label, what, ok in checks:
            print(f"  {label:<9} {what:<40} {'met' if ok else 'NOT met'}")
    bad = study.runs[study.runs["status"] != "ok"]
    for _, r in bad.iterrows():
        print(f"  failed: {r['scenario']} seed {r['seed']} {r['method']}: {r['error']}")
    print(f"({len(study.runs)} runs in {out}; {time.perf_counter() - t0:.0f} s)")
    return 0
