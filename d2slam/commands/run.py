"""``d2slam run SEQUENCE_DIR --method none --out TRAJ.txt``: run the SLAM engine on a sequence."""

from __future__ import annotations

import glob
import json
import os
import sys
from pathlib import Path

import psutil

from d2slam.config import DEFAULT, load_config_file
from d2slam.data import SyntheticSequence, open_sequence, write_tum_trajectory
from d2slam.data.depth_scale import depth_scale_warning
from d2slam.data.intrinsics import is_camera_file, read_camera_file
from d2slam.errors import D2SlamError
from d2slam.eval.fragment import is_fragment, tracked_share
from d2slam.outputs import check_output_file, check_outputs, remove_stale_temps, write_bytes
from d2slam.ranges import overridden
from d2slam.run.methods import get_method, methods
from d2slam.run.metrics import RunSource, run_json
from d2slam.run.online import Schedule, online_line, online_report, replay, run_online
from d2slam.run.record import EXIT_FRAGMENT
from d2slam.run.runner import run_config, run_method
from d2slam.slam.orb_vocabulary import load_vocabulary


def register(sub) -> None:
    min_share = DEFAULT.evaluation.min_tracked_share

    p = sub.add_parser(
        "run", help="run the SLAM engine on a TUM or synthetic sequence",
        description="Run the ORB-SLAM3-style RGB-D engine on SEQUENCE_DIR (TUM layout, or a d2slam synthetic "
        "sequence) with a keypoint-filter method, write the trajectory of the tracked frames in TUM format and, "
        "with --metrics-json, frames/tracked/lost/fps, mean milliseconds per stage, the config hash, the seconds from "
        "the process start to the end of the first frame (startup_s) and (when the sequence has ground truth) "
        "ATE/RPE computed with evo. The last line printed says what was run: `d2slam run: "
        "method M; masks KIND (where from); camera NAME (where from); tracked T/N frames; ATE X m; wrote FILES`. "
        f"A run that tracked less than evaluation.min_tracked_share (default {min_share:g}) of its frames is a "
        f"fragment: the line says `tracked T/N frames (S %): a fragment, below {100 * min_share:g} %; ATE X m over "
        "the tracked fragment only`, the "
        "metrics JSON has \"fragment\": true with tracked_share and a fragment_note, and the exit status is 3.",
        epilog="Exit status: 0 the run tracked at least evaluation.min_tracked_share of its frames; "
        f"{EXIT_FRAGMENT} it tracked fewer (a fragment: its ATE/RPE are over the tracked part only, not a result for "
        "the sequence); 2 bad input (one `d2slam: error:` line) or, for --method orbslam3 and orbslam3-masked, a "
        "failed ORB-SLAM3 run; 1 (orbslam3 and orbslam3-masked only) ORB-SLAM3 lost track or started a new map on "
        "some frames but tracked at least that share.")
    p.add_argument("sequence", metavar="SEQUENCE_DIR")
    p.add_argument("--method", default="none", choices=methods(), help="keypoint filter (default: none)")
    p.add_argument("--out", required=True, metavar="TRAJ.txt", help="estimated trajectory (TUM format)")
    p.add_argument("--metrics-json", metavar="RUN.json", help="write run statistics and metrics as JSON")
    p.add_argument("--masks", choices=["onnx", "sim", "gt", "truth"], default=None,
                   help="person masks given to the filter when the method needs masks (default: onnx, the real "
                   "segmenter, as in the study; its masks are computed once per sequence into the mask cache). "
                   "sim: the simulated segmenter of a synthetic sequence (mask_sim/), gt: its person ids (mask_gt/), "
                   "truth: its dynamic truth (persons and moving objects), what --method oracle always uses")
    p.add_argument("--masks-from", metavar="SEQUENCE_DIR", default=None,
                   help="read the masks from this sequence instead (same frames and timestamps), e.g. --method "
                   "oracle on a static twin with its dynamic sequence, or on a real recording with a composite made "
                   "of it (d2slam synth real_walking --on): the occluded twin of the study")
    p.add_argument("--camera", metavar="fr1|fr2|fr3|FILE.yaml", default=None,
                   help="camera of a TUM-layout folder: fr1/fr2/fr3, or an ORB-SLAM3 RGB-D settings YAML (Camera.fx, "
                   "..., DepthMapFactor, ThDepth; old Camera.* or new Camera1.* keys) for any other RGB-D camera "
                   "(default: from the folder name; synthetic sequences carry their own, a different one is an error)")
    p.add_argument("--config", metavar="FILE.yaml", default=None,
                   help="override config fields (d2slam/config.py): a YAML of `section: {field: value}`, e.g. "
                   "`dynamics: {z_far: 5.0}`; saved in the metrics JSON")
    p.add_argument("--seed", type=int, default=0, help="seed of the engine's RANSAC (relocalisation, loops)")
    p.add_argument("--no-loop-closing", action="store_true",
                   help="the engine without loop closing and its keyframe database (EngineConfig.loop_closing; "
                   "relocalisation then searches the recent keyframes)")
    p.add_argument("--repeats", type=int, default=1, help="--method orbslam3 and orbslam3-masked only: runs of "
                   "ORB-SLAM3 (default 1)")
    p.add_argument("--online", action="store_true",
                   help="run as on a live camera (d2slam.run.online): frames arrive at their timestamps (or --rate), "
                   "the "
                   "segmenter runs in its own thread on the newest frame, tracking never waits for it and takes the "
                   "newest frame when free, dropping the rest. Depends on timing: see --online-log")
    p.add_argument("--rate", type=float, default=None, metavar="HZ",
                   help="--online: frames arrive at HZ instead of their timestamps (online.rate_hz)")
    p.add_argument("--online-log", metavar="LOG.npz", default=None,
                   help="--online: write the run's schedule (frames tracked, the masks each read) for --deterministic")
    p.add_argument("--deterministic", metavar="LOG.npz", default=None,
                   help="replay an online run's schedule (--online-log) without a clock: the same frames with the same "
                   "masks, the same trajectory byte for byte")
    p.add_argument("--quiet", action="store_true", help="no progress, no summary")
    p.set_defaults(func=run)


