"""TUM RGB-D sequences: list files, RGB/depth association, lazy frames, ground truth, trajectory files.

The layout (https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats)::

    ROOT/rgb.txt          "timestamp filename" per line (filename relative to ROOT, e.g. rgb/1305031102.175304.png)
    ROOT/depth.txt        same, 16-bit PNG depth images (value / 5000 = metres, 0 = no measurement)
    ROOT/groundtruth.txt  "timestamp tx ty tz qx qy qz qw": T_world_camera (optional: a sequence without it has
                          ``groundtruth is None``)

Parsing rules (those of TUM's ``associate.py``, made strict): lines whose first non-blank character is ``#`` and
blank lines are skipped; fields are separated by any whitespace (commas count as whitespace, as in TUM's tools).
Everything else is an error naming the file and line: a wrong number of columns, a non-numeric or non-finite
number, timestamps that are not strictly increasing (unsorted or duplicated).

Association (:func:`associate`) reproduces ``associate.py``: every pair (a, b) with ``|a - (b + offset)| < max_dt``
is a candidate, candidates are taken greedily by increasing ``|a - (b + offset)|`` (ties by a, then b) and each
timestamp is used at most once. Vectorised: candidates come from ``searchsorted`` on the sorted lists.

Images are read only when a frame is requested. They are never undistorted: the camera carries the distortion
coefficients and the engine undistorts keypoints.

Ground-truth lookup (:meth:`TumSequence.gt_poses`): linear interpolation of the translation and SLERP of the
rotation between the two bracketing samples. Policy outside the data: a time before the first or after the last
sample, or inside a gap between samples longer than ``max_gap`` seconds (motion-capture dropouts), gives a pose
full of NaN from ``gt_poses`` and a :class:`D2SlamError` from ``gt_pose``. A time equal to a sample returns that
sample exactly.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from d2slam.data.base import Camera, RGBDFrame, Trajectory
from d2slam.data.config import DataConfig
from d2slam.data.intrinsics import resolve_camera
from d2slam.errors import D2SlamError
from d2slam.outputs import write_bytes

# The constants live in ``d2slam.config.DataConfig``; these names are their defaults here.
#: RGB/depth association tolerance of TUM's associate.py (seconds).
DEFAULT_MAX_DT = DataConfig().max_dt
#: Ground-truth interpolation refuses to bridge gaps between samples longer than this (seconds); TUM ground truth
#: is 100 Hz, so 0.1 s is ten missing samples.
DEFAULT_GT_MAX_GAP = DataConfig().gt_max_gap
#: A quaternion whose norm is further than this from 1 is an error (TUM files are unit to ~1e-4).
QUATERNION_NORM_TOLERANCE = DataConfig().quaternion_norm_tolerance
#: A rotation block with ``|R^T R - I| > tol`` or ``det(R) <= 0`` is rejected by the trajectory writer.
ROTATION_TOLERANCE = DataConfig().rotation_tolerance

_TRAJECTORY_HEADER = "# timestamp tx ty tz qx qy qz qw"


# ------------------------------------------------------------------------------------------------------------------
# Text files
# ------------------------------------------------------------------------------------------------------------------
def _read_rows(path: Path) -> list[tuple[int, list[str]]]:
    """Non-comment, non-blank lines of a TUM text file as (1-based line number, fields)."""
    path = Path(path)
    if not path.is_file():
        raise D2SlamError("file not found" if not path.exists() else "not a regular file", path=path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise D2SlamError(f"not a text file ({exc.reason})", path=path) from None
    except OSError as exc:
        raise D2SlamError(f"cannot read: {exc.strerror or exc}", path=path) from None
    rows = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        rows.append((lineno, stripped.replace(",", " ").split()))
    return rows


def _parse_float(token: str, what: str, path: Path, lineno: int) -> float:
    try:
        value = float(token)
    except ValueError:
        raise D2SlamError(f"{what} {token!r} is not a number", path=path, line=lineno) from None
    if not math.isfinite(value):
        raise D2SlamError(f"{what} {token!r} is not finite", path=path, line=lineno)
    return value


def _numeric_table(rows: list[tuple[int, list[str]]], names: tuple[str, ...], path: Path) -> np.ndarray:
    """The first ``len(names)`` fields of every row as a finite float64 (N, len(names)) array. Fast path: one
    numpy conversion; on failure, the first bad token is located and reported with its line."""
    k = len(names)
    try:
        arr = np.array([fields[:k] for _, fields in rows], dtype=np.float64).reshape(-1, k)
    except ValueError:
        arr = None
    if arr is not None and np.isfinite(arr).all():
        return arr
    for lineno, fields in rows:
        for tok, name in zip(fields, names):
            _parse_float(tok, name, path, lineno)
    raise AssertionError("unreachable: a bad value was not located")  # pragma: no cover


def _check_increasing(timestamps: np.ndarray, lines: np.ndarray, path: Path) -> None:
    if len(timestamps) < 2:
        return
    bad = np.flatnonzero(np.diff(timestamps) <= 0)
    if len(bad):
        i = int(bad[0]) + 1
        kind = "duplicated" if timestamps[i] == timestamps[i - 1] else "not after the previous one"
        raise D2SlamError(f"timestamp {timestamps[i]:.6f} is {kind} ({timestamps[i - 1]:.6f} on line "
                          f"{int(lines[i - 1])}); timestamps must be strictly increasing", path=path,
                          line=int(lines[i]))


def read_file_list(path: str | Path) -> tuple[np.ndarray, list[str], np.ndarray]:
    """Read ``rgb.txt`` / ``depth.txt``: (timestamps (N,) float64 strictly increasing, filenames, line numbers)."""
    path = Path(path)
    rows = _read_rows(path)
    for lineno, fields in rows:
        if len(fields) != 2:
            raise D2SlamError(f"expected 2 columns 'timestamp filename', found {len(fields)}", path=path,
                              line=lineno)
    names = [fields[1] for _, fields in rows]
    ln = np.asarray([lineno for lineno, _ in rows], dtype=np.int64)
    ts = _numeric_table(rows, ("timestamp",), path).reshape(-1)
    _check_increasing(ts, ln, path)
    return ts, names, ln


def _poses_from_tum(values: np.ndarray, lines: np.ndarray, path: Path) -> np.ndarray:
    """(N, 7) tx ty tz qx qy qz qw -> (N, 4, 4) T_world_camera, with unit-quaternion validation."""
    quat = values[:, 3:7]
    norms = np.linalg.norm(quat, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > QUATERNION_NORM_TOLERANCE)
    if len(bad):
        i = int(bad[0])
        raise D2SlamError(f"quaternion (qx qy qz qw) has norm {norms[i]:.6g}, expected 1", path=path,
                          line=int(lines[i]))
    poses = np.tile(np.eye(4), (len(values), 1, 1))
    if len(values):
        poses[:, :3, :3] = Rotation.from_quat(quat / norms[:, None]).as_matrix()
        poses[:, :3, 3] = values[:, :3]
    return poses


def read_tum_trajectory(path: str | Path) -> Trajectory:
    """Read a TUM trajectory file (``timestamp tx ty tz qx qy qz qw`` per line, T_world_camera) into a
    :class:`Trajectory`. Errors (naming file and line): wrong column count, non-numeric or non-finite values,
    timestamps not strictly increasing, a quaternion that is not unit (norm off by more than 1e-2; smaller
    deviations are normalised away). An empty file gives an empty trajectory."""
    path = Path(path)
    rows = _read_rows(path)
    for lineno, fields in rows:
        if len(fields) != 8:
            raise D2SlamError(f"expected 8 columns 'timestamp tx ty tz qx qy qz qw', found {len(fields)}",
                              path=path, line=lineno)
    arr = _numeric_table(rows, ("timestamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw"), path)
    ln = np.asarray([lineno for lineno, _ in rows], dtype=np.int64)
    _check_increasing(arr[:, 0], ln, path)
    poses = _poses_from_tum(arr[:, 1:], ln, path)
    return Trajectory(timestamps=arr[:, 0].copy(), poses=poses, meta={"path": str(path), "lines": ln})


def validate_trajectory(traj: Trajectory, what: str = "trajectory") -> None:
    """Shapes (N,) / (N, 4, 4), finite values, strictly increasing timestamps, rigid transforms (orthonormal
    rotation with det +1, last row 0 0 0 1). Raises D2SlamError naming the first bad pose."""
    ts = np.asarray(traj.timestamps)
    poses = np.asarray(traj.poses)
    if ts.ndim != 1 or poses.ndim != 3 or poses.shape[1:] != (4, 4) or len(ts) != len(poses):
        raise D2SlamError(f"{what}: expected timestamps (N,) and poses (N, 4, 4), got {ts.shape} and "
                          f"{poses.shape}")
    if len(ts) == 0:
        return
    finite = np.isfinite(ts) & np.isfinite(poses).all(axis=(1, 2))
    if not finite.all():
        raise D2SlamError(f"{what}: pose {int(np.argmin(finite))} has a non-finite timestamp or value")
    bad = np.flatnonzero(np.diff(ts) <= 0)
    if len(bad):
        i = int(bad[0]) + 1
        raise D2SlamError(f"{what}: timestamp {i} ({ts[i]:.6f}) is not after timestamp {i - 1} "
                          f"({ts[i - 1]:.6f}); timestamps must be strictly increasing")
    last_row_ok = np.all(np.abs(poses[:, 3, :] - np.array([0.0, 0.0, 0.0, 1.0])) < ROTATION_TOLERANCE, axis=1)
    rot = poses[:, :3, :3]
    ortho_err = np.abs(np.einsum("nji,njk->nik", rot, rot) - np.eye(3)).max(axis=(1, 2))
    rigid = last_row_ok & (ortho_err < ROTATION_TOLERANCE) & (np.linalg.det(rot) > 0)
    if not rigid.all():
        i = int(np.argmin(rigid))
        raise D2SlamError(f"{what}: pose {i} (t={ts[i]:.6f}) is not a rigid transform (rotation not orthonormal "
                          f"with det +1, or last row not 0 0 0 1)")


def write_tum_trajectory(path: str | Path, traj: Trajectory, header: str | None = None) -> Path:
    """Write ``traj`` in the TUM format: ``timestamp tx ty tz qx qy qz qw`` with 6 decimals for the timestamp
    and 9 for the pose (quaternion with qw >= 0), preceded by a ``#`` header. The trajectory is validated first
    (:func:`validate_trajectory`); the file is written atomically. Returns the path."""
    path = Path(path)
    validate_trajectory(traj, what=f"trajectory for {path}")
    ts = np.asarray(traj.timestamps, dtype=np.float64)
    poses = np.asarray(traj.poses, dtype=np.float64)
    lines = [_TRAJECTORY_HEADER] if header is None else [f"# {h}" for h in header.splitlines()] + [
        _TRAJECTORY_HEADER]
    if len(ts):
        quat = Rotation.from_matrix(poses[:, :3, :3]).as_quat(canonical=True)
        table = np.column_stack([ts, poses[:, :3, 3], quat])
        lines += [f"{r[0]:.6f} " + " ".join(f"{v:.9f}" for v in r[1:]) for r in table]
    if not path.parent.is_dir():
        raise D2SlamError("output folder does not exist", path=path.parent)

    return write_bytes(path, "\n".join(lines) + "\n")  # whole or not at all; a failed write is one line


# ------------------------------------------------------------------------------------------------------------------
# Association and interpolation (pure array functions)
# ------------------------------------------------------------------------------------------------------------------
def associate(first: np.ndarray, second: np.ndarray, max_dt: float = DEFAULT_MAX_DT,
              offset: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """TUM ``associate.py`` on sorted timestamp arrays: indices ``(i, j)`` of the matched pairs, sorted by
    ``first[i]``.

    Candidates are all pairs with ``|first[i] - (second[j] + offset)| < max_dt`` (strict, as in associate.py),
    found per ``i`` by ``searchsorted``; they are accepted greedily by increasing difference (ties by first, then
    second timestamp), each index used at most once. The greedy pass is done in vectorised rounds: a candidate
    that is the best remaining one for both its ``i`` and its ``j`` is exactly one the sequential greedy accepts,
    so every round accepts all of them and drops the candidates they conflict with.
    """
    a = np.asarray(first, dtype=np.float64)
    b = np.asarray(second, dtype=np.float64)
    empty = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
    if len(a) == 0 or len(b) == 0:
        return empty
    shifted = b + offset
    order_b = np.argsort(shifted, kind="stable")
    sb = shifted[order_b]
    window = max_dt * (1.0 + 1e-9) + 1e-9  # a hair wider than max_dt: the exact test below decides
    lo = np.searchsorted(sb, a - window, side="left")
    hi = np.searchsorted(sb, a + window, side="right")
    counts = hi - lo
    if counts.sum() == 0:
        return empty
    ia = np.repeat(np.arange(len(a)), counts)
    starts = np.repeat(lo - np.concatenate([[0], np.cumsum(counts)[:-1]]), counts)
    jb = order_b[starts + np.arange(len(ia))]
    diff = np.abs(a[ia] - (b[jb] + offset))
    keep = diff < max_dt
    ia, jb, diff = ia[keep], jb[keep], diff[keep]
    if len(ia) == 0:
        return empty
    rank_order = np.lexsort((b[jb], a[ia], diff))
    ia, jb = ia[rank_order], jb[rank_order]
    rank = np.arange(len(ia))
    partner = np.full(len(a), -1, dtype=np.int64)
    used_b = np.zeros(len(b), dtype=bool)
    alive = np.ones(len(ia), dtype=bool)
    big = len(ia)
    while alive.any():
        best_a = np.full(len(a), big)
        best_b = np.full(len(b), big)
        np.minimum.at(best_a, ia[alive], rank[alive])
        np.minimum.at(best_b, jb[alive], rank[alive])
        # distinct i and j within a round: each i (j) has a single best-ranked candidate
        accept = alive & (best_a[ia] == rank) & (best_b[jb] == rank)
        partner[ia[accept]] = jb[accept]
        used_b[jb[accept]] = True
        alive &= (partner[ia] < 0) & ~used_b[jb]
    out_a = np.flatnonzero(partner >= 0)
    return out_a, partner[out_a]


def interpolate_poses(timestamps: np.ndarray, poses: np.ndarray, query: np.ndarray,
                      max_gap: float | None = DEFAULT_GT_MAX_GAP) -> np.ndarray:
    """Poses at ``query`` times (M,) -> (M, 4, 4): linear translation, SLERP rotation between the bracketing
    samples of the strictly increasing ``timestamps`` (N,). A query equal to a sample returns it exactly. Queries
    outside ``[timestamps[0], timestamps[-1]]``, or between two samples more than ``max_gap`` s apart (None = any
    gap), give NaN poses."""
    ts = np.asarray(timestamps, dtype=np.float64)
    poses = np.asarray(poses, dtype=np.float64)
    q = np.atleast_1d(np.asarray(query, dtype=np.float64))
    out = np.full((len(q), 4, 4), np.nan)
    if len(ts) == 0 or len(q) == 0:
        return out
    exact_idx = np.clip(np.searchsorted(ts, q, side="left"), 0, len(ts) - 1)
    exact = ts[exact_idx] == q
    inside = (q > ts[0]) & (q < ts[-1]) & ~exact
    if len(ts) >= 2 and inside.any():
        qi = q[inside]
        k = np.searchsorted(ts, qi, side="right") - 1  # ts[k] < qi < ts[k + 1]
        t0, t1 = ts[k], ts[k + 1]
        ok = np.ones(len(qi), dtype=bool) if max_gap is None else (t1 - t0) <= max_gap
        alpha = ((qi - t0) / (t1 - t0))[:, None]
        res = np.full((len(qi), 4, 4), np.nan)
        if ok.any():
            slerp = Slerp(ts, Rotation.from_matrix(poses[:, :3, :3]))
            block = np.tile(np.eye(4), (int(ok.sum()), 1, 1))
            block[:, :3, :3] = slerp(qi[ok]).as_matrix()
            block[:, :3, 3] = (1.0 - alpha[ok]) * poses[k[ok], :3, 3] + alpha[ok] * poses[k[ok] + 1, :3, 3]
            res[ok] = block
        out[inside] = res
    out[exact] = poses[exact_idx[exact]]
    return out


# ------------------------------------------------------------------------------------------------------------------
# Images
# ------------------------------------------------------------------------------------------------------------------
def _imread(path: Path, list_file: Path | None, line: int | None) -> np.ndarray:
    if not path.is_file():
        raise D2SlamError(f"image {path} not found", path=list_file or path, line=line)
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise D2SlamError(f"image {path} cannot be decoded (corrupt or truncated PNG?)", path=list_file or path,
                          line=line)
    return img


def read_rgb(path: str | Path, list_file: Path | None = None, line: int | None = None,
             shape: tuple[int, int] | None = None) -> np.ndarray:
    """8-bit colour PNG -> (H, W, 3) uint8 in RGB order (an alpha channel is dropped). Anything else (grey,
    16-bit, undecodable, wrong (H, W)) is a D2SlamError naming the list file and line."""
    path = Path(path)
    img = _imread(path, list_file, line)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] not in (3, 4):
        raise D2SlamError(f"image {path} is not an 8-bit colour image (dtype {img.dtype}, shape {img.shape})",
                          path=list_file or path, line=line)
    if shape is not None and img.shape[:2] != tuple(shape):
        raise D2SlamError(f"image {path} is {img.shape[1]}x{img.shape[0]}, the camera is {shape[1]}x{shape[0]}",
                          path=list_file or path, line=line)
    code = cv2.COLOR_BGRA2RGB if img.shape[2] == 4 else cv2.COLOR_BGR2RGB
    return cv2.cvtColor(img, code)


def read_depth(path: str | Path, depth_factor: float, list_file: Path | None = None, line: int | None = None,
               shape: tuple[int, int] | None = None) -> np.ndarray:
    """16-bit single-channel PNG -> (H, W) float32 metres = value / depth_factor (0 stays 0 = invalid). An 8-bit
    image (a common export mistake that would silently give depths of at most 5 cm), several channels, an
    undecodable file or a wrong (H, W) is a D2SlamError naming the list file and line."""
    path = Path(path)
    img = _imread(path, list_file, line)
    if img.dtype == np.uint8:
        raise D2SlamError(f"depth image {path} is 8-bit; TUM depth images are 16-bit PNGs (metres x "
                          f"{depth_factor:g})", path=list_file or path, line=line)
    if img.dtype != np.uint16 or img.ndim != 2:
        raise D2SlamError(f"depth image {path} is not a 16-bit single-channel image (dtype {img.dtype}, "
                          f"shape {img.shape})", path=list_file or path, line=line)
    if shape is not None and img.shape != tuple(shape):
        raise D2SlamError(f"depth image {path} is {img.shape[1]}x{img.shape[0]}, the camera is "
                          f"{shape[1]}x{shape[0]}", path=list_file or path, line=line)
    return img.astype(np.float32) / np.float32(depth_factor)


# ------------------------------------------------------------------------------------------------------------------
# The sequence
# ------------------------------------------------------------------------------------------------------------------
class TumSequence:
    """A TUM RGB-D folder as a lazy sequence of associated RGB-D frames (the ``Sequence`` protocol).

    ``camera``: a :class:`Camera`, a name (``"fr1"``, ``"freiburg3"``, ...) or None to choose it from the folder
    name. ``max_dt`` / ``offset``: association tolerance and the offset added to depth timestamps (associate.py).
    Construction parses and validates the three text files, associates, and checks that every associated image
    exists; images are decoded (and checked) when a frame is requested.

    Attributes: ``name``, ``root``, ``camera``, ``timestamps`` (RGB times of the frames), ``depth_timestamps``,
    ``rgb_files`` / ``depth_files`` (paths), ``n_rgb`` / ``n_depth`` (entries in the list files).
    """

    def __init__(self, root: str | Path, camera: Camera | str | None = None, max_dt: float = DEFAULT_MAX_DT,
                 offset: float = 0.0):
        root = Path(root).expanduser()
        if not root.exists():
            raise D2SlamError("sequence folder not found", path=root)
        if not root.is_dir():
            raise D2SlamError("not a folder (expected a TUM sequence folder with rgb.txt, depth.txt)", path=root)
        if not (max_dt > 0 and math.isfinite(max_dt)) or not math.isfinite(offset):
            raise D2SlamError(f"max_dt must be a positive number and offset finite (got {max_dt}, {offset})")
        self.root = root
        self.name = root.resolve().name
        self.max_dt = float(max_dt)
        self.offset = float(offset)
        self.camera = self._load_camera(camera)
        self._rgb_list = root / "rgb.txt"
        self._depth_list = root / "depth.txt"
        rgb_ts, rgb_names, rgb_lines = read_file_list(self._rgb_list)
        depth_ts, depth_names, depth_lines = read_file_list(self._depth_list)
        if len(rgb_ts) == 0:
            raise D2SlamError("no frames: the list has no entries", path=self._rgb_list)
        if len(depth_ts) == 0:
            raise D2SlamError("no frames: the list has no entries", path=self._depth_list)
        self.n_rgb, self.n_depth = len(rgb_ts), len(depth_ts)
        ia, jb = associate(rgb_ts, depth_ts, self.max_dt, self.offset)
        if len(ia) == 0:
            raise D2SlamError(
                f"no RGB/depth pair within {self.max_dt:g} s (offset {self.offset:g} s): rgb.txt spans "
                f"[{rgb_ts[0]:.6f}, {rgb_ts[-1]:.6f}], depth.txt spans [{depth_ts[0]:.6f}, {depth_ts[-1]:.6f}]",
                path=self._depth_list)
        self.timestamps = rgb_ts[ia]
        self.depth_timestamps = depth_ts[jb]
        self.rgb_files = [self._resolve(rgb_names[i]) for i in ia]
        self.depth_files = [self._resolve(depth_names[j]) for j in jb]
        self._rgb_lines = rgb_lines[ia]
        self._depth_lines = depth_lines[jb]
        self._check_files_exist(self.rgb_files, self._rgb_lines, self._rgb_list)
        self._check_files_exist(self.depth_files, self._depth_lines, self._depth_list)
        gt_path = root / "groundtruth.txt"
        self._groundtruth = read_tum_trajectory(gt_path) if gt_path.exists() else None
        if self._groundtruth is not None and len(self._groundtruth) == 0:
            raise D2SlamError("ground truth has no poses (delete the file if the sequence has none)", path=gt_path)

    # -- construction helpers ---------------------------------------------------------------------------------
    def _load_camera(self, camera: Camera | str | None) -> Camera:
        return resolve_camera(camera, self.root.resolve())

    def _resolve(self, name: str) -> Path:
        p = Path(name)
        return p if p.is_absolute() else self.root / p

    @staticmethod
    def _check_files_exist(files: list[Path], lines: np.ndarray, list_file: Path) -> None:
        missing = [k for k, f in enumerate(files) if not f.is_file()]
        if missing:
            k = missing[0]
            more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
            raise D2SlamError(f"image {files[k]} not found{more}", path=list_file, line=int(lines[k]))

    # -- Sequence protocol ------------------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.timestamps)

    def __getitem__(self, index: int) -> RGBDFrame:
        index = int(index)
        n = len(self)
        if index < 0:
            index += n
        if not 0 <= index < n:
            raise IndexError(f"frame {index} out of range for {n} frames")
        shape = (self.camera.height, self.camera.width)
        rgb = read_rgb(self.rgb_files[index], self._rgb_list, int(self._rgb_lines[index]), shape)
        depth = read_depth(self.depth_files[index], self.camera.depth_factor, self._depth_list,
                           int(self._depth_lines[index]), shape)
        return RGBDFrame(index=index, timestamp=float(self.timestamps[index]),
                     depth_timestamp=float(self.depth_timestamps[index]), rgb=rgb, depth=depth,
                     rgb_path=self.rgb_files[index], depth_path=self.depth_files[index])

    def rgb_frame(self, index: int) -> RGBDFrame:
        """Frame ``index`` with its colour image alone (``depth`` None; what a segmenter reads, without decoding the
        depth image)."""
        index = int(index)
        if not 0 <= index < len(self):
            raise IndexError(f"frame {index} out of range for {len(self)} frames")
        rgb = read_rgb(self.rgb_files[index], self._rgb_list, int(self._rgb_lines[index]),
                       (self.camera.height, self.camera.width))
        return RGBDFrame(index=index, timestamp=float(self.timestamps[index]),
                         depth_timestamp=float(self.depth_timestamps[index]), rgb=rgb, depth=None,
                         rgb_path=self.rgb_files[index], depth_path=self.depth_files[index])

    def depth_image(self, index: int) -> np.ndarray:
        """The depth image (float32 metres) of frame ``index`` alone, without decoding the RGB image (runs that read
        stored features need only the depth)."""
        index = int(index)
        if not 0 <= index < len(self):
            raise IndexError(f"frame {index} out of range for {len(self)} frames")
        return read_depth(self.depth_files[index], self.camera.depth_factor, self._depth_list,
                          int(self._depth_lines[index]), (self.camera.height, self.camera.width))

    def __iter__(self) -> Iterator[RGBDFrame]:
        for i in range(len(self)):
            yield self[i]

    @property
    def groundtruth(self) -> Trajectory | None:
        return self._groundtruth

    # -- ground truth -----------------------------------------------------------------------------------------
    def gt_poses(self, timestamps, max_gap: float | None = DEFAULT_GT_MAX_GAP) -> np.ndarray:
        """Ground-truth T_world_camera at each time (M, 4, 4), interpolated (see the module docstring); NaN where
        there is no ground truth (outside its time range or in a gap longer than ``max_gap`` s)."""
        if self._groundtruth is None:
            raise D2SlamError("the sequence has no ground truth", path=self.root / "groundtruth.txt")
        gt = self._groundtruth
        return interpolate_poses(gt.timestamps, gt.poses, timestamps, max_gap)

    def gt_pose(self, t: float, max_gap: float | None = DEFAULT_GT_MAX_GAP) -> np.ndarray:
        """Ground-truth T_world_camera (4, 4) at time ``t``; D2SlamError where there is none."""
        pose = self.gt_poses([t], max_gap)[0]
        if np.isnan(pose).any():
            gt = self._groundtruth
            raise D2SlamError(f"no ground truth at t={t:.6f}: outside [{gt.timestamps[0]:.6f}, "
                              f"{gt.timestamps[-1]:.6f}] or in a gap longer than {max_gap} s",
                              path=self.root / "groundtruth.txt")
        return pose

    def frame_gt_poses(self, max_gap: float | None = DEFAULT_GT_MAX_GAP) -> np.ndarray:
        """Ground truth at every frame's RGB timestamp (len(self), 4, 4); NaN where there is none."""
        return self.gt_poses(self.timestamps, max_gap)

    def __repr__(self) -> str:
        return (f"{type(self).__name__}({str(self.root)!r}, camera={self.camera.name}, frames={len(self)}, "
                f"groundtruth={'yes' if self._groundtruth is not None else 'no'})")
