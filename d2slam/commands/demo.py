"""``d2slam demo``: the main job on built-in synthetic data, end to end and small.

1. generate (or reuse) a short synthetic walking_halfsphere sequence and its static twin in the study's sequence
   cache and describe them (everything the demo writes is in the cache: it prints where);
2. run the engine on both with the keypoint filter off (``none``, the ORB-SLAM3 stand-in) and with D2SLAM
   (``d2slam``, the real segmenter's masks), evaluate with evo and print the table (a tiny ``d2slam study`` grid).
   The default (walking_halfsphere, development seed 0, 120 frames) is one where the unfiltered engine is dragged
   by the people within the first seconds (as ORB-SLAM3 is on TUM's w/half), so the table shows what the filter is
   for in about a minute; on other seeds and scenarios the people may not drag it that early.
"""

from __future__ import annotations

import pandas as pd

from d2slam.data import open_sequence
from d2slam.paths import cache_dir
from d2slam.study import run_study
from d2slam.study.sequences import ensure_sequence


def register(sub) -> None:
    p = sub.add_parser("demo", help="the main job on a short synthetic sequence: generate, run none vs d2slam, "
                       "evaluate",
                       description="Generate (or reuse) a short synthetic sequence (default walking_halfsphere) and "
                       "its static twin in the study's sequence cache, describe them, then run the engine with the "
                       "keypoint filter off (none) and with D2SLAM (d2slam, the real segmenter's masks) on both, evaluate with evo "
                       "and print ATE / RPE / keypoint F1 (a tiny `d2slam study` grid). Everything goes into the "
                       "cache ($D2SLAM_CACHE, default ~/.cache/d2slam): the sequences into study/sequences/, the "
                       "results (runs.csv, tables.md, trajectories/, runs/) into demo/study/, overwritten by the next "
                       "demo.")
    p.add_argument("--scenario", default="walking_halfsphere",
                   help="a synthetic fr3 scenario (default walking_halfsphere)")
    p.add_argument("--frames", type=int, default=120, help="frames to generate (default 120)")
    p.add_argument("--seed", type=int, default=0, help="synthetic seed (default 0, a development seed)")
    p.add_argument("--jobs", type=int, default=2, help="parallel runs (default 2)")
    p.set_defaults(func=run)


def run(args) -> int:

    root = cache_dir("demo")
    print(f"d2slam demo: sequences into {cache_dir('study', 'sequences')}, results into {root / 'study'}")
    print("\n== 1. synthetic sequences (TUM layout + masks + scene.json)")
    for twin in (False, True):
        out = ensure_sequence(args.scenario, args.seed, args.frames, twin, progress=True)
        seq = open_sequence(out)
        print(f"{len(seq)} frames of {args.scenario} (seed {args.seed}{', static twin' if twin else ''}) in {out}")
        print(f"  people ids {seq.person_ids.tolist()}, moved objects {seq.moved_object_ids.tolist()}")
        files = sorted(p.name for p in out.iterdir())
        print(f"  contents: {', '.join(files)}")

    print("\n== 2. engine without (none) and with (d2slam) the dynamic-keypoint filter, evaluated with evo")
    study = run_study(root / "study", scenarios=[args.scenario], methods=["none", "d2slam"], seeds=[args.seed],
                      frames=args.frames, twin_methods=["none", "d2slam"], jobs=args.jobs, plots=False)
    cols = ["scenario", "twin", "method", "status", "frames_tracked", "frames", "ate_rmse_m", "rpe_trans_m",
            "rpe_rot_deg", "kp_precision", "kp_recall", "kp_f1", "fps"]
    runs = study.runs[[c for c in cols if c in study.runs.columns]].astype({"frames_tracked": "Int64", "twin": bool})
    with pd.option_context("display.width", 160, "display.max_columns", 20):
        print(runs.to_string(index=False, float_format=lambda x: f"{x:.4f}"))
    r = study.runs
    ate = {(bool(t), m): a for t, m, a in zip(r["twin"], r["method"], r["ate_rmse_m"])}
    print(f"\nATE: none {ate[(False, 'none')]:.4f} m, d2slam {ate[(False, 'd2slam')]:.4f} m; "
          f"the static twin without people: none {ate[(True, 'none')]:.4f} m.")
    print(f"Results in {study.out}: runs.csv, tables.md, trajectories/, runs/ (the next demo overwrites them).")
    print("The full study: `d2slam study --out results/` (see docs/results.md).")
    return 0
