"""Does a trajectory belong to a ground truth? What ``d2slam eval`` checks before it reports an ATE.

Synthetic sequences share one clock, so a trajectory run on one of them overlaps in time with the ground truth of
any other and evo aligns it without complaint. Three checks, the first that can decide does:

1. identity: the trajectory's header (``d2slam run`` and the ORB-SLAM3 baseline write the sequence folder there)
   names a synthetic sequence, and the ground truth is one too (its folder's ``scene.json`` or the ``# file:``
   line ``d2slam synth`` writes in ``groundtruth.txt``): the scenario and seed must agree (a static twin shares its
   sequence's camera path, so the twin flag does not count);
2. frame times: the ground truth is a sequence folder (or its ``groundtruth.txt``) with ``rgb.txt``: a trajectory of
   this sequence has its poses at the frame times, so at least ``BelongsConfig.eval_min_frame_share`` of its timestamps
   must be in ``rgb.txt`` or ``depth.txt`` (each synthetic scenario and seed has its own frame jitter);
   Against a bare ground-truth file, a trajectory whose header names the sequence it was run on is checked against
   that sequence's ``groundtruth.txt`` (the same positions within ``eval_same_gt_m``);
3. residual, when nothing else can decide (a bare ground-truth file, a trajectory without such a header): an ATE
   RMSE beyond ``eval_ate_floor_m`` and ``eval_ate_extent_ratio`` times the ground truth's own extent (RMS distance
   of the matched positions from their centroid) while the estimate spans no more than ``eval_est_extent_max`` times
   that extent is refused: a compact trajectory that does not fit is another one. A run that failed usually
   wanders off (a large extent) and passes; some do not (docs/inputs.md), hence ``--force``.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from d2slam.data.tum import interpolate_poses, read_file_list, read_tum_trajectory
from d2slam.errors import D2SlamError
from d2slam.eval.config import BelongsConfig
from d2slam.eval.trajectory import aligned_estimate

_RUN_HEADER = re.compile(r"^#\s*d2slam (?:run --method \S+|orbslam3 \([^)]*\)) (?P<root>.+?)\s*$")
_SYNTH_HEADER = re.compile(r"^#\s*file: 'd2slam-synth (?P<scenario>\S+) seed (?P<seed>-?\d+)(?P<twin> static twin)?'")


def header_lines(path: Path) -> list[str]:
    """The comment lines at the top of a TUM text file (before its first data line)."""
    lines = []
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            for line in fh:
                if line.strip() and not line.lstrip().startswith("#"):
                    break
                lines.append(line.rstrip("\n"))
    except OSError:
        return []
    return lines


def run_sequence(traj_path: Path) -> Path | None:
    """The sequence folder a trajectory's header names (as given to ``d2slam run``: absolute, or relative to the
    current folder or to the trajectory's), when it exists."""
    for line in header_lines(traj_path):
        m = _RUN_HEADER.match(line)
        if m:
            root = Path(m.group("root")).expanduser()
            for candidate in ([root] if root.is_absolute() else [Path.cwd() / root, traj_path.parent / root]):
                if candidate.is_dir():
                    return candidate.resolve()
    return None


def synthetic_identity(folder: Path | None, gt_file: Path | None = None) -> tuple[str, int] | None:
    """(scenario, seed) of a synthetic sequence: its ``scene.json``, else the ``# file:`` line of its ground truth."""
    if folder is not None and (folder / "scene.json").is_file():
        try:
            scene = json.loads((folder / "scene.json").read_text())
            return str(scene["scenario"]), int(scene["seed"])
        except (OSError, ValueError, KeyError, TypeError):
            pass
    for path in (gt_file, folder / "groundtruth.txt" if folder is not None else None):
        if path is not None and path.is_file():
            for line in header_lines(path):
                m = _SYNTH_HEADER.match(line)
                if m:
                    return m.group("scenario"), int(m.group("seed"))
    return None


def frame_share(timestamps: np.ndarray, folder: Path, tol: float) -> float | None:
    """Share of ``timestamps`` within ``tol`` s of a frame time of ``folder`` (``rgb.txt`` or ``depth.txt``); None
    when the folder lists no frames."""
    frames = []
    for name in ("rgb.txt", "depth.txt"):
        if (folder / name).is_file():
            try:
                frames.append(read_file_list(folder / name)[0])
            except D2SlamError:
                continue
    if not frames or len(timestamps) == 0:
        return None
    ref = np.unique(np.concatenate(frames))
    if ref.size == 0:
        return None
    ts = np.asarray(timestamps, dtype=np.float64)
    k = np.clip(np.searchsorted(ref, ts), 1, max(1, len(ref) - 1))
    near = np.minimum(np.abs(ts - ref[k - 1]), np.abs(ts - ref[np.minimum(k, len(ref) - 1)]))
    return float(np.mean(near <= tol))


