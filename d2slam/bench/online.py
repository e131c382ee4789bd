"""Online at the sensor's rate (``d2slam run --online``, :mod:`d2slam.run.online`), side by side in one run per
sequence: offline ``d2slam`` (the paper's protocol: every frame segmented first, nothing dropped), online ``d2slam``
(the segmenter in its own thread, late frames dropped), online ``none`` and the real ORB-SLAM3 online (the same
camera, ``d2slam.data.live``), and the real ORB-SLAM3 offline. Each run is ``d2slam run`` in its own process, as a
user runs it. Online figures depend on the machine and its load (printed with them)."""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from d2slam.assets import real_full
from d2slam.config import DEFAULT
from d2slam.data import open_sequence
from d2slam.errors import D2SlamError
from d2slam.eval.trajectory import evaluate_run
from d2slam.outputs import write_bytes
from d2slam.ranges import overridden
from d2slam.run.online import replay, simulated_schedule
from d2slam.run.record import EXIT_FRAGMENT
from d2slam.study.grid import DEFAULT_FRAMES, DEFAULT_SEEDS, ONLINE_SCENARIOS, REAL_SCENARIOS
from d2slam.study.online import load_average
from d2slam.study.sequences import ensure_sequence

DESCRIPTION = ("online at the sensor's rate: d2slam --online beside offline d2slam, online none and the real "
               "ORB-SLAM3 online and offline; frames processed, lag, ATE (also: bench engine --online)")
WALKING = tuple(s for s in ONLINE_SCENARIOS if s not in REAL_SCENARIOS)  # the study's online scenarios
TARGET_PROCESSED, TARGET_LAG_MS, TARGET_ATE_RATIO, TARGET_BETTER = 0.95, 33.0, 1.15, 0.90


def add_arguments(parser) -> None:
    parser.add_argument("sequences", nargs="*", metavar="SEQ", help="TUM or synthetic sequence folders (default: the "
                        "four fr3 walking scenarios of --seeds and --frames, and the whole real fr1/rpy when fetched)")
    parser.add_argument("--rate", type=float, default=None, help="frames arrive at this rate (Hz; default "
                        "online.rate_hz, as in the study's online runs: 0, the frames' own timestamps)")
    parser.add_argument("--seeds", type=int, nargs="+", default=None,
                        help=f"sequence seeds of the default scenarios (default {DEFAULT_SEEDS[0]}, a study seed; "
                        "with --latency 3, a development seed)")
    parser.add_argument("--frames", type=int, default=DEFAULT_FRAMES, help="frames of the default scenarios")
    parser.add_argument("--no-real", action="store_true", help="without the real fr1/rpy")
    parser.add_argument("--latency", type=int, nargs="+", metavar="FRAMES", default=None,
                        help="instead, timing-free (deterministic): d2slam with every frame tracked and the segmenter's "
                        "masks LATENCY frames late (d2slam.run.online.simulated_schedule), with the masks moved on "
                        "with "
                        "their people and without, beside the offline run (latency 0); default scenarios: dev seeds")
    parser.add_argument("--repeats", type=int, default=1, metavar="N",
                        help="each online run N times (an online run depends on timing; the offline runs are "
                        "deterministic and run once): every run's line, and the targets judged on the median")
    parser.add_argument("--json", metavar="PATH", help="also write the rows as JSON")


def _sequences(args) -> list[Path]:
    if args.sequences:
        missing = [s for s in args.sequences if not Path(s).is_dir()]
        if missing:
            raise D2SlamError(f"no sequence folder {missing[0]}")
        return [Path(s) for s in args.sequences]
    seeds = args.seeds or [3 if getattr(args, "latency", None) else DEFAULT_SEEDS[0]]
    out = [ensure_sequence(s, seed, args.frames, False) for seed in seeds for s in WALKING]
    real = None if args.no_real else real_full()
    return out + ([Path(real)] if real is not None else [])


def engine_run(seq, method: str, out, extra: list[str] = ()) -> dict:
    """``d2slam run SEQ --method METHOD [EXTRA...]`` in a child process (as a user runs it); its run JSON."""
    out.mkdir(parents=True, exist_ok=True)
    traj, js = out / f"{method}.txt", out / f"{method}.json"
    js.unlink(missing_ok=True)
    proc = subprocess.run([sys.executable, "-m", "d2slam.cli", "run", str(seq), "--method", method, "--out", str(traj),
                           "--metrics-json", str(js), "--quiet", *extra], capture_output=True, text=True)
    if proc.returncode not in (0, EXIT_FRAGMENT) or not js.is_file():
        tail = " | ".join((proc.stderr or proc.stdout).strip().splitlines()[-2:])
        return {"method": method, "status": "failed", "message": tail}
    run = json.loads(js.read_text())
    return {**run, "status": "fragment" if run.get("fragment") else "ok"}  # a fragment ran: its timings count


def _run(seq: Path, method: str, out: Path, extra: list[str]) -> dict:
    return engine_run(seq, method, out, extra)


ONLINE_RUNS = ("d2slam", "none", "orbslam3")


