"""The person segmenter's settings (YOLOv8n-seg person masks through onnxruntime)."""

from __future__ import annotations

from dataclasses import dataclass

from d2slam.ranges import Checked, flag, within


@dataclass(frozen=True)
class SegmentationConfig(Checked):
    # A proposal is a person when its best class is person (class 0) and its person score exceeds this.
    score_threshold: float = within(0.25, 0.0, 1.0, lo_open=True, hi_open=True)
    # IoU above which cv2.dnn.NMSBoxes suppresses the lower-scored person box (Ultralytics default 0.7).
    nms_iou: float = within(0.7, 0.0, 1.0, lo_open=True)
    # sigmoid(coefficients . prototypes), upsampled to the frame, is a person pixel above this.
    mask_threshold: float = within(0.5, 0.0, 1.0, lo_open=True, hi_open=True)
    # Optional dilation of every mask by this radius (pixels, elliptic kernel); 0 = none.
    dilation_px: int = within(0, 0, 100)
    # onnxruntime intra-op threads (inter-op 1, sequential); not part of the mask-cache key.
    intra_op_threads: int = within(2, 0, 256)
    # onnxruntime's intra-op threads spin-wait between operators when True (its default). False: they sleep. Spinning
    # took 1.7x the CPU time of a frame (65 -> 112 ms) and, with two segmenting processes on 2 cores (the study's
    # workers), twice the wall time; not part of the mask-cache key. Measured: docs/benchmarks.md.
    allow_spinning: bool = flag(False)
    # At most this many persons per frame, highest scores first.
    max_persons: int = within(20, 1, 1000)
    # The mask cache file of a sequence is rewritten after this many newly segmented frames (and when the sequence
    # is complete); not part of the mask-cache key.
    cache_flush_frames: int = within(100, 1, 1_000_000)


# SegmentationConfig fields that do not change masks: left out of the mask-cache key and of the runs' keys.
NOT_IN_KEY = ("intra_op_threads", "allow_spinning", "cache_flush_frames")