def same_poses(a, b, tol_m: float) -> bool:
    """Whether trajectories ``a`` and ``b`` hold the same positions (within ``tol_m``) wherever both have poses
    (``b`` interpolated at ``a``'s times; at least 3 common poses)."""
    at = interpolate_poses(b.timestamps, b.poses, a.timestamps)
    ok = np.isfinite(at).all(axis=(1, 2))
    if ok.sum() < 3:
        return False
    return bool(np.max(np.linalg.norm(at[ok, :3, 3] - np.asarray(a.poses)[ok, :3, 3], axis=1)) <= tol_m)


def residual_check(gt_xyz: np.ndarray, est_xyz: np.ndarray,
                   cli: BelongsConfig = BelongsConfig()) -> tuple[bool, float, float, float]:
    """The residual rule (module docstring, 3) on matched ground-truth and aligned estimated positions (M, 3):
    (refused, ATE RMSE, the ground truth's extent, the estimate's extent), extents as RMS distances from the
    centroid."""
    def rms(x):
        return float(np.sqrt(np.mean(np.sum((x - x.mean(axis=0)) ** 2, axis=1))))

    ate = float(np.sqrt(np.mean(np.sum((gt_xyz - est_xyz) ** 2, axis=1))))
    extent, spread = rms(gt_xyz), rms(est_xyz)
    refused = ate > max(cli.eval_ate_floor_m, cli.eval_ate_extent_ratio * extent) and \
        spread <= cli.eval_est_extent_max * extent
    return refused, ate, extent, spread


def _who(ident: tuple[str, int]) -> str:
    return f"{ident[0]} seed {ident[1]}"


def check_belongs(gt, est, gt_file: Path, gt_folder: Path | None, traj_path: Path,
                  cli: BelongsConfig = BelongsConfig()) -> str:
    """Why ``est`` (read from ``traj_path``) belongs to ``gt`` (read from ``gt_file``, in the sequence folder
    ``gt_folder`` when there is one), as a short reason; a one-line :class:`D2SlamError` when it does not (module
    docstring)."""
    force = "; --force evaluates it anyway"
    folder = gt_folder if gt_folder is not None else (gt_file.parent if (gt_file.parent / "rgb.txt").is_file()
                                                      else None)
    source = run_sequence(traj_path)
    if source is not None:
        ran, truth = synthetic_identity(source), synthetic_identity(folder, gt_file)
        if ran is not None and truth is not None:
            if ran != truth:
                raise D2SlamError(f"the trajectory was run on {source} ({_who(ran)}), the ground truth is of "
                                  f"{_who(truth)}{force}", path=traj_path)
            return f"same sequence ({_who(ran)})"
        if folder is not None and source == folder.resolve():
            return "same sequence folder"
        if folder is None and (source / "groundtruth.txt").is_file():
            if not same_poses(gt, read_tum_trajectory(source / "groundtruth.txt"), cli.eval_same_gt_m):
                raise D2SlamError(f"the trajectory was run on {source}, whose groundtruth.txt is not this ground "
                                  f"truth{force}", path=traj_path)
            return f"the ground truth of {source}, where it was run"
    if folder is not None:
        share = frame_share(est.timestamps, folder, cli.eval_frame_tolerance_s)
        if share is not None:
            if share < cli.eval_min_frame_share:
                raise D2SlamError(f"only {100 * share:.0f} % of the trajectory's {len(est.timestamps)} timestamps are "
                                  f"frame times of {folder} (rgb.txt, depth.txt; {100 * cli.eval_min_frame_share:.0f} "
                                  f"% needed): it was not run on this sequence{force}", path=traj_path)
            return f"{100 * share:.0f} % of its timestamps are frame times of the sequence"

    gt_xyz, est_xyz, _ = aligned_estimate(gt, est)
    refused, ate, extent, spread = residual_check(gt_xyz, est_xyz, cli)
    if refused:
        raise D2SlamError(f"ATE RMSE {ate:.3f} m is {ate / max(extent, 1e-12):.1f} times the ground truth's extent "
                          f"({extent:.3f} m RMS about its centroid over {len(gt_xyz)} matched poses) while the "
                          f"estimate spans as little ({spread:.3f} m): it looks like another trajectory (give the "
                          f"sequence folder to check its frame times){force}", path=traj_path)
    return f"ATE within the ground truth's extent ({extent:.3f} m)"
