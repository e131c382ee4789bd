"""``d2slam study --out results/``: the reproducible study (grid of scenarios x methods x seeds, static twins)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

from d2slam.config import load_config_file
from d2slam.errors import D2SlamError
from d2slam.outputs import check_output_dir, check_outputs
from d2slam.run.methods import methods as registered
from d2slam.study import grid as G, run_study
from d2slam.study.core import composite_cached, rebuild_tables
from d2slam.study.grid import DEFAULT_FRAMES, DEFAULT_SEEDS, SCENARIOS, TUM_FOLDERS, TWIN_METHODS
from d2slam.study.sequences import is_complete, sequence_dir
from d2slam.synth.scene import frames_arg

ENV_TUM = "D2SLAM_TUM_ROOT"


def register(sub) -> None:
    p = sub.add_parser(
        "study", help="run the study grid and write runs.csv, summary.csv, tables.md, plots, manifest.json",
        description="Run every (scenario, method, seed) of the grid on synthetic TUM-like sequences (generated once "
        "into the cache, keyed by scenario/seed/frames/generator version) and on their static twins (methods of "
        "--twin-methods), evaluate each run with evo (ATE, 1-second RPE) and the keypoint truth, and write "
        "OUT/runs.csv (one row per run, grid order; timing columns last), OUT/summary.csv (median, min, max over "
        "seeds), OUT/tables.md (the paper's Tables 1-3 as improvement over `none` and, when run, over real "
        "ORB-SLAM3, absolute values, static-twin ratios, keypoint F1), OUT/plots/*.png, OUT/trajectories/, "
        "OUT/runs/*.json and OUT/manifest.json. A failed run is a row with status=failed and its error.")
    p.add_argument("--out", required=True, metavar="DIR", help="results folder (created)")
    p.add_argument("--scenarios", nargs="+", choices=SCENARIOS, default=None, metavar="SCENARIO",
                   help=f"default: all ({', '.join(SCENARIOS)}; carry, push and office_loop are ours, not TUM's; "
                   "office_loop always runs at its own length, whatever --frames; fr1_rpy is the real TUM fr1/rpy, "
                   "each method once over all its frames, when `d2slam assets fetch --full-real` has fetched it)")
    p.add_argument("--methods", nargs="+", default=None, metavar="METHOD",
                   help="default: every registered method and orbslam3 (real ORB-SLAM3)")
    p.add_argument("--seeds", nargs="+", type=int, default=list(DEFAULT_SEEDS), metavar="SEED",
                   help=f"default: {' '.join(map(str, DEFAULT_SEEDS))} (the study seeds, never tuned on)")
    p.add_argument("--frames", type=frames_arg, default=DEFAULT_FRAMES, help=f"frames per sequence (default "
                   f"{DEFAULT_FRAMES}; >= 40 so that 1-second RPE pairs exist; 'tum': each scenario at the duration "
                   "of its TUM fr3 sequence; on TUM data: first N frames, 0 = all)")
    p.add_argument("--twin-methods", nargs="*", default=list(TWIN_METHODS), metavar="METHOD",
                   help="methods also run on each static twin (default: none d2slam oracle; oracle there reads the "
                   "dynamic sequence's truth: the occluded twin; give none of them to skip)")
    p.add_argument("--jobs", "-j", type=int, default=min(2, os.cpu_count() or 1),
                   help="local worker processes (joblib/loky, single-threaded BLAS and OpenCV each; 1 = serial in "
                   "this process; default min(2, cores)). The numbers do not depend on it")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT", default=None,
                   help="run the grid on a dask.distributed cluster instead: every worker with this checkout and "
                   "environment (checked before the first phase) and the same cache folder ($D2SLAM_CACHE on a "
                   "shared filesystem); docs/study.md, 'The study on a Dask cluster'")
    p.add_argument("--no-online", action="store_true",
                   help="without the online runs (default: none, d2slam and orbslam3 also run online, `d2slam run "
                   "--online` at online.rate_hz, on the fr3 walking scenarios and fr1_rpy; after every other run, one "
                   "at a time in this process, never on --scheduler's workers; an online d2slam segments its frames "
                   "with the real segmenter in its own thread, whatever --masks; docs/study.md, 'Online runs')")
    p.add_argument("--orbslam3-repeats", type=int, default=None, help="ORB-SLAM3 runs per sequence (not "
                   "deterministic: median and spread reported; default: config baseline.orbslam3_repeats, 3)")
    p.add_argument("--masks", choices=["gt", "sim", "onnx", "truth"], default=None,
                   help="person masks (default: onnx, the real segmenter through the mask cache; the oracle always "
                   "uses truth, d2slam-sim the simulated segmenter)")
    p.add_argument("--tum-root", metavar="DIR", default=None,
                   help=f"run on a real TUM copy (folders rgbd_dataset_freiburg3_*) instead of synthetic data "
                   f"(default ${ENV_TUM} only when --tum is given)")
    p.add_argument("--tum", action="store_true", help=f"use the TUM copy at ${ENV_TUM}")
    p.add_argument("--resume", action="store_true",
                   help="reuse the runs already in OUT/runs/ whose key matches (same run, config, masks, generator "
                   "version, source of the code computing it, package versions; failed runs are redone)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    p.add_argument("--tables-only", action="store_true",
                   help="re-render OUT/tables.md and OUT/summary.csv from an existing OUT/runs.csv; run nothing")
    p.add_argument("--dry-run", action="store_true", help="print the grid and which sequences are cached; run nothing")
    p.add_argument("--config", metavar="FILE.yaml", default=None,
                   help="override config fields for every run, as `d2slam run --config` does (a YAML of `section: "
                   "{field: value}`); with --resume only the runs that read a changed field run again")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def run(args) -> int:
    out = Path(args.out)
    if args.tables_only:
        if not (out / "runs.csv").is_file():
            raise D2SlamError("no runs.csv to build tables from", path=out / "runs.csv")
        print(f"wrote {rebuild_tables(out)}")
        return 0
    tum_root = args.tum_root
    if args.tum and not tum_root:
        tum_root = os.environ.get(ENV_TUM)
        if not tum_root:
            raise D2SlamError(f"--tum needs ${ENV_TUM} pointing at a TUM RGB-D copy")
    check_output_dir(out, "--out")
    check_outputs([("--out", out)], [("TUM root", tum_root), ("--config", args.config)], folders=True)
    scenarios = args.scenarios
    if scenarios is None:
        scenarios = G.default_scenarios()
        skipped = [s for s in G.REAL_SCENARIOS if s not in scenarios]
        if skipped and not tum_root:
            print(f"d2slam study: the real recording(s) {', '.join(skipped)} left out: not in the cache "
                  "(`d2slam assets fetch --full-real` fetches them)", file=sys.stderr)
    if tum_root:  # a real TUM copy has the fr3 sequences only
        ours = [s for s in scenarios if s not in G.FR3_SCENARIOS]
        if ours and args.scenarios is not None:
            raise D2SlamError(f"{', '.join(ours)} is ours, not a TUM sequence: give fr3 scenarios with --tum-root")
        scenarios = _downloaded(tum_root, [s for s in scenarios if s in G.FR3_SCENARIOS])
    methods = args.methods or G.default_methods("tum" if tum_root else "synth")

    unknown = [m for m in methods if m not in registered() and m != G.ORBSLAM3]
    if unknown:
        raise D2SlamError(f"unknown method(s) {', '.join(unknown)}; choose from "
                          f"{', '.join(registered() + [G.ORBSLAM3])}")
    if not tum_root and args.frames != "tum" and args.frames < 40:
        raise D2SlamError(f"--frames {args.frames} is too short: RPE needs 1-second pairs (>= 40 frames at 30 Hz)")
    if args.jobs < 1:
        raise D2SlamError(f"--jobs must be >= 1, got {args.jobs}")
    specs = G.expand_grid(scenarios, args.methods, args.seeds, args.frames, args.twin_methods,
                          source="tum" if tum_root else "synth",
                          online_methods=() if args.no_online else None)
    if args.dry_run:
        return _dry_run(specs)

    config = load_config_file(args.config)[0] if args.config else None
    res = run_study(out, specs=specs, jobs=args.jobs, scheduler=args.scheduler, tum_root=tum_root, config=config,
                    masks=args.masks, orbslam3_repeats=args.orbslam3_repeats, plots=not args.no_plots,
                    progress=False if args.quiet else None, resume=args.resume)
    df = res.runs
    n_ok = int((df["status"] == "ok").sum())
    print(f"{len(df)} runs: {n_ok} ok, {int((df['status'] == 'failed').sum())} failed, "
          f"{len(df) - n_ok - int((df['status'] == 'failed').sum())} other (see tables.md, 'Runs without metrics')")
    for name, path in res.files.items():
        print(f"  {name}: {path}")
    if res.manifest["grid"].get("reused_runs"):
        print(f"  {len(res.manifest['grid']['reused_runs'])} runs reused from {out / 'runs'} (--resume)")
    print(f"  {res.manifest['timing'].get('total_s', 0):.0f} s ({_where(res.manifest['executor'], args.jobs)})")
    if n_ok == 0:
        print("d2slam: error: no run succeeded (see the 'error' column of runs.csv)", file=sys.stderr)
        return 1
    return 0


def _where(executor: dict, jobs: int) -> str:
    """The executor the study ran on, in words: ``serial, jobs 1``, ``dask, 2 workers at tcp://HOST:PORT``."""
    n = executor.get("workers")
    return (f"{executor['executor']}, " + (f"{n} worker{'s' if n > 1 else ''} at {executor['scheduler']}" if n
                                           else f"jobs {jobs}"))


