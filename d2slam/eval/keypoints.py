"""Keypoint classification against synthetic ground truth: precision, recall and F1 of "dynamic".

``keypoint_truth(kps, dynamic_mask)`` labels each keypoint from a per-pixel truth mask (the synthetic benchmark's
``SyntheticSequence.dynamic_mask(i)``: a person, or a moved object while it moves). ``KeypointMetrics`` accumulates
confusion counts over frames (and ``ModuleMetrics`` one per module of the classifier's diagnostics).
``KeypointRecorder(sequence)`` is the per-frame recorder of ``d2slam.run.sequence.run_sequence`` that does all of it
over a run and returns a JSON-ready dict (``result()``).

Undefined ratios (no predicted or no true dynamic keypoint at all) are NaN, never a made-up 0 or 1.
"""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from d2slam.errors import D2SlamError


def keypoint_labels(kps: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(N,) the label image's value at each keypoint's pixel (u, v), rounded to the nearest pixel (``np.rint``).

    Keypoints outside the image (after rounding) or with non-finite coordinates get 0 (static): the truth has
    nothing to say there, and the engine keeps only in-image keypoints anyway."""
    m = np.asarray(labels)
    if m.ndim != 2:
        raise D2SlamError(f"dynamic truth mask must be (H, W), got shape {m.shape}")
    kps = np.asarray(kps, dtype=np.float64).reshape(-1, 2)
    h, w = m.shape
    finite = np.all(np.isfinite(kps), axis=1)
    pix = np.rint(np.where(finite[:, None], kps, -1.0)).astype(np.int64)
    ok = finite & (pix[:, 0] >= 0) & (pix[:, 0] < w) & (pix[:, 1] >= 0) & (pix[:, 1] < h)
    out = np.zeros(len(kps), dtype=m.dtype)
    out[ok] = m[pix[ok, 1], pix[ok, 0]]
    return out


def keypoint_truth(kps: np.ndarray, dynamic_mask: np.ndarray) -> np.ndarray:
    """(N,) bool: the truth mask at each keypoint's pixel (``keypoint_labels`` != 0)."""
    return keypoint_labels(kps, dynamic_mask) != 0


class OracleFilter:
    """The ``oracle`` method's keypoint filter: belief 1 for a keypoint inside one of the frame's masks, 0 elsewhere,
    by the same pixel test as ``keypoint_truth``. Given the ``truth`` masks (``d2slam.segmentation.sim``: the dynamic
    truth of ``mask_gt``) its labels *are* the keypoint truth: a run shows what the engine does with a perfect
    classifier, the upper bound of every dynamics method (synthetic sequences only)."""

    def reset(self) -> None:
        pass

    def __call__(self, inp) -> np.ndarray:
        masks = inp.masks
        if masks is None or len(masks) == 0:
            return np.zeros(len(inp.kps))
        return keypoint_truth(inp.kps, np.asarray(masks, dtype=bool).any(axis=0)).astype(np.float64)


def _ratio(a: int, b: int) -> float:
    return a / b if b > 0 else float("nan")


@dataclass
class KeypointMetrics:
    """Confusion counts of "dynamic" accumulated over frames."""

    tp: int = 0  # dynamic predicted dynamic
    fp: int = 0  # static predicted dynamic
    fn: int = 0  # dynamic predicted static
    tn: int = 0  # static predicted static

    def update(self, pred: np.ndarray, truth: np.ndarray) -> "KeypointMetrics":
        pred = np.asarray(pred, dtype=bool).reshape(-1)
        truth = np.asarray(truth, dtype=bool).reshape(-1)
        if pred.shape != truth.shape:
            raise D2SlamError(f"{len(pred)} predictions for {len(truth)} truth labels")
        self.tp += int(np.count_nonzero(pred & truth))
        self.fp += int(np.count_nonzero(pred & ~truth))
        self.fn += int(np.count_nonzero(~pred & truth))
        self.tn += int(np.count_nonzero(~pred & ~truth))
        return self

    def __add__(self, other: "KeypointMetrics") -> "KeypointMetrics":
        return KeypointMetrics(self.tp + other.tp, self.fp + other.fp, self.fn + other.fn, self.tn + other.tn)

    @property
    def n(self) -> int:
        return self.tp + self.fp + self.fn + self.tn

    @property
    def precision(self) -> float:
        """Of the keypoints predicted dynamic, the fraction truly dynamic."""
        return _ratio(self.tp, self.tp + self.fp)

    @property
    def recall(self) -> float:
        """Of the truly dynamic keypoints, the fraction predicted dynamic."""
        return _ratio(self.tp, self.tp + self.fn)

    @property
    def f1(self) -> float:
        p, r = self.precision, self.recall
        if np.isnan(p) or np.isnan(r):
            return float("nan")
        return 2 * p * r / (p + r) if p + r > 0 else 0.0

    @property
    def static_precision(self) -> float:
        """Of the keypoints kept as static, the fraction truly static (what pose optimisation sees)."""
        return _ratio(self.tn, self.tn + self.fn)

    def as_dict(self) -> dict[str, float]:
        return {"tp": self.tp, "fp": self.fp, "fn": self.fn, "tn": self.tn, "precision": self.precision,
                "recall": self.recall, "f1": self.f1, "static_precision": self.static_precision}


@dataclass
class ModuleMetrics:
    """One ``KeypointMetrics`` per module name, fed with ``FrameDiagnostics.predictions()`` dicts."""

    modules: dict[str, KeypointMetrics] = field(default_factory=dict)

    def update(self, predictions: dict[str, np.ndarray], truth: np.ndarray) -> "ModuleMetrics":
        for name, pred in predictions.items():
            self.modules.setdefault(name, KeypointMetrics()).update(pred, truth)
        return self

    def as_dict(self) -> dict[str, dict[str, float]]:
        return {name: m.as_dict() for name, m in self.modules.items()}


MODULE_ORDER = ("semantic", "geometric", "pose", "edge", "fusion", "bayes", "oim", "final")


def _json_number(v):
    """NaN (an undefined ratio) -> None, so that the dict is strict JSON; ints stay ints."""
    if isinstance(v, float) and not np.isfinite(v):
        return None
    return v


class KeypointRecorder:
    """Recorder for ``run_sequence(..., recorder=KeypointRecorder(sequence))``: precision / recall / F1 of "dynamic"
    per module of the classifier, and static precision, against the sequence's keypoint truth.

    Called once per frame as ``recorder(index, kps (N, 2), beliefs (N,) or None, diagnostics)``: the truth of each
    keypoint is its label in ``sequence.dynamic_labels(index)`` (``keypoint_labels``: 1 a person, 2 a moved object
    while it moves, 0 static); the predictions are the diagnostics'
    ``predictions()`` (``FrameDiagnostics``: semantic, geometric, pose, edge, fusion, bayes, oim, final - whichever
    modules the mode ran) when the diagnostics belong to this frame (same ``frame_index`` and keypoint count),
    otherwise only ``final`` from the beliefs (belief > ``threshold``; no beliefs, i.e. method ``none``: every
    keypoint static). ``moved_objects``: the final classification's recall on the keypoints of moved objects (what
    the masks cannot see and the OIM and geometry are for). ``sequence`` must have ``dynamic_labels(i)``
    (``d2slam.data.SyntheticSequence``); anything else is a D2SlamError.
    """

    def __init__(self, sequence, threshold: float = 0.5):
        if not callable(getattr(sequence, "dynamic_labels", None)):
            raise D2SlamError("keypoint metrics need a synthetic sequence (per-pixel truth in mask_gt/ and scene.json)",
                              path=getattr(sequence, "root", None))
        self.sequence = sequence
        self.threshold = float(threshold)
        self.metrics = ModuleMetrics()
        self.objects = KeypointMetrics()  # the final classification of keypoints on moved objects while they move
        self.frames = 0
        self.keypoints = 0
        self.dynamic_keypoints = 0
        self.frames_with_diagnostics = 0
        self._reader: ThreadPoolExecutor | None = None
        self._next: tuple[int, Future] | None = None

    def _truth_mask(self, index: int) -> np.ndarray:
        """The frame's dynamic mask; the next frame's is read meanwhile in a thread (frames come in order; only for
        a sequence with a length)."""
        if self._next is not None and self._next[0] == index:
            mask = self._next[1].result()
        else:
            mask = self.sequence.dynamic_labels(index)
        if index + 1 < len(self.sequence) if hasattr(self.sequence, "__len__") else False:
            if self._reader is None:
                self._reader = ThreadPoolExecutor(max_workers=1, thread_name_prefix="d2slam-truth")
            self._next = (index + 1, self._reader.submit(self.sequence.dynamic_labels, index + 1))
        elif self._reader is not None:  # the last frame: the thread is not needed any more
            self._next = None
            self._reader.shutdown(wait=False)
            self._reader = None
        return mask

    def __call__(self, index: int, kps: np.ndarray, beliefs: np.ndarray | None, diagnostics=None) -> None:
        kps = np.asarray(kps, dtype=np.float64).reshape(-1, 2)
        n = len(kps)
        labels = keypoint_labels(kps, self._truth_mask(index))  # 0 static, 1 person, 2 moved object
        truth = labels > 0
        preds = None
        if diagnostics is not None and getattr(diagnostics, "frame_index", None) == index \
                and len(getattr(diagnostics, "belief", ())) == n:
            preds = diagnostics.predictions(self.threshold)
            self.frames_with_diagnostics += 1
        if preds is None:
            if beliefs is None:
                final = np.zeros(n, dtype=bool)
            else:
                b = np.asarray(beliefs, dtype=np.float64).reshape(-1)
                if len(b) != n:
                    raise D2SlamError(f"frame {index}: {len(b)} beliefs for {n} keypoints")
                final = b > self.threshold
            preds = {"final": final}
        self.metrics.update(preds, truth)
        on_objects = labels == 2
        self.objects.update(preds["final"][on_objects], truth[on_objects])
        self.frames += 1
        self.keypoints += n
        self.dynamic_keypoints += int(truth.sum())

    def result(self) -> dict:
        """JSON-ready: frames, keypoints, dynamic_keypoints, threshold and, per module (in the pipeline's order),
        tp/fp/fn/tn, precision, recall, f1, static_precision (None where a ratio is undefined)."""
        mods = self.metrics.as_dict()
        names = [m for m in MODULE_ORDER if m in mods] + sorted(set(mods) - set(MODULE_ORDER))
        return {"frames": self.frames, "frames_with_diagnostics": self.frames_with_diagnostics,
                "keypoints": self.keypoints, "dynamic_keypoints": self.dynamic_keypoints,
                "threshold": self.threshold,
                "modules": {m: {k: _json_number(v) for k, v in mods[m].items()} for m in names},
                "moved_objects": {"keypoints": self.objects.n, "recall": _json_number(self.objects.recall)}}


def keypoint_recorder(sequence, threshold: float = 0.5) -> KeypointRecorder | None:
    """A ``KeypointRecorder`` when ``sequence`` carries keypoint truth (synthetic), None otherwise (TUM)."""
    if callable(getattr(sequence, "dynamic_labels", None)):
        return KeypointRecorder(sequence, threshold)
    return None
