"""Real against synthetic sensor, side by side: the statistics ``d2slam bench realism --real SEQ --twin SEQ`` prints
and ``docs/real_data.md`` quotes, as library functions (a notebook calls the same).

Everything here is measured on the *engine's own* inputs, the log of :func:`d2slam.run.observe.engine_log` (per frame
what a keypoint filter would see, and which map points the tracked frame matched). From that log:

- static epipolar error (eq 5) of every match against F found by RANSAC on the frame's matches (as the geometric
  module finds it), percentiles overall, by keypoint depth and by image radius (``SynthEvalConfig.realism_depth_bins``,
  ``realism_radius_bins``);
- the pose test's residuals (our deviation, ``PoseTestConfig.enabled``): reprojection error (px) and normalised
  depth residual |dz| / sigma of the relative pose found by PnP RANSAC on the matches with depth;
- track lengths: how many consecutive frames a map point stays matched (an inlier) in the tracked frames;
- depth holes: share of the image and of the keypoints without depth;
- FAST corners per frame (``d2slam.synth.realism.texture_stats``), the blur measure (:func:`blur_extent`: the length
  of the motion blur along the ground truth's image motion) and the ground truth's angular speed.

The sensor's calibration against the real recording uses the same log: :func:`fit_rolling_shutter` (the RGB
camera's row readout time and the timestamp's place in the exposure, from the epipolar error of the ground truth's
motion) and :func:`fit_exposure` (the exposure from the blur extent against the image speed).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from d2slam.data.config import DepthNoise
from d2slam.data.tum import interpolate_poses
from d2slam.dynamics.config import DynamicsConfig
from d2slam.dynamics.depth import depth_sigma
from d2slam.dynamics.geometric import back_project, epipolar_error, fundamental_matrix, pose_residuals, relative_pose
from d2slam.errors import D2SlamError
from d2slam.ranges import AnyConfig, part_of
from d2slam.slam.frame import undistort
from d2slam.synth.config import SynthConfig, SynthEvalConfig
from d2slam.synth.realism import texture_stats
from d2slam.synth.scene import Scene
from d2slam.synth.twin import RecordedPath, placement
from d2slam.synth.world import WorldRenderer



@dataclass
class EngineLog:
    """What :func:`engine_log` recorded on ``frames`` frames of a sequence."""

    name: str
    frames: int
    tracked: int
    timestamps: np.ndarray  # (n,) RGB timestamps of the frames run
    observed: list[dict]  # Observer.frames: one per frame
    tracks: list[np.ndarray] = field(default_factory=list)  # per frame: map point ids matched (inliers); empty if lost


# --------------------------------------------------------------------------------------------------
# motion blur
# --------------------------------------------------------------------------------------------------
def blur_extent(gray: np.ndarray, centre: tuple[float, float], direction: tuple[float, float], size: int,
                max_lag: int, min_dip: float) -> float:
    """Length (px) of the linear motion blur along ``direction`` in the ``size`` x ``size`` patch of ``gray`` around
    ``centre``, or NaN when the patch shows none that can be measured.

    The blur-identification method of Yitzhaky and Kopeika (1997): the patch is turned so that the motion runs along
    its rows; the derivative along the rows of an image blurred by a box of length L is the difference of two copies
    L apart, so its autocorrelation along the rows dips to a negative minimum at lag L. The extent is the lag of the
    deepest dip in [2, max_lag] whose normalised autocorrelation is below ``-min_dip`` (a weaker dip is texture, not
    blur)."""
    g = np.asarray(gray, np.float32)
    h, w = g.shape[:2]
    d = np.asarray(direction, float)
    n = float(np.hypot(*d))
    if n == 0 or not np.isfinite(n):
        return float("nan")
    ang = np.degrees(np.arctan2(d[1], d[0]))
    half = int(np.ceil(size * 0.75))  # the turned patch's corners stay inside the crop
    cx, cy = float(centre[0]), float(centre[1])
    if cx - half < 0 or cy - half < 0 or cx + half >= w or cy + half >= h:
        return float("nan")
    M = cv2.getRotationMatrix2D((cx, cy), ang, 1.0)  # rotates the motion direction onto +x
    M[:, 2] += np.array([size / 2.0 - cx, size / 2.0 - cy])
    patch = cv2.warpAffine(g, M, (size, size), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    dx = np.diff(patch, axis=1)
    dx -= dx.mean()
    var = float((dx * dx).mean())
    if var <= 1e-6:
        return float("nan")
    lags = np.arange(1, min(max_lag, dx.shape[1] - 2) + 1)
    ac = np.array([float((dx[:, :-k] * dx[:, k:]).mean()) for k in lags]) / var
    sel = lags >= 2
    k = int(np.argmin(np.where(sel, ac, np.inf)))
    return float(lags[k]) if ac[k] < -min_dip else float("nan")


def patch_grid(width: int, height: int, cols: int, rows: int, margin: int) -> np.ndarray:
    """(cols * rows, 2) patch centres on a regular grid ``margin`` px inside the image."""
    u = np.linspace(margin, width - 1 - margin, cols)
    v = np.linspace(margin, height - 1 - margin, rows)
    uu, vv = np.meshgrid(u, v)
    return np.stack([uu.ravel(), vv.ravel()], axis=1)


def image_velocity(camera, poses_at, t: float, px: np.ndarray, z: np.ndarray, h: float = 0.002) -> np.ndarray:
    """(K, 2) image velocity (px/s, in the camera's distorted image) at pixels ``px`` (K, 2, distorted) of scene
    points at depths ``z`` (K,) seen at time ``t``, from the camera poses ``poses_at(times) -> (n, 4, 4)``
    (``T_world_camera``): each point is fixed in the world and projected (with the lens distortion) at t -+ h."""
    K = camera.K
    und = undistort(np.asarray(px, np.float64).reshape(-1, 2), camera)
    Xc = np.stack([(und[:, 0] - K[0, 2]) / K[0, 0] * z, (und[:, 1] - K[1, 2]) / K[1, 1] * z, z], axis=1)
    T0, Ta, Tb = poses_at(np.array([t, t - h, t + h]))
    Xw = Xc @ T0[:3, :3].T + T0[:3, 3]
    out = []
    for T in (Ta, Tb):
        Xk = (Xw - T[:3, 3]) @ T[:3, :3]  # R^T (X - C)
        uv, _ = cv2.projectPoints(Xk.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, np.asarray(camera.dist))
        out.append(uv.reshape(-1, 2))
    return (out[1] - out[0]) / (2 * h)


def frame_blur(gray: np.ndarray, depth: np.ndarray, camera, poses_at, t: float,
               ev=None) -> tuple[np.ndarray, np.ndarray]:
    """Per patch of the realism grid (``SynthEvalConfig.realism_blur_*``): the image speed (px/s) the ground truth
    gives (``poses_at(times)``: ``T_world_camera``) and the blur extent measured along it (:func:`blur_extent`; NaN
    where none is measured)."""
    ev = ev or SynthEvalConfig()
    h, w = gray.shape[:2]
    c = patch_grid(w, h, ev.realism_blur_grid[0], ev.realism_blur_grid[1], ev.realism_blur_patch)
    r = ev.realism_blur_patch // 2
    z = np.array([np.median(d[d > 0]) if (d := depth[int(v) - r:int(v) + r, int(u) - r:int(u) + r]).size
                  and (d > 0).any() else np.nan for u, v in c])
    zf = np.where(np.isfinite(z), z, np.nanmedian(z) if np.isfinite(z).any() else 1.0)
    vel = image_velocity(camera, poses_at, t, c, zf)
    speed = np.hypot(vel[:, 0], vel[:, 1])
    ext = np.full(len(c), np.nan)
    for k in np.flatnonzero(speed > 0):
        ext[k] = blur_extent(gray, c[k], vel[k], ev.realism_blur_patch, ev.realism_blur_max_lag,
                             ev.realism_blur_min_dip)
    return speed, ext


def fit_exposure(speed: np.ndarray, extent: np.ndarray) -> tuple[float, float, int]:
    """(exposure s, intercept px, patches used): the robust (Theil-Sen) line ``extent = intercept + exposure x
    speed`` through the measured patches; the intercept holds what is not motion (the optics' blur, the measure's
    own bias of about a pixel)."""
    from scipy.stats import theilslopes

    ok = np.isfinite(speed) & np.isfinite(extent)
    if ok.sum() < 10:
        raise D2SlamError(f"too few patches with a measurable blur ({int(ok.sum())}) to fit the exposure")
    slope, icpt, _, _ = theilslopes(extent[ok], speed[ok])
    return float(slope), float(icpt), int(ok.sum())


# --------------------------------------------------------------------------------------------------
# per match: epipolar error, pose-test residuals
# --------------------------------------------------------------------------------------------------
@dataclass
class MatchStats:
    """Per frame-to-frame match of the logged frames (static by construction: real fr1/rpy and a static twin have
    nothing moving)."""

    epi: np.ndarray  # eq 5 error (px) against F by RANSAC on the frame's matches
    depth: np.ndarray  # the current keypoint's depth (m), 0 = none
    radius: np.ndarray  # distance (px) of the current keypoint (undistorted) from the principal point
    reproj: np.ndarray  # pose test: reprojection error (px) under the PnP relative pose, NaN without depth / pose
    dres: np.ndarray  # pose test: |depth residual| / sigma, NaN without depth / pose
    frame: np.ndarray  # the match's frame index


def match_stats(log: EngineLog, K: np.ndarray, config: AnyConfig | None = None,
                noise: DepthNoise = DepthNoise()) -> MatchStats:
    """Eq 5 and the pose test on every logged frame's matches, as the geometric module computes them
    (``d2slam.dynamics.geometric``: F by RANSAC, PnP RANSAC on the matches with depth in the previous frame; the
    camera's depth ``noise``)."""
    dyn = part_of(config, "dynamics", DynamicsConfig)
    cols: dict[str, list] = {k: [] for k in ("epi", "depth", "radius", "reproj", "dres", "frame")}
    for f in log.observed:
        p, q = f["p"], f["q"]
        k = len(p)
        if k < 8:
            continue
        F, _ = fundamental_matrix(q, p, dyn)
        epi = epipolar_error(F, p, q) if F is not None else np.full(k, np.nan)
        reproj = np.full(k, np.nan)
        dres = np.full(k, np.nan)
        has = f["zq"] > 0
        X = back_project(q, np.where(has, f["zq"], np.nan), K)
        pose = relative_pose(X[has], p[has], K, dyn) if has.sum() >= 6 else None
        if pose is not None:
            reproj, d = pose_residuals(X, p, f["zp"], pose[0], pose[1], K, noise)
            dres = np.abs(d)
        for name, v in (("epi", epi), ("depth", f["zp"]), ("radius", np.hypot(p[:, 0] - K[0, 2], p[:, 1] - K[1, 2])),
                        ("reproj", reproj), ("dres", dres), ("frame", np.full(k, f["index"]))):
            cols[name].append(np.asarray(v, float))
    cat = {n: np.concatenate(v) if v else np.zeros(0) for n, v in cols.items()}
    return MatchStats(**cat)


def track_lengths(tracks: list[np.ndarray]) -> np.ndarray:
    """Lengths (frames) of the runs of consecutive frames in which each map point stays matched, from the per-frame
    sets of matched map point ids (a lost frame's set is empty); runs still open at the end are counted too."""
    lengths: list[np.ndarray] = []
    ids = np.zeros(0, np.int64)
    run = np.zeros(0, np.int64)
    for cur in list(tracks) + [np.zeros(0, np.int64)]:
        cur = np.unique(np.asarray(cur, np.int64))
        pos = np.searchsorted(ids, cur)
        pos = np.clip(pos, 0, max(len(ids) - 1, 0))
        cont = (len(ids) > 0) & (ids[pos] == cur) if len(ids) else np.zeros(len(cur), bool)
        new_run = np.ones(len(cur), np.int64)
        new_run[cont] = run[pos[cont]] + 1
        ended = ~np.isin(ids, cur)
        lengths.append(run[ended])
        ids, run = cur, new_run
    return np.concatenate(lengths) if lengths else np.zeros(0, np.int64)


def angular_speed(seq, n: int) -> np.ndarray:
    """(n,) the ground truth's angular speed (deg/s) between each of the first ``n`` frames and the one before (NaN
    for the first, and where the ground truth has no pose)."""
    gt = seq.groundtruth
    ts = np.asarray(seq.timestamps[:n], float)
    out = np.full(n, np.nan)
    if gt is None or n < 2:
        return out
    P = interpolate_poses(gt.timestamps, gt.poses, ts, max_gap=None)
    ok = np.isfinite(P).all(axis=(1, 2))
    both = ok[1:] & ok[:-1]
    rel = np.einsum("nji,njk->nik", P[:-1, :3, :3][both], P[1:, :3, :3][both])
    ang = np.degrees(np.linalg.norm(Rotation.from_matrix(rel).as_rotvec(), axis=1))
    out[1:][both] = ang / np.diff(ts)[both]
    return out


def noise_sigma(gray: np.ndarray) -> float:
    """Image noise (grey levels) by Immerkaer's method: the mean absolute response to the 3 x 3 mask that cancels
    linear intensity, scaled to a Gaussian's sigma; measured where the local gradient is low (the flattest half of
    the pixels), so texture and edges do not count as noise."""
    g = np.asarray(gray, np.float32)
    mask = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    r = np.abs(cv2.filter2D(g, -1, mask, borderType=cv2.BORDER_REFLECT))[1:-1, 1:-1]
    grad = cv2.magnitude(cv2.Sobel(g, cv2.CV_32F, 1, 0), cv2.Sobel(g, cv2.CV_32F, 0, 1))[1:-1, 1:-1]
    flat = grad <= np.median(grad)
    return float(np.sqrt(np.pi / 2.0) * r[flat].mean() / 6.0)


# --------------------------------------------------------------------------------------------------
# a sequence's whole set of statistics
# --------------------------------------------------------------------------------------------------
@dataclass
class Realism:
    """Everything ``d2slam bench realism --real/--twin`` compares, for one sequence."""

    name: str
    frames: int
    tracked: int
    matches: MatchStats
    tracks: np.ndarray  # track lengths (frames)
    sampled: np.ndarray  # frame indices of the per-frame image statistics
    corners: np.ndarray  # FAST corners per sampled frame
    hole_share: np.ndarray  # per sampled frame: share of the image without depth
    noise: np.ndarray  # per sampled frame: image noise (grey levels, :func:`noise_sigma`)
    blur: np.ndarray  # per sampled frame: median blur extent (px) over the patches where one is measured
    blur_speed: np.ndarray  # per patch of the sampled frames: image speed (px/s)
    blur_extent: np.ndarray  # per patch: blur extent (px), NaN where none is measured
    kp_hole_share: np.ndarray  # per logged frame: share of the engine's keypoints without depth
    speed: np.ndarray  # per frame: the ground truth's angular speed (deg/s)
    speed_per_match: np.ndarray = field(default=None)  # the angular speed of each match's frame


def measure(seq, log: EngineLog, stride: int | None = None, config: AnyConfig | None = None,
            time_offset: float | None = None) -> Realism:
    """The realism statistics of the frames of ``seq`` that ``log`` ran (:func:`d2slam.run.observe.engine_log`; the
    per-frame image statistics on every ``stride``-th: ``SynthEvalConfig.realism_stride``). The ground truth's image
    motion (for the blur) is taken ``time_offset`` s after the timestamps: what the images show (default
    ``TwinConfig.rgb_time_shift``, measured on fr1/rpy, which its twin renders)."""

    ev = part_of(config, "synth_eval", SynthEvalConfig)
    n = log.frames
    ms = match_stats(log, seq.camera.K, config, seq.camera.depth_noise)
    stride = int(stride or ev.realism_stride)
    idx = np.arange(0, n, max(stride, 1))
    gt = seq.groundtruth
    offset = part_of(config, "synth", SynthConfig).twin.rgb_time_shift if time_offset is None else float(time_offset)

    def poses_at(t):
        tt = np.clip(np.asarray(t, float) + offset, gt.timestamps[0], gt.timestamps[-1])
        return interpolate_poses(gt.timestamps, gt.poses, tt, max_gap=None)

    corners, holes, noise, blur, bs, be = [], [], [], [], [], []
    for i in idx:
        fr = seq[int(i)]
        gray = fr.gray
        corners.append(texture_stats(gray, ev)[1])
        holes.append(float(np.count_nonzero(fr.depth <= 0)) / fr.depth.size)
        noise.append(noise_sigma(gray))
        if gt is not None:
            s, e = frame_blur(gray, fr.depth, seq.camera, poses_at, fr.timestamp, ev)
        else:
            s = e = np.full(1, np.nan)
        bs.append(s)
        be.append(e)
        blur.append(float(np.nanmedian(e)) if np.isfinite(e).any() else float("nan"))
    speed = angular_speed(seq, n)
    kp_holes = np.array([f["kp_holes"] / max(f["n_kp"], 1) for f in log.observed])
    return Realism(log.name, n, log.tracked, ms, track_lengths(log.tracks), idx, np.array(corners),
                   np.array(holes), np.array(noise), np.array(blur), np.concatenate(bs), np.concatenate(be),
                   kp_holes, speed, speed[ms.frame.astype(int)] if len(ms.frame) else np.zeros(0))


# --------------------------------------------------------------------------------------------------
# side by side
# --------------------------------------------------------------------------------------------------
EPI_PERCENTILES = (50, 90, 99)
SPEED_BINS = (40.0, 80.0)  # deg/s: inner edges of the angular-speed bins of the epipolar table


def pct(values, q=EPI_PERCENTILES) -> np.ndarray:
    """Percentiles of the finite values (NaN when there are none)."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    return np.percentile(v, q) if v.size else np.full(len(np.atleast_1d(q)), np.nan)


def bins(edges) -> list[tuple[float, float, str]]:
    """(low, high, label) of the bins the inner ``edges`` make, from 0 to infinity."""
    e = [0.0] + [float(x) for x in edges] + [np.inf]
    return [(a, b, f"<{b:g}" if a == 0 else (f">={a:g}" if b == np.inf else f"{a:g}-{b:g}")) for a, b in zip(e, e[1:])]


def _fmt(v, digits=2) -> str:
    v = np.atleast_1d(np.asarray(v, float))
    return "/".join("-" if not np.isfinite(x) else f"{x:.{digits}f}" for x in v)


def comparison(real: Realism, twin: Realism, config: AnyConfig | None = None) -> list[tuple[str, str, str]]:
    """The side-by-side table: (what, real, twin) rows."""
    ev = part_of(config, "synth_eval", SynthEvalConfig)
    rows = [("frames tracked (engine, no filter)", f"{real.tracked}/{real.frames}", f"{twin.tracked}/{twin.frames}")]

    def row(label, f, digits=2):
        rows.append((label, _fmt(f(real), digits), _fmt(f(twin), digits)))

    row("FAST corners per frame p10/p50/p90", lambda r: pct(r.corners, (10, 50, 90)), 0)
    row("image noise (grey levels) p50", lambda r: pct(r.noise, 50))
    row("matches per frame p50", lambda r: pct(np.bincount(r.matches.frame.astype(int))[
        np.unique(r.matches.frame.astype(int))], 50), 0)
    row("epipolar error (px) p50/p90/p99", lambda r: pct(r.matches.epi))
    for lo, hi, lab in bins(ev.realism_depth_bins):
        row(f"  keypoint depth {lab} m", lambda r, lo=lo, hi=hi: pct(r.matches.epi[(r.matches.depth > 0) & (
            r.matches.depth >= lo) & (r.matches.depth < hi)]))
    row("  keypoint without depth", lambda r: pct(r.matches.epi[r.matches.depth <= 0]))
    for lo, hi, lab in bins(ev.realism_radius_bins):
        row(f"  image radius {lab} px", lambda r, lo=lo, hi=hi: pct(r.matches.epi[(r.matches.radius >= lo) & (
            r.matches.radius < hi)]))
    for lo, hi, lab in bins(SPEED_BINS):
        row(f"  angular speed {lab} deg/s", lambda r, lo=lo, hi=hi: pct(r.matches.epi[(r.speed_per_match >= lo) & (
            r.speed_per_match < hi)]))
    row("share of matches (%) by depth " + ", ".join(b[2] for b in bins(ev.realism_depth_bins)) + ", none",
        lambda r: 100 * np.array([np.mean((r.matches.depth > 0) & (r.matches.depth >= lo) & (r.matches.depth < hi))
                                  for lo, hi, _ in bins(ev.realism_depth_bins)] + [np.mean(r.matches.depth <= 0)]), 0)
    row("pose test reprojection (px) p50/p90/p99", lambda r: pct(r.matches.reproj))
    row("pose test |dz|/sigma p50/p90/p99", lambda r: pct(r.matches.dres))
    row("track length (frames) p50/p90/mean", lambda r: np.append(pct(r.tracks, (50, 90)), np.mean(r.tracks)
                                                                     if len(r.tracks) else np.nan), 1)
    row("depth holes: image share (%) p50", lambda r: 100 * pct(r.hole_share, 50), 1)
    row("depth holes: keypoint share (%) p50", lambda r: 100 * pct(r.kp_hole_share, 50), 1)
    row("blur extent (px) per frame p10/p50/p90", lambda r: pct(r.blur, (10, 50, 90)), 1)
    row("blur: exposure fit (ms) / intercept (px)", lambda r: _exposure(r), 1)
    row("angular speed (deg/s) p50/p90/max", lambda r: np.append(pct(r.speed, (50, 90)), np.nanmax(r.speed)
                                                                    if np.isfinite(r.speed).any() else np.nan), 0)
    return rows


def _exposure(r: Realism) -> np.ndarray:
    try:
        e, b, _ = fit_exposure(r.blur_speed, r.blur_extent)
    except D2SlamError:
        return np.full(2, np.nan)
    return np.array([1e3 * e, b])


def within(real: float, twin: float, tolerance: float) -> bool:
    """``twin`` within ``tolerance`` (a fraction) of ``real``."""
    return bool(np.isfinite(real) and np.isfinite(twin) and abs(twin - real) <= tolerance * abs(real))


# --------------------------------------------------------------------------------------------------
# the sensor's calibration against a real recording
# --------------------------------------------------------------------------------------------------
def gt_epipolar_errors(log: EngineLog, seq, offset: float, readout: float) -> np.ndarray:
    """Eq 5 error (px) of every logged match against the ground truth's own motion, when the images show the scene
    ``offset`` s after their timestamps and each row ``readout`` s after the one above it (rolling shutter; the middle
    row at the timestamp): each keypoint's instant is its frame's timestamp + offset + (its distorted row - middle)
    x readout, and F is that of the ground truth's relative pose between the two instants."""
    cam = seq.camera
    K = cam.K
    Kinv = np.linalg.inv(K)
    gt = seq.groundtruth
    ts = np.asarray(seq.timestamps, float)
    P, Q, tp, tq = [], [], [], []
    for f in log.observed:
        i = f["index"]
        if i == 0 or len(f["p"]) == 0:
            continue
        P.append(f["p"])
        Q.append(f["q"])
        tp.append(np.full(len(f["p"]), ts[i]))
        tq.append(np.full(len(f["p"]), ts[i - 1]))
    if not P:
        return np.zeros(0)
    P, Q, tp, tq = (np.concatenate(x) for x in (P, Q, tp, tq))
    mid = (cam.height - 1) / 2.0

    def row(px):  # the distorted (sensor) row of undistorted pixels
        x = np.stack([(px[:, 0] - K[0, 2]) / K[0, 0], (px[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(px))], axis=1)
        uv, _ = cv2.projectPoints(x.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, np.asarray(cam.dist))
        return uv.reshape(-1, 2)[:, 1]

    lo, hi = gt.timestamps[0], gt.timestamps[-1]
    Tp = interpolate_poses(gt.timestamps, gt.poses, np.clip(tp + offset + (row(P) - mid) * readout, lo, hi), None)
    Tq = interpolate_poses(gt.timestamps, gt.poses, np.clip(tq + offset + (row(Q) - mid) * readout, lo, hi), None)
    Tr = np.einsum("nij,njk->nik", np.linalg.inv(Tp), Tq)  # previous camera -> current camera
    t = Tr[:, :3, 3]
    tx = np.zeros((len(t), 3, 3))
    tx[:, 0, 1], tx[:, 0, 2], tx[:, 1, 2] = -t[:, 2], t[:, 1], -t[:, 0]
    tx[:, 1, 0], tx[:, 2, 0], tx[:, 2, 1] = t[:, 2], -t[:, 1], t[:, 0]
    F = Kinv.T @ np.einsum("nij,njk->nik", tx, Tr[:, :3, :3]) @ Kinv
    lines = np.einsum("nij,nj->ni", F, np.concatenate([Q, np.ones((len(Q), 1))], axis=1))
    num = np.abs(np.einsum("ni,ni->n", np.concatenate([P, np.ones((len(P), 1))], axis=1), lines))
    with np.errstate(divide="ignore", invalid="ignore"):
        return num / np.hypot(lines[:, 0], lines[:, 1])


def fit_time_offset(log: EngineLog, seq, offsets, readouts) -> tuple[np.ndarray, float, float]:
    """(table (len(offsets), len(readouts)) of the median ground-truth epipolar error, best offset, best readout)."""
    table = np.array([[np.nanmedian(gt_epipolar_errors(log, seq, float(o), float(r))) for r in readouts]
                      for o in offsets])
    i, j = np.unravel_index(int(np.nanargmin(table)), table.shape)
    return table, float(offsets[i]), float(readouts[j])


def depth_border(depths: list[np.ndarray], share: float = 0.5) -> tuple[int, int, int, int]:
    """(top, bottom, left, right): how many outermost rows / columns of the depth images are holes in at least
    ``share`` of their pixels over all images (the border a registered depth does not cover)."""
    freq = np.mean([d <= 0 for d in depths], axis=0)
    rows, cols = freq.mean(axis=1) >= share, freq.mean(axis=0) >= share

    def run(flags):
        k = np.flatnonzero(~flags)
        return int(k[0]) if len(k) else len(flags)

    return run(rows), run(rows[::-1]), run(cols), run(cols[::-1])


def depth_consistency(seq, indices, offset: float, step: int = 4, edge_m: float = 0.05,
                      depth_range: tuple[float, float] = (0.5, 4.0), readout: float = 0.0) -> np.ndarray:
    """Per frame i of ``indices`` (>= 1): the median normalised depth residual |dz| / sigma(z) of frame i-1's depth
    image (every ``step``-th pixel, away from depth edges: no jump above ``edge_m`` within 5 x 5 px) moved into frame
    i by the ground truth's motion between the two depth images' instants, when each depth image shows the scene
    ``offset`` s after its timestamp (with a rolling shutter, ``readout`` > 0: each row that much later than the one
    above it, the middle row at the shifted timestamp), against frame i's depth. Each depth pixel is the ray of the
    camera's distorted pixel (the depth is registered to the colour image). A wrong ``offset`` gives the wrong
    relative motion wherever the camera's motion changes between the frames, so the residual over many frames is
    least at the true one; a wrong ``readout`` gives each row the wrong motion, the more so the faster the camera
    turns."""
    cam = seq.camera
    K = cam.K
    gt = seq.groundtruth
    dts = np.asarray(seq.depth_timestamps, float)
    H, W = cam.height, cam.width
    vv, uu = np.mgrid[0:H:step, 0:W:step]
    px = np.stack([uu.ravel(), vv.ravel()], axis=1).astype(np.float64)
    und = undistort(px, cam)
    rays = np.stack([(und[:, 0] - K[0, 2]) / K[0, 0], (und[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(und))], axis=1)
    k = np.ones((5, 5), np.uint8)
    out = []
    prev = None
    for i in indices:
        i = int(i)
        if i < 1:
            continue
        if prev is None or prev[0] != i - 1:
            prev = (i - 1, seq[i - 1].depth)
        cur = seq[i].depth
        z0 = prev[1]
        big = np.float32(99.0)
        jump = cv2.dilate(np.where(z0 > 0, z0, 0).astype(np.float32), k) - \
            (-cv2.dilate(-np.where(z0 > 0, z0, big).astype(np.float32), k))
        zs = z0[vv, uu].ravel().astype(np.float64)
        ok = (zs > depth_range[0]) & (zs < depth_range[1]) & (jump[vv, uu].ravel() <= edge_m)
        lo, hi = gt.timestamps[0], gt.timestamps[-1]
        rows_t = (np.arange(H) - (H - 1) / 2.0) * readout
        Ta = interpolate_poses(gt.timestamps, gt.poses, np.clip(dts[i - 1] + offset + rows_t, lo, hi), None)
        Tb = interpolate_poses(gt.timestamps, gt.poses, np.clip(dts[i] + offset + rows_t, lo, hi), None)
        src = vv.ravel()[ok]
        X = rays[ok] * zs[ok, None]
        Xw = np.einsum("nij,nj->ni", Ta[src, :3, :3], X) + Ta[src, :3, 3]
        Xb, uv = _seen_by_rows(Xw, Tb, cam, readout)
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
        zb = cur[uv[inside, 1], uv[inside, 0]].astype(np.float64)
        zp = Xb[inside, 2]
        valid = zb > 0
        noise = cam.depth_noise
        r = np.abs(zb[valid] - zp[valid]) / np.hypot(depth_sigma(zb[valid], noise), depth_sigma(zp[valid], noise))
        out.append(float(np.median(r)) if r.size else np.nan)
        prev = (i, cur)
    return np.array(out)


def _seen_by_rows(Xw: np.ndarray, Tb: np.ndarray, cam, readout: float) -> tuple[np.ndarray, np.ndarray]:
    """World points ``Xw`` (M, 3) as the camera sees them through a rolling shutter (``Tb``: the camera's pose
    T_world_camera at each image row's instant, (H, 4, 4); ``readout`` 0: one instant): (the points in the camera
    frame at the instant of the row they land on, (M', 3); their pixels, rounded) for those in front of it."""
    K, H = cam.K, len(Tb)
    row = np.full(len(Xw), (H - 1) // 2)
    for _ in range(2):  # the row a point lands on decides the instant it is seen at: twice is enough
        Xb = np.einsum("nji,nj->ni", Tb[row, :3, :3], Xw - Tb[row, :3, 3])
        front = Xb[:, 2] > 0.1
        uv, _ = cv2.projectPoints(np.where(front[:, None], Xb, [0.0, 0.0, 1.0]).reshape(-1, 1, 3), np.zeros(3),
                                  np.zeros(3), K, np.asarray(cam.dist))
        uv = uv.reshape(-1, 2)
        row = np.clip(np.rint(uv[:, 1]).astype(np.int64), 0, H - 1)
        if readout == 0:
            break
    return Xb[front], np.rint(uv[front]).astype(np.int64)


def hole_kinds(depth: np.ndarray, border: tuple[int, int, int, int], jump_a: float, jump_b: float) -> dict:
    """Where a depth image's holes are, inside ``border`` (top, bottom, left, right px left out): shares of the
    inner image that are holes at depth edges (a connected hole whose rim's valid depths span more than ``jump_a +
    jump_b z``, z its rim's nearest depth: the Kinect's occlusion shadows and mixed edge pixels), other holes (blobs:
    dark, glossy or out-of-range surfaces), and the hole components' median area (px)."""
    t, b, l, r = border
    d = np.asarray(depth, np.float32)[t:depth.shape[0] - b, l:depth.shape[1] - r]
    hole = (d <= 0).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(hole, connectivity=8)
    if n <= 1:
        return {"edge": 0.0, "blob": 0.0, "median_area": 0.0}
    rim = cv2.dilate(hole, np.ones((3, 3), np.uint8)).astype(bool) & (hole == 0)
    # each rim pixel takes the label of a neighbouring hole (the largest label among its neighbours)
    near = cv2.dilate(lab.astype(np.float32), np.ones((3, 3), np.uint8)).astype(np.int64)
    ids, z = near[rim], d[rim].astype(np.float64)
    lo = np.full(n, np.inf)
    hi = np.full(n, -np.inf)
    np.minimum.at(lo, ids, z)
    np.maximum.at(hi, ids, z)
    area = stats[:, cv2.CC_STAT_AREA].astype(np.float64)
    edge = np.isfinite(lo) & (hi - lo > jump_a + jump_b * np.where(np.isfinite(lo), lo, 0.0))
    edge[0] = False
    total = float(d.size)
    return {"edge": float(area[1:][edge[1:]].sum()) / total, "blob": float(area[1:][~edge[1:]].sum()) / total,
            "median_area": float(np.median(area[1:]))}


# --------------------------------------------------------------------------------------------------
# where the recording goes in the room
# --------------------------------------------------------------------------------------------------
DEPTH_PERCENTILES = (10, 25, 50, 75, 90)


def depth_percentiles(depths: list[np.ndarray], border: tuple[int, int, int, int] = (0, 0, 0, 0)) -> np.ndarray:
    """``DEPTH_PERCENTILES`` (m) of the valid depths (> 0) of images (H, W), pooled, inside ``border`` (top, bottom,
    left, right px left out)."""
    t, b, l, r = border
    vals = [d[t:d.shape[0] - b, l:d.shape[1] - r] for d in depths]
    v = np.concatenate([x[x > 0].ravel() for x in vals])
    if v.size == 0:
        raise D2SlamError("no valid depth to take percentiles of")
    return np.percentile(v, DEPTH_PERCENTILES)


def anchor_scan(rec, real_depths: list[np.ndarray], indices: np.ndarray, xs, ys, headings,
                cfg=None, seed: int = 0) -> list[dict]:
    """For every anchor (x, y, heading) of the grid: the depth percentiles of the twin's clean depth (distorted,
    inside ``depth_border``) at the frames ``indices`` against the real ones (``real_depths``, the same frames), and
    the mismatch: the mean |log(twin / real)| over the percentiles. Sorted best first. Renders depth only."""

    cfg = cfg or SynthConfig()
    indices = np.asarray(indices, int)
    scene = Scene("fr1_rpy_twin", seed, int(indices.max()) + 1, cfg=cfg, recording=rec)
    border = scene.cfg.twin.depth_border
    want = depth_percentiles(real_depths, border)
    first = RecordedPath(rec, np.eye(4), scene.t0).poses([0.0])[0]
    tw = scene.cfg.twin
    times = scene.t_rel[indices] + scene.depth_offset[indices] + tw.depth_time_shift if tw.depth_at_depth_time \
        else scene.t_rel[indices] + tw.rgb_time_shift  # the middle row's instant
    raw = RecordedPath(rec, np.eye(4), scene.t0).poses(times)
    renderer = WorldRenderer(scene)
    rows = []
    try:
        for h in headings:
            for x in xs:
                for y in ys:
                    A = placement(first, (float(x), float(y)), float(h))
                    zs = [scene.lens(renderer.gl.render_depth(A @ T)[0], nearest=True) for T in raw]
                    got = depth_percentiles(zs, border) if any((z > 0).any() for z in zs) else np.full(5, np.nan)
                    err = float(np.mean(np.abs(np.log(got / want)))) if np.isfinite(got).all() else float("inf")
                    rows.append({"x": float(x), "y": float(y), "heading": float(h), "twin": got, "real": want,
                                 "mismatch": err})
    finally:
        renderer.close()
    return sorted(rows, key=lambda r: r["mismatch"])


def edge_hole_runs(depth: np.ndarray, border: tuple[int, int, int, int], jump_a: float, jump_b: float,
                   max_px: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """Widths (px) of the runs of holes along the rows, inside ``border``, that separate two valid depths differing by
    more than ``jump_a + jump_b z`` (z the nearer; runs up to ``max_px``): (those whose nearer side is on the right,
    those whose nearer side is on the left). A structured-light sensor's projector shadows the farther surface on one
    side of a near object, so one side's runs are the wider."""
    t, b, l, r = border
    d = np.asarray(depth, np.float32)[t:depth.shape[0] - b, l:depth.shape[1] - r]
    H, W = d.shape
    hole = np.zeros((H, W + 2), np.int8)
    hole[:, 1:-1] = d <= 0
    step = np.diff(hole, axis=1)  # +1 where a run starts (at column c), -1 where it ends (column c is past it)
    rs, cs = np.nonzero(step == 1)
    re_, ce = np.nonzero(step == -1)  # row-major order: the k-th start and the k-th end belong to one run
    ok = (cs > 0) & (ce < W) & (ce - cs <= max_px)
    rs, cs, ce = rs[ok], cs[ok], ce[ok]
    zl, zr = d[rs, cs - 1], d[rs, ce]
    near = np.minimum(zl, zr)
    edge = (zl > 0) & (zr > 0) & (np.abs(zl - zr) > jump_a + jump_b * near)
    width = (ce - cs)[edge]
    right = (zr < zl)[edge]
    return width[right], width[~right]