def run(args) -> int:
    method = get_method(args.method)
    _check_online_args(args, method)
    out = _check_outputs(args, method)
    camera, camera_source, th_depth = _camera(args)
    if method.runner is not None:  # not a keypoint filter of our engine (orbslam3[-masked]): its own command
        return _run_orbslam3(args, method, camera)
    config, overrides = load_config_file(args.config) if args.config else (DEFAULT, None)
    config = run_config(config, args.seed, not args.no_loop_closing, th_depth)
    seq = open_sequence(args.sequence, **({"camera": camera} if camera else {}))
    _warn_depth_scale(seq, config)
    if args.online or args.deterministic:
        return run_online_command(args, seq, config, out)
    mask_seq = open_sequence(args.masks_from) if args.masks_from is not None else None
    # the truth masks of --masks-from a synthetic sequence serve a real one too (a composite's recording: the
    # occluded twin)
    synthetic = isinstance(seq, SyntheticSequence) or isinstance(mask_seq, SyntheticSequence)
    record = run_method(seq, args.method, config, masks=args.masks, mask_seq=mask_seq, synthetic=synthetic,
                        progress=False if args.quiet else None, desc=f"{args.method} {seq.name}")
    write_tum_trajectory(out, record.trajectory, header=(f"d2slam run {args.method}: no frame tracked" if
                                                         record.tracked == 0 else
                                                         f"d2slam run --method {args.method} {seq.root}"))
    vocabulary = None
    if record.loop_closing:
        voc = load_vocabulary(config.engine.vocabulary or None)
        vocabulary = {"path": voc.path, "sha256": voc.sha256}
    source = RunSource(seq, args.seed, camera_source or ("scene.json" if synthetic else args.camera or "folder name"),
                       out, mask_seq, args.config, overrides, config if args.config else None, vocabulary)
    js = run_json(record, source, record.engine.first_frame_at - process_start())
    if args.metrics_json:
        write_bytes(Path(args.metrics_json).expanduser(), json.dumps(js, indent=2) + "\n")
    if not args.quiet:
        _print_run(record, js, args, seq, out)
    return EXIT_FRAGMENT if record.fragment else 0