def _downloaded(tum_root, scenarios: list[str]) -> list[str]:
    """The scenarios whose fr3 folder is under ``tum_root``; the others are listed as skipped (not downloaded).
    A missing root, or one holding none of them, is an error."""
    root = Path(tum_root).expanduser()
    if not root.is_dir():
        raise D2SlamError("--tum-root: folder not found", path=root)
    present = [s for s in scenarios if (root / TUM_FOLDERS[s]).is_dir()]
    skipped = [TUM_FOLDERS[s] for s in scenarios if s not in present]
    if not present:
        raise D2SlamError(f"--tum-root holds none of the sequences ({', '.join(skipped)}); `d2slam download` "
                          "fetches them", path=root)
    if skipped:
        print(f"skipped (not under {root}; `d2slam download` fetches them): {', '.join(skipped)}")
    return present


def _dry_run(specs) -> int:
    keys = list(dict.fromkeys(s.sequence_key for s in specs))
    cached = [k for k in keys if (k[0] == "synth" and is_complete(sequence_dir(*k[1:])))
              or (k[0] == "composite" and not k[4] and composite_cached(k))]
    real = [k for k in keys if k[0] in ("tum", "real") or (k[0] == "composite" and k[4])]
    print(f"{len(specs)} runs on {len(keys)} sequences ({len(cached)} already cached"
          + (f"; {len(real)} of them real recordings" if real else "") + ")")
    for s in specs:
        print(f"  {s.run_id}")
    return 0
