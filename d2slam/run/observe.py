"""The engine's own inputs, recorded frame by frame (:func:`engine_log`): a sequence run through the engine with a
keypoint filter that marks nothing dynamic (:class:`Observer`: the engine then tracks exactly as ``--method none``
does) that keeps what the filter would see (``FilterInput``: the frame-to-frame matches of all keypoints, in
undistorted pixels, with their depths), and which map points each tracked frame matched. The sensor's statistics real
against synthetic (:mod:`d2slam.eval.realism`) are measured on this log.
"""

from __future__ import annotations

import numpy as np

from d2slam.config import DEFAULT, Config
from d2slam.eval.realism import EngineLog
from d2slam.run.sequence import ensure_vocabulary, run_sequence
from d2slam.slam.engine import Engine


class Observer:
    """A keypoint filter that marks nothing dynamic (every belief 0: the engine tracks as without a filter) and keeps
    what it was given: per frame the matched keypoints (current ``p``, previous ``q``; undistorted pixels), their
    depths and octaves."""

    def __init__(self):
        self.frames: list[dict] = []

    def reset(self) -> None:
        self.frames = []

    def __call__(self, inp) -> np.ndarray:
        m = np.asarray(inp.matches, np.int64).reshape(-1, 2)
        self.frames.append({
            "index": int(inp.frame_index), "timestamp": float(inp.timestamp), "n_kp": len(inp.kps),
            "kp_holes": int(np.count_nonzero(np.asarray(inp.kp_depth) <= 0)),
            "p": np.asarray(inp.kps, np.float64)[m[:, 0]], "q": np.asarray(inp.prev_kps, np.float64)[m[:, 1]],
            "zp": np.asarray(inp.kp_depth, np.float64)[m[:, 0]],
            "zq": np.asarray(inp.prev_kp_depth, np.float64)[m[:, 1]],
            "octave": (np.asarray(inp.octave)[m[:, 0]] if inp.octave is not None else np.zeros(len(m), np.int64)),
            "hole_share": float(np.count_nonzero(np.asarray(inp.depth) <= 0)) / max(np.asarray(inp.depth).size, 1),
        })
        return np.zeros(len(inp.kps))


def engine_log(seq, frames: int | None = None, config: Config | None = None, progress: bool = False) -> EngineLog:
    """Run ``seq`` (its first ``frames``) through the engine with an :class:`Observer` and log its inputs."""
    config = config or DEFAULT
    ensure_vocabulary(config)
    obs = Observer()
    eng = Engine(seq.camera, config, obs)
    tracks: list[np.ndarray] = []

    def rec(i, kps, belief, diag):
        f = eng.last
        ok = eng.tracker.last_tracked is f and f is not None and f.Tcw is not None
        tracks.append(np.unique(f.mp[(f.mp >= 0) & ~f.outlier]) if ok else np.zeros(0, np.int64))

    run = run_sequence(seq, config, keypoint_filter=obs, recorder=rec, progress=progress, engine=eng, frames=frames)
    n = run.frames
    return EngineLog(getattr(seq, "name", ""), n, run.tracked, np.asarray(seq.timestamps[:n], float), obs.frames,
                     tracks)