def _check_outputs(args, method) -> Path:
    """``--out``, checked with ``--metrics-json`` against each other and the run's inputs, before any work; what a
    killed run was writing there is removed."""
    out = check_output_file(args.out, "--out")
    if args.metrics_json:
        check_output_file(args.metrics_json, "--metrics-json")
    check_outputs(run_outputs(args, method), run_inputs(args))
    for path in filter(None, [out, args.metrics_json]):
        path = Path(path).expanduser()
        remove_stale_temps(path.parent, f"{glob.escape(path.name)}.tmp-*")
    return out


def _camera(args) -> tuple[object, str | None, float | None]:
    """(``--camera``: a name, or the camera of a settings file; where it came from when a file; the file's ThDepth)."""
    if not is_camera_file(args.camera):
        return args.camera, None, None
    settings = read_camera_file(args.camera)
    return settings.camera, str(Path(args.camera).expanduser().resolve()), settings.th_depth


def _run_orbslam3(args, method, camera) -> int:
    """``d2slam run --method orbslam3[-masked]``: the arguments that apply to our engine only are refused; the
    depth-scale check, then ORB-SLAM3's own run."""
    for given, what in ((args.masks_from is not None, "--masks-from"),
                        (args.masks is not None and not method.needs_masks, "--masks"),
                        (args.config is not None, "--config")):
        if given:
            raise D2SlamError(f"{what} does not apply to --method {args.method}")
    if args.no_loop_closing:
        raise D2SlamError(f"--no-loop-closing does not apply to --method {args.method} (the real ORB-SLAM3)")
    _warn_depth_scale(open_sequence(args.sequence, **({"camera": camera} if camera else {})), DEFAULT)
    return print_orbslam3(method.runner(args), args)


def _print_run(record, js: dict, args, seq, out: Path) -> None:
    """What ``d2slam run`` prints of an engine run: its figures, the frames not run, the loops, RPE (or why there is
    none), and the summary line."""
    print(f"{seq.name}: {record.lost} lost, {record.keyframes} keyframes, {record.fps:.1f} fps; ms/frame: "
          + ", ".join(f"{k} {v:.1f}" for k, v in record.stage_ms.items()))
    if "frames_note" in js:
        print(js["frames_note"])
    if record.loop_closing:
        judged = record.evaluation is not None
        judged_text = f" ({len(js['loops_true'])} true, {len(js['loops_false'])} false)" if judged else ""
        print(f"loops: {len(js['loops'])}" + judged_text + "".join(f"; frames {a} -> {b}" for a, b in js["loops"]))
    if "metrics_error" in js:
        print(js["metrics_error"])
    else:
        m = js["metrics"]
        print(f"rpe_trans_m {m['rpe_trans_m']:.4f}  rpe_rot_deg {m['rpe_rot_deg']:.3f}")
    masks = f"{record.masks} ({record.masks_origin})" if record.masks else "none"
    ate = js["metrics"]["ate_rmse_m"] if "metrics" in js else None
    print(summary_line(args.method, masks, camera_text(seq.camera.name, js["camera"]["source"], args.camera),
                       record.tracked, record.frames, ate, [out, args.metrics_json],
                       ate_note=" (no RPE)" if "metrics" in js and "metrics_error" in js else "",
                       min_share=record.min_tracked_share))


def run_online_command(args, seq, config, out) -> int:
    """``d2slam run --online`` and ``--deterministic``: run, write ``--out``, ``--metrics-json`` and ``--online-log``,
    print the online line and the summary line; the exit status (3: a fragment of the processed frames)."""
    if args.rate is not None:
        config = overridden(config, {"online": {"rate_hz": float(args.rate)}})
    quiet = getattr(args, "quiet", False)
    if args.deterministic:
        run = replay(seq, Schedule.load(args.deterministic), args.method, config, progress=False if quiet else None)
    else:
        run = run_online(seq, args.method, config, progress=False if quiet else None)
        if args.online_log:
            run.schedule.save(args.online_log)
    report = online_report(run, seq, config, replayed=bool(args.deterministic))
    write_tum_trajectory(out, run.trajectory, header=f"d2slam run --method {args.method} --online {seq.root}")
    record = {"sequence": str(seq.root), "name": seq.name, "method": args.method, "config_hash": config.hash(),
              "frames": run.schedule.frames, "tracked": run.tracked, "keyframes": run.keyframes,
              "map_points": run.map_points, **report, "trajectory": str(out)}
    if args.metrics_json:
        write_bytes(Path(args.metrics_json).expanduser(), json.dumps(record, indent=2) + "\n")
    if not quiet:
        print(online_line(report))
        ate = report.get("metrics", {}).get("ate_rmse_m")
        masks = ("none" if not report["online"]["with_mask"] and not run.schedule.segmented else
                 "onnx (the schedule's)" if args.deterministic else "onnx (the segmenter's thread)")
        print(summary_line(args.method, masks, camera_text(seq.camera.name, args.camera or "folder name",
                                                           args.camera),
                           run.tracked, len(run.schedule.processed), ate,
                           [out, args.metrics_json, None if args.deterministic else args.online_log],
                           ate_note=" over the processed frames", min_share=config.evaluation.min_tracked_share))
    return EXIT_FRAGMENT if report["fragment"] else 0