def _row(seq: Path, rate: float | None, out: Path, repeats: int = 1) -> dict:
    """The runs on one sequence: offline d2slam and ORB-SLAM3 once, each online run ``repeats`` times (repeat k's
    online runs one after the other, then repeat k + 1's). ``runs`` holds the first repeat, ``repeats`` every one."""
    online = ["--online"] + (["--rate", f"{rate:g}"] if rate else [])
    d2slam_offline = _run(seq, "d2slam", out / "offline", [])
    rep: dict[str, list] = {f"{m} online": [] for m in ONLINE_RUNS}
    for k in range(repeats):
        for m in ONLINE_RUNS:
            rep[f"{m} online"].append(_run(seq, m, out / f"online{k}", online))
    runs = {"d2slam offline": d2slam_offline, **{k: v[0] for k, v in rep.items()},
            "orbslam3 offline": _run(seq, "orbslam3", out / "offline", [])}
    return {"sequence": str(seq), "runs": runs, "repeats": rep}


def _median(xs: list) -> float | None:
    """The median of the numbers among ``xs`` (runs without a figure left out), or None."""
    vals = [x for x in xs if isinstance(x, (int, float))]
    return float(np.median(vals)) if vals else None


def judged(row: dict) -> dict:
    """The targets of ``d2slam --online`` on one sequence, over its repeats: the smallest share of frames processed,
    the median of the runs' median lags, the median ATE and its ratio to offline d2slam (with the ratios' range),
    and the median ATE's gain over the real ORB-SLAM3 online's median ATE (walking sequences only)."""
    reps = row["repeats"]["d2slam online"]
    ref = _ate(row["runs"]["d2slam offline"])
    ates = [_ate(r) for r in reps]
    ratios = [a / ref for a in ates if isinstance(a, float) and ref]
    shares = [(r.get("online") or {}).get("processed_share") for r in reps]
    lags = [(r.get("online") or {}).get("lag_ms_median") for r in reps]
    orb = _median([_ate(r) for r in row["repeats"]["orbslam3 online"]])
    ate = _median(ates)
    ok = [r.get("status") == "ok" for r in reps]
    return {"runs": len(reps), "ok": sum(ok),
            "processed_min": min((s for s in shares if s is not None), default=None),
            "lag_ms_median": _median(lags), "ate_median_m": ate, "ate_ratio_median": _median(ratios),
            "ate_ratio_range": [min(ratios), max(ratios)] if ratios else None,
            "better_than_orbslam3": 1 - ate / orb if isinstance(ate, float) and orb else None}


def _walking(seq: str) -> bool:
    return any(s in Path(seq).name for s in WALKING)


def _targets(rows: list[dict]) -> list[str]:
    """The targets' lines: one per sequence, then met or not over all of them."""
    out = [f"{'sequence':40} {'runs':>4} {'processed min':>13} {'lag p50':>7} {'ATE/offline median [range]':>26} "
           f"{'better than ORB-SLAM3 online':>28}"]
    met = {"processed": True, "lag": True, "ate": True,
           "better": True if any(_walking(r["sequence"]) for r in rows) else None}  # None: nothing to judge it on
    for row in rows:
        j = judged(row)
        row["judged"] = j
        walking = _walking(row["sequence"])
        p, lag, q, rr, b = (j["processed_min"], j["lag_ms_median"], j["ate_ratio_median"], j["ate_ratio_range"],
                            j["better_than_orbslam3"])
        met["processed"] &= p is not None and p >= TARGET_PROCESSED and j["ok"] == j["runs"]
        met["lag"] &= lag is not None and lag <= TARGET_LAG_MS
        met["ate"] &= q is not None and q <= TARGET_ATE_RATIO
        if walking:
            met["better"] &= b is not None and b >= TARGET_BETTER
        out.append(f"{Path(row['sequence']).name[:40]:40} {j['ok']:>2}/{j['runs']:<1} "
                   f"{f'{100 * p:.1f} %' if p is not None else '-':>13} {f'{lag:.1f}' if lag is not None else '-':>7} "
                   f"{f'{q:.2f} [{rr[0]:.2f}, {rr[1]:.2f}]' if q is not None else '-':>26} "
                   f"{(f'{100 * b:.1f} %' if b is not None else '-') if walking else '(not walking)':>28}")
    say = {True: "met", False: "NOT met", None: "not judged (no walking sequence)"}
    out.append(f"targets (medians over the repeats): processed >= {100 * TARGET_PROCESSED:g} % "
               f"{say[met['processed']]}; "
               f"median lag <= {TARGET_LAG_MS:g} ms {say[met['lag']]}; ATE <= {TARGET_ATE_RATIO:g}x offline "
               f"{say[met['ate']]}; >= {100 * TARGET_BETTER:g} % better than the real ORB-SLAM3 online on the walking "
               f"sequences {say[met['better']]}")
    return out


def _ate(r: dict):
    return (r.get("metrics") or {}).get("ate_rmse_m")


