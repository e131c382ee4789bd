"""``d2slam bench startup``: how long a new ``d2slam run`` takes before its first frame, with and without the
compiled kernels in numba's cache.

Each case is ``d2slam run SEQ`` in a fresh process, numba's cache pointed at a temporary folder with
``$NUMBA_CACHE_DIR`` (the package's own cache is left alone); printed: ``startup_s`` of the run JSON (from the process
start to the end of the first frame: imports, opening the sequence, the masks, loading or compiling the kernels the
first frame needs, the first frame), the whole run's wall time and its frames per second.

1. *empty cache*: a fresh install without the warm-up of ``make install``; numba compiles each kernel on its first
   use, during the run;
2. *warm cache*: the same again, with the kernels the first run compiled (every later run, and a study's workers);
3. *after the warm-up*: ``python -m d2slam.run.warmup`` (``make install`` runs it) into another empty cache, then
   the run: the first run of a fresh install. Target: startup at most 10 s.

The run's ``onnx`` masks are segmented into the mask cache before the three cases.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from d2slam.data import SyntheticSequence, open_sequence
from d2slam.errors import D2SlamError
from d2slam.run.methods import get_method, mask_kind
from d2slam.run.record import EXIT_FRAGMENT
from d2slam.segmentation import cached_segmenter
from d2slam.study.sequences import ensure_sequence

DESCRIPTION = ("time to the first frame of a new `d2slam run` with an empty kernel cache, a warm one, and after "
               "the warm-up of `make install`")
TARGET_STARTUP_S = 10.0


def add_arguments(parser) -> None:
    parser.add_argument("sequence", nargs="?", metavar="SEQ",
                        help="sequence folder (default: the cached synthetic walking_xyz of development seed 0, "
                             "--frames frames)")
    parser.add_argument("--frames", type=int, default=60, help="frames of the default sequence (default 60)")
    parser.add_argument("--method", default="d2slam", help="run method (default d2slam)")
    parser.add_argument("--masks", default=None, help="--masks of the run (default: as `d2slam run` chooses)")


def _run(cmd: list[str], env: dict) -> tuple[float, subprocess.CompletedProcess]:
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    return time.perf_counter() - t0, proc


def run(args) -> int:
    if args.sequence:
        seq = Path(args.sequence)
        if not seq.is_dir():
            raise D2SlamError("no sequence folder", path=seq)
    else:
        seq = ensure_sequence("walking_xyz", 0, args.frames, False)
    _segment_first(seq, args.method, args.masks)

    with tempfile.TemporaryDirectory(prefix="d2slam_bench_startup_") as tmp:
        tmp = Path(tmp)
        base = {**os.environ}
        run_cmd = [sys.executable, "-m", "d2slam.cli", "run", str(seq), "--method", args.method,
                   "--out", str(tmp / "traj.txt"), "--metrics-json", str(tmp / "run.json"), "--quiet"]
        if args.masks:
            run_cmd += ["--masks", args.masks]
        print(f"d2slam bench startup: `d2slam run {seq.name} --method {args.method}` in fresh processes; load "
              f"average (1 min) {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
        print(f"{'case':<34} {'startup s':>9} {'run s':>7} {'fps':>6}  target")
        rows = []
        for label, cache, warm in (("empty kernel cache", "a", False), ("warm kernel cache", "a", False),
                                   ("after python -m d2slam.run.warmup", "b", True)):
            env = {**base, "NUMBA_CACHE_DIR": str(tmp / cache)}
            if warm:
                wall, proc = _run([sys.executable, "-m", "d2slam.run.warmup"], env)
                if proc.returncode != 0:
                    raise D2SlamError(f"the warm-up failed: {(proc.stderr or proc.stdout).strip()[-300:]}")
                print(f"{'  (python -m d2slam.run.warmup)':<34} {'':>9} {wall:7.1f}")
            (tmp / "run.json").unlink(missing_ok=True)
            wall, proc = _run(run_cmd, env)
            if proc.returncode not in (0, EXIT_FRAGMENT) or not (tmp / "run.json").is_file():  # a fragment starts too
                raise D2SlamError(f"d2slam run failed: {(proc.stderr or proc.stdout).strip()[-300:]}")
            record = json.loads((tmp / "run.json").read_text())
            startup = float(record["startup_s"])
            verdict = f"<= {TARGET_STARTUP_S:g} s: {'met' if startup <= TARGET_STARTUP_S else 'NOT met'}"
            print(f"{label:<34} {startup:9.1f} {wall:7.1f} {record['fps']:6.1f}  {verdict}", flush=True)
            rows.append(startup)
    print("(startup: from the process start to the end of the first frame; later frames that first use a kernel "
          "compile it then, in the empty-cache case)")
    return 0


def _segment_first(path: Path, method: str, masks: str | None) -> None:
    """Fill the mask cache of the run's ``onnx`` masks beforehand, so that the cases time the start, not the
    segmentation."""
    seq = open_sequence(path)
    if mask_kind(get_method(method), masks, synthetic=isinstance(seq, SyntheticSequence)) == "onnx":
        cached_segmenter(seq, "onnx").fill(progress=True, recheck=False)