def _check_online_args(args, method) -> None:
    """The online options together: one clear error for a combination that cannot run."""
    online = getattr(args, "online", False)
    replaying = getattr(args, "deterministic", None)
    if online and replaying:
        raise D2SlamError("--online and --deterministic exclude each other: --deterministic replays an online run")
    if not online and (args.rate is not None or args.online_log):
        raise D2SlamError("--rate and --online-log need --online")
    if replaying and args.rate is not None:
        raise D2SlamError("--deterministic replays the schedule it reads: --rate does not apply")
    orbslam3 = method.name == "orbslam3" and online
    if (online or replaying) and not orbslam3 and (method.runner is not None or method.masks is not None
                                                   or args.masks_from or args.masks not in (None, "onnx")):
        raise D2SlamError(f"--online runs none, the dynamics methods (with the real segmenter) and orbslam3, not "
                          f"--method {args.method}" + (" with other masks" if args.masks or args.masks_from else ""))
    if orbslam3 and args.online_log:
        raise D2SlamError("--online-log: ORB-SLAM3's online run has no schedule to replay (its threads are its own)")
    if args.rate is not None and not 0 < args.rate <= 1000:
        raise D2SlamError(f"--rate {args.rate:g}: must be in (0, 1000] Hz")


def run_outputs(args, method) -> list[tuple[str, object]]:
    """What ``d2slam run`` writes: ``--out``, ``--metrics-json``, and for the real ORB-SLAM3 the files it keeps
    beside the trajectory (its settings and online poses)."""
    out = Path(args.out).expanduser()
    extra = [] if method.runner is None else [
        ("--out's ORB-SLAM3 settings", out.with_name(out.stem + ".orbslam3.yaml")),
        ("--out's online poses", out.with_name(out.stem + ".online.txt"))]
    return [("--out", out), ("--metrics-json", args.metrics_json),
            ("--online-log", getattr(args, "online_log", None))] + extra


def run_inputs(args) -> list[tuple[str, object]]:
    """What ``d2slam run`` reads: the sequence folder, ``--masks-from``, ``--camera FILE``, ``--config``, the
    vocabulary (``$PYORBSLAM3_VOCAB``)."""
    return [("sequence", args.sequence), ("--masks-from sequence", args.masks_from),
            ("--camera file", args.camera if is_camera_file(args.camera) else None), ("--config file", args.config),
            ("vocabulary ($PYORBSLAM3_VOCAB)", os.environ.get("PYORBSLAM3_VOCAB") or None),
            ("--deterministic schedule", getattr(args, "deterministic", None))]