def _line(name: str, r: dict, ref_ate, orb_ate) -> str:
    o = r.get("online") or {}
    ate = _ate(r)
    share = o.get("processed_share")
    cells = [f"{name:17}", f"{r.get('status', '-'):9}",
             f"{o['processed']}/{o['frames']}" if o else f"{r.get('tracked', '-')}/{r.get('frames', '-')}",
             f"{100 * share:5.1f} %" if share is not None else "      -",
             f"{o['lag_ms_median']:7.1f}" if o.get("lag_ms_median") is not None else "      -",
             f"{o['lag_ms_p95']:7.1f}" if o.get("lag_ms_p95") is not None else "      -",
             f"{ate:8.4f}" if isinstance(ate, float) else "       -",
             f"{ate / ref_ate:6.2f}" if isinstance(ate, float) and ref_ate else "     -",
             f"{100 * (1 - ate / orb_ate):6.1f} %" if isinstance(ate, float) and orb_ate else "       -"]
    return " ".join(cells)


def latency(args) -> int:
    """What stale masks cost d2slam in accuracy, without a clock (``--latency``)."""
    variants = (("moved", overridden(DEFAULT, {"online": {"mask_motion": True}})),
                ("tracks", overridden(DEFAULT, {"online": {"mask_tracks": True}})),
                ("still", overridden(DEFAULT, {"online": {"mask_motion": False}})))
    print("d2slam bench online --latency: d2slam on every frame, the segmenter's masks L frames late (a mask every L "
          "frames), moved on with their people's centroids (online.mask_motion), by their keypoints' tracks "
          "(online.mask_tracks) or not; ATE (m) and its ratio to offline (L 0)")
    print(f"{'sequence':44} {'offline':>8} " + " ".join(f"{f'L{n} {name}':>13}" for n in args.latency
                                                        for name, _ in variants))
    rows = []
    for seq_dir in _sequences(args):
        seq = open_sequence(seq_dir)

        def ate(sched, cfg):
            r = replay(seq, sched, "d2slam", cfg, progress=False)
            return evaluate_run(seq.groundtruth, r.trajectory).ate_rmse_m

        ref = ate(simulated_schedule(seq, 0), DEFAULT)
        row = {"sequence": str(seq_dir), "offline": ref}
        cells = []
        for n in args.latency:
            for name, cfg in variants:
                a = ate(simulated_schedule(seq, n, cfg), cfg)
                row[f"L{n} {name}"] = a
                cells.append(f"{a:7.4f} {a / ref:4.2f}x")
        rows.append(row)
        print(f"{seq.name[:44]:44} {ref:8.4f} " + " ".join(f"{c:>13}" for c in cells), flush=True)
    if args.json:
        write_bytes(Path(args.json), json.dumps(rows, indent=2) + "\n")
    return 0


def run(args) -> int:
    if args.latency:
        return latency(args)
    if args.repeats < 1:
        raise D2SlamError(f"--repeats must be at least 1 (got {args.repeats})")
    seqs = _sequences(args)
    out = Path(tempfile.mkdtemp(prefix="d2slam_bench_online_"))
    rows = []
    at = f"{args.rate:g} Hz" if args.rate else "online.rate_hz" if DEFAULT.online.rate_hz else "their timestamps"
    print(f"d2slam bench online: {len(seqs)} sequence(s) at {at}; targets for d2slam online: processed "
          f">= {100 * TARGET_PROCESSED:g} %, median lag <= {TARGET_LAG_MS:g} ms, ATE <= {TARGET_ATE_RATIO:g}x offline "
          f"d2slam, >= {100 * TARGET_BETTER:g} % better than the real ORB-SLAM3 (fr3 walking)")
    for i, seq in enumerate(seqs):
        row = _row(seq, args.rate, out / f"s{i}", args.repeats)
        rows.append(row)
        r = row["runs"]
        ref, orb_off = _ate(r["d2slam offline"]), _ate(r["orbslam3 offline"])
        orb_on = _median([_ate(x) for x in row["repeats"]["orbslam3 online"]])
        print(f"\n{seq}")
        print(f"{'run':17} {'status':9} {'processed':>9} {'share':>7} {'lag p50':>7} {'lag p95':>7} {'ATE m':>8} "
              f"{'/offl.':>6} {'vs ORB-SLAM3 online':>8}")
        for name, rr in r.items():
            if name in row["repeats"]:
                for k, rk in enumerate(row["repeats"][name]):
                    print(_line(name if args.repeats == 1 else f"{name} {k + 1}", rk, ref, orb_on))
            else:
                print(_line(name, rr, ref, orb_on))
        if isinstance(orb_off, float):
            d = _median([_ate(x) for x in row["repeats"]["d2slam online"]])
            if isinstance(d, float):
                print(f"d2slam online against the real ORB-SLAM3 offline: {100 * (1 - d / orb_off):.1f} % better")
    print("")
    for line in _targets(rows):
        print(line)
    load = load_average()
    print(f"\nload average: {', '.join(f'{x:.1f}' for x in load) if load else 'n/a'}; runs in {out}")
    if args.json:
        write_bytes(Path(args.json), json.dumps(rows, indent=2) + "\n")
    return 0
