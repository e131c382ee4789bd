"""``d2slam bench orbslam3_vs_engine``: the real ORB-SLAM3 (pyorbslam3) against our engine's ``none`` method, side by
side on the same synthetic sequences: the static twins and the walking scenarios (benchmark seeds 101, 102, 103: never
tuned on). Figures: status, tracked frames, ATE RMSE, RPE (translation m, rotation deg over 1 s pairs; evo via
:mod:`d2slam.eval.trajectory`), ms per frame. ORB-SLAM3 is not deterministic (threads): ``--repeats N`` runs it N times
and prints the median with the [min, max] spread. Sequences come from the study's cache (keyed by the generator
version)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from d2slam.baselines.orbslam3 import evaluate_trajectory
from d2slam.config import DEFAULT, load_config_file
from d2slam.data import open_sequence
from d2slam.errors import D2SlamError
from d2slam.outputs import check_output_dir
from d2slam.paths import cache_dir
from d2slam.run.orbslam3_runs import run_orbslam3
from d2slam.run.record import EXIT_FRAGMENT
from d2slam.study.sequences import ensure_sequence, sequence_dir

DESCRIPTION = ("real ORB-SLAM3 (pyorbslam3) vs our `none` engine on static twins and walking scenarios: "
               "ATE, RPE, tracked frames, ms per frame")
SCENARIOS = ("walking_xyz", "walking_static", "walking_halfsphere", "walking_rpy")
METHODS = ("orbslam3", "none")


def add_arguments(parser) -> None:
    parser.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), metavar="SCENARIO")
    parser.add_argument("--seeds", nargs="+", type=int, default=[101], metavar="SEED")
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--variants", nargs="+", choices=("twin", "dynamic"), default=["twin", "dynamic"],
                        help="static twin (no people, no moved objects) and/or the dynamic sequence")
    parser.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS))
    parser.add_argument("--repeats", type=int, default=1, help="ORB-SLAM3 runs per sequence (median, spread)")
    parser.add_argument("--vocab", default=None, help="DBoW2 text vocabulary (default: $PYORBSLAM3_VOCAB or the "
                        "project-built one)")
    parser.add_argument("--config", default=None, metavar="FILE.yaml",
                        help="config overrides for ORB-SLAM3's runs, e.g. `baseline: {orbslam3_frame_store_mb: 0}` "
                        "(every repeat decodes its own frames)")
    parser.add_argument("--out", default=None, help="output folder (default: the d2slam cache)")
    parser.add_argument("--regenerate", action="store_true",
                        help="generate the sequences again (the cache is already keyed by the generator version)")


def _sequence(scenario: str, seed: int, frames: int, twin: bool, regenerate: bool = False) -> Path:
    """The benchmark sequence: the study's cached copy, keyed by the generator version (a generator change makes a
    new one), shared with `d2slam study` and `d2slam bench engine`."""
    if regenerate and sequence_dir(scenario, seed, frames, twin).exists():
        shutil.rmtree(sequence_dir(scenario, seed, frames, twin))
    return ensure_sequence(scenario, seed, frames, twin)


def _run_engine(seq: Path, out: Path) -> dict:
    """Our engine, ``d2slam run SEQ --method none``, in a child process (a crash is recorded, not raised)."""
    traj, run_json = out / "none.txt", out / "none.json"
    for p in (traj, run_json):
        p.unlink(missing_ok=True)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "d2slam.cli", "run", str(seq), "--method", "none", "--out",
                           str(traj), "--metrics-json", str(run_json)], capture_output=True, text=True)
    wall = time.perf_counter() - t0

    if proc.returncode not in (0, EXIT_FRAGMENT) or not run_json.is_file():
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        return {"method": "none", "status": "failed", "message": " | ".join(tail), "wall_s": wall}
    run = json.loads(run_json.read_text())
    run.setdefault("method", "none")
    run.setdefault("status", "fragment" if run.get("fragment") else "ok")
    run["wall_s"] = wall
    run["trajectory"] = str(traj) if traj.is_file() else None
    return run


def _ms_per_frame(run: dict):
    """Processing milliseconds per frame without image loading, like ORB-SLAM3's tracking-thread time: for our
    engine the sum of its stage means except ``load`` (its local BA runs inline; ORB-SLAM3's runs in a second
    thread), else ``ms_per_frame``, else 1000 / fps."""
    stages = run.get("stage_ms")
    if run.get("method") == "none" and isinstance(stages, dict) and stages:
        return float(sum(v for k, v in stages.items() if k != "load" and isinstance(v, (int, float))))
    for key in ("ms_per_frame", "ms_per_frame_mean", "mean_ms_per_frame"):
        if isinstance(run.get(key), (int, float)):
            return float(run[key])
    if isinstance(run.get("fps"), (int, float)) and run["fps"] > 0:
        return 1000.0 / run["fps"]
    return None


def _fmt(run: dict, key: str, fmt: str, metric: bool = False) -> str:
    v = (run.get("metrics") or {}).get(key) if metric else run.get(key)
    if not isinstance(v, (int, float)):
        return "-"
    s = format(v, fmt)
    spread = (run.get("metrics_spread") or {}).get(key) if metric else run.get(f"{key}_spread")
    if spread:
        s += f" [{format(spread['min'], fmt)}, {format(spread['max'], fmt)}]"
    return s


def run(args) -> int:
    if args.frames < 30:
        raise D2SlamError("--frames must be at least 30 (RPE needs 1 s pairs)")

    config = load_config_file(args.config)[0] if args.config else DEFAULT
    out_root = check_output_dir(args.out, "--out") if args.out else cache_dir("bench", "orbslam3")
    out_root.mkdir(parents=True, exist_ok=True)
    rows = []
    for scenario in args.scenarios:
        for seed in args.seeds:
            for variant in args.variants:
                twin = variant == "twin"
                seq = _sequence(scenario, seed, args.frames, twin, args.regenerate)
                name = f"{scenario}{' twin' if twin else ''} s{seed}"
                out = out_root / seq.name
                out.mkdir(parents=True, exist_ok=True)
                sequence = open_sequence(seq)
                for method in args.methods:
                    if method == "orbslam3":
                        r = run_orbslam3(seq, out / "orbslam3.txt", out / "orbslam3.json", repeats=args.repeats,
                                         vocab=args.vocab, config=config).orbslam3
                    else:
                        r = _run_engine(seq, out)
                        if r.get("trajectory") and "metrics" not in r and "metrics_error" not in r:
                            r.update(evaluate_trajectory(sequence, r["trajectory"]))
                    r["ms_per_frame"] = _ms_per_frame(r)
                    rows.append({**r, "sequence_dir": str(seq), "sequence": name, "variant": variant,
                                 "scenario": scenario, "seed": seed, "method": method})
                    msg = r.get("message") or f"tracked {r.get('tracked')}/{r.get('frames')}"
                    print(f"  {name:32s} {method:9s} {r.get('status', '?'):8s} {msg}", file=sys.stderr)
    _print_table(rows, args)
    summary = out_root / "bench_orbslam3.json"
    summary.write_text(json.dumps({"args": {k: v for k, v in vars(args).items() if k != "func"}, "rows": rows},
                                  indent=1, default=str))
    print(f"\nper-run JSON, trajectories and this summary: {summary}")
    return 0


def _loadavg() -> tuple:
    try:
        return os.getloadavg()
    except OSError:  # pragma: no cover
        return ()


def _print_table(rows: list[dict], args) -> None:
    vocab = next((r.get("vocabulary") for r in rows if r.get("vocabulary")), None)
    print(f"\nORB-SLAM3 (pyorbslam3, RGB-D) vs our engine `none`; {args.frames} frames; "
          f"ORB-SLAM3 repeats: {args.repeats} (median [min, max])")
    if vocab:
        print(f"vocabulary: {vocab['kind']} {vocab['path']} sha256 {vocab['sha256'][:16]}")
    head = (f"{'sequence':30s} {'method':9s} {'status':8s} {'tracked':>9s} {'ATE m':>22s} {'RPE m':>22s} "
            f"{'RPE deg':>22s} {'ms/frame':>22s}")
    print(head)
    print("-" * len(head))
    for r in rows:
        frames = r.get("frames") or r.get("frames_expected") or 0
        tracked = f"{r['tracked']:.0f}/{frames}" if isinstance(r.get("tracked"), (int, float)) else "-"
        print(f"{r['sequence']:30s} {r['method']:9s} {str(r.get('status', '?')):8s} {tracked:>9s} "
              f"{_fmt(r, 'ate_rmse_m', '.4f', True):>22s} {_fmt(r, 'rpe_trans_m', '.4f', True):>22s} "
              f"{_fmt(r, 'rpe_rot_deg', '.3f', True):>22s} {_fmt(r, 'ms_per_frame', '.1f'):>22s}")
    ours = [r for r in rows if r["method"] == "none" and isinstance(r.get("ms_per_frame"), float)]
    theirs = [r for r in rows if r["method"] == "orbslam3" and isinstance(r.get("ms_per_frame"), float)]
    if ours and theirs:
        a = float(np.median([r["ms_per_frame"] for r in ours]))
        b = float(np.median([r["ms_per_frame"] for r in theirs]))
        print(f"\nspeed (median over sequences, image loading excluded): our engine {a:.1f} ms/frame vs ORB-SLAM3 "
              f"{b:.1f} ms/frame (its tracking thread; local mapping runs in parallel) = {a / b:.1f}x")
        stages = {}
        for r in ours:
            for k, v in (r.get("stage_ms") or {}).items():
                stages.setdefault(k, []).append(v)
        if stages:
            print("  our engine per stage (median ms/frame): "
                  + ", ".join(f"{k} {np.median(v):.1f}" for k, v in stages.items()))
        print(f"  machine load average at the end: {', '.join(f'{x:.1f}' for x in _loadavg())} "
              "(figures are wall-clock: other processes slow both)")
    _print_overhead(rows)
    for method in ("orbslam3", "none"):
        for variant in ("twin", "dynamic"):
            ates = [r["metrics"]["ate_rmse_m"] for r in rows if r["method"] == method and r["variant"] == variant
                    and isinstance((r.get("metrics") or {}).get("ate_rmse_m"), (int, float))]
            if ates:
                print(f"median ATE {method:8s} {variant:7s}: {np.median(ates):.4f} m over {len(ates)} sequence(s)")


OVERHEAD_PARTS = ("process", "load", "decode", "save", "evaluate")


def overhead(run: dict) -> dict | None:
    """Per-run seconds of an ORB-SLAM3 run dict (median over its repeats): ``wall`` (the child process, plus its
    evaluation and its share of the frame store), ``track`` (the frames' ``track_rgbd`` calls), the overhead parts
    (``process``: interpreter, imports, exit; ``load``: the vocabulary; ``decode``: frames read in the worker plus
    the share of the frames decoded once; ``save``: shutdown and SaveTrajectoryTUM; ``evaluate``: evo) and their
    sum ``overhead``; ``cpu``: the worker's CPU seconds (every ORB-SLAM3 thread). None without per-run seconds."""
    reps = [r for r in run.get("runs") or [] if r.get("seconds")]
    if not reps:
        return None
    share = (run.get("frame_store") or {}).get("wall_s", 0.0) / len(reps)
    per = []
    for r in reps:
        sec = dict(r["seconds"])
        sec["decode"] = sec.get("decode", 0.0) + share
        sec["wall"] = r["wall_s"] + sec.get("evaluate", 0.0) + share
        sec["overhead"] = sum(sec.get(k, 0.0) for k in OVERHEAD_PARTS)
        sec["cpu"] = r.get("cpu_s") or float("nan")
        per.append(sec)
    keys = ("wall", "track", "overhead", *OVERHEAD_PARTS, "cpu")
    return {k: float(np.median([p.get(k, 0.0) for p in per])) for k in keys}


def _print_overhead(rows: list[dict]) -> None:
    table = [(r["sequence"], o) for r in rows if r["method"] == "orbslam3" and (o := overhead(r))]
    if not table:
        return
    print("\nORB-SLAM3 per-run seconds (median over repeats): wall = track + overhead + the frame loop's own time")
    print(f"{'sequence':30s} " + " ".join(f"{k:>8s}" for k in table[0][1]))
    for name, o in table:
        print(f"{name:30s} " + " ".join(f"{v:8.2f}" for v in o.values()))