def print_orbslam3(run, args) -> int:
    """What ``d2slam run --method orbslam3[-masked]`` prints of ORB-SLAM3's run (``RunRecord``) and its exit status:
    0 when ORB-SLAM3 tracked, 1 when it ran but lost / reset, 2 when it failed, :data:`EXIT_FRAGMENT` when it ran
    but tracked less than ``EvalConfig.min_tracked_share`` of the frames (``RunRecord.fragment``)."""
    report = run.orbslam3
    stream = sys.stdout if report["status"] in ("ok", "lost") else sys.stderr
    v = report.get("vocabulary") or {}
    masks = f" ({report['masks']} masks)" if report.get("masks") else ""
    print(f"{report['method']} {report.get('name', args.sequence)}{masks}: {report['status']}: {report['message']}",
          file=stream)
    if v:
        print(f"  vocabulary: {v['kind']} {v['path']} (sha256 {v['sha256'][:16]})", file=stream)
    if isinstance(report.get("ms_per_frame"), (int, float)):
        print(f"  {report['ms_per_frame']:.1f} ms/frame", file=stream)
    if report.get("online"):
        o = report["online"]
        rate = f"{o['rate_hz']:g} Hz" if o["rate_hz"] > 0 else "the frames' timestamps"
        print(f"  online at {rate}: processed {o['processed']}/{o['frames']} frames ({o['dropped']} dropped), lag "
              f"median {o['lag_ms_median']} ms, p95 {o['lag_ms_p95']} ms (depends on timing)", file=stream)
    if not getattr(args, "quiet", False):
        repeats = int(report.get("repeats", 1) or 1)
        many = " (median of {repeats} runs)".format(repeats=repeats) if repeats > 1 else ""
        ate = report.get("metrics", {}).get("ate_rmse_m")
        masks = f"{report['masks']} ({report.get('masks_origin')})" if report.get("masks") else "none"
        tracked = report.get("tracked") if isinstance(report.get("tracked"), (int, float)) else 0
        print(summary_line(report["method"], masks,
                           camera_text(report.get("camera", "?"), report.get("camera_source", "?"),
                                       getattr(args, "camera", None)),
                           tracked, report.get("frames", report.get("frames_expected", 0)), ate,
                           [report.get("trajectory"), getattr(args, "metrics_json", None)], ate_note=many,
                           min_share=run.min_tracked_share if run.fragment else None),
              file=stream)
    code = {"ok": 0, "lost": 1, "reset": 1}.get(report["status"], 2)
    return EXIT_FRAGMENT if code != 2 and run.fragment else code


def _warn_depth_scale(seq, config) -> None:
    """The depth-scale check (:mod:`d2slam.data.depth_scale`, seeded with the run's seed): a warning on stderr naming
    the factor to set."""
    warning = depth_scale_warning(seq, config, seed=config.engine.seed)
    if warning:
        print(f"d2slam: warning: {warning}", file=sys.stderr)


def camera_text(name: str, source: str, camera_arg: str | None) -> str:
    """The camera of a run and where it came from (the run JSON's ``camera.source``: a settings file, the synthetic
    sequence's ``scene.json``, the TUM folder name, or ``--camera NAME``), for the summary line."""
    named = camera_arg and source == camera_arg and not is_camera_file(camera_arg)
    return f"{name} ({'--camera ' + source if named else source})"


def summary_line(method: str, masks: str, camera: str, tracked: float, frames: float, ate_m: float | None,
                 outputs, ate_note: str = "", min_share: float | None = None) -> str:
    """The one line ``d2slam run`` ends with (the engine's methods and the real ORB-SLAM3 alike), easy to grep:
    ``d2slam run: method M; masks KIND (ORIGIN); camera NAME (ORIGIN); tracked T/N frames; ATE X m; wrote FILES``.
    A fragment (less than ``min_share`` of the frames tracked, ``d2slam.run.record.is_fragment``; None: not judged) says
    so: ``tracked T/N frames (S %): a fragment, below M %; ATE X m over the tracked fragment only``."""

    share = tracked_share(tracked, frames)
    fragment = min_share is not None and is_fragment(share, min_share)
    note = f" ({100 * share:.1f} %): a fragment, below {100 * min_share:g} %" if fragment else ""
    ate = (f"ATE {ate_m:.4f} m{ate_note}" + (" over the tracked fragment only" if fragment else "")
           if ate_m is not None else "no ATE")
    wrote = ", ".join(str(o) for o in outputs if o) or "nothing"
    return (f"d2slam run: method {method}; masks {masks}; camera {camera}; tracked {tracked:.0f}/{frames:.0f} "
            f"frames{note}; {ate}; wrote {wrote}")


def process_start() -> float:
    """When this process started (epoch seconds): ``startup_s`` of the run JSON is the time from there to the end
    of the first frame (imports, opening the sequence, loading or compiling kernels, the first frame)."""
    return psutil.Process().create_time()
