"""Person segmentation: one interface (frame -> list of ``PersonInstance``), three implementations.

* ``onnx``: YOLOv8n-seg through onnxruntime (``d2slam.segmentation.onnx.OnnxSegmenter``), any sequence: the default
  of every run;
* ``sim``: the synthetic sequence's simulated segmenter output ``mask_sim/``;
* ``gt``: the synthetic sequence's ground-truth person ids in ``mask_gt/``;
* ``truth``: the synthetic sequence's dynamic truth (persons, and moved objects while they move) from ``mask_gt/``:
  for the ``oracle`` upper bound, not a segmenter (``d2slam.segmentation.sim``).

``get_segmenter(kind, sequence, config)`` builds one; ``CachedSegmenter(segmenter, sequence)`` or
``masks_for(sequence, i, kind)`` (what the pipeline calls) reads the per-frame mask cache and fills it on demand.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from d2slam.errors import D2SlamError
from d2slam.ranges import AnyConfig, part_of
from d2slam.segmentation.base import PersonInstance, Segmenter, stack_masks
from d2slam.segmentation.cache import CachedSegmenter
from d2slam.segmentation.config import SegmentationConfig
from d2slam.segmentation.onnx import OnnxSegmenter, default_model_path
from d2slam.segmentation.sim import LabelSegmenter

KINDS = ("onnx", "sim", "gt", "truth")

__all__ = ["KINDS", "PersonInstance", "Segmenter", "stack_masks", "CachedSegmenter", "get_segmenter", "masks_for",
           "cached_segmenter", "masks_origin", "flush_masks", "segmentation_config", "mask_source"]


def segmentation_config(config: AnyConfig | SegmentationConfig | None = None) -> SegmentationConfig:
    """The segmenter's section of a whole config, the section itself, or its defaults (None)."""
    return part_of(config, "segmentation", SegmentationConfig)


def get_segmenter(kind: str, sequence=None, config: AnyConfig | SegmentationConfig | None = None,
                  model: str | Path | None = None, allow_unknown_model: bool | None = None):
    """A segmenter of ``kind`` ("onnx", "sim", "gt" or "truth"). ``sequence`` is needed by sim/gt/truth (its ``mask_*``
    folders); ``model`` overrides ``$D2SLAM_SEG_MODEL`` for onnx."""
    if kind == "onnx":
        return OnnxSegmenter(model, segmentation_config(config), allow_unknown_model)
    if kind in ("sim", "gt", "truth"):
        return LabelSegmenter(sequence, kind)
    raise D2SlamError(f"unknown segmenter kind {kind!r}; choose one of {', '.join(KINDS)}")


_SESSIONS: dict[tuple, object] = {}  # ONNX segmenters by (config, model): one session per process
_CACHED: dict[tuple, CachedSegmenter] = {}  # the few most recent (sequence, kind, config, model)
_MAX_CACHED = 8


def cached_segmenter(sequence, kind: str = "onnx", config: AnyConfig | SegmentationConfig | None = None,
                     model: str | Path | None = None) -> CachedSegmenter:
    """The :class:`CachedSegmenter` that :func:`masks_for` reads ``kind`` masks of ``sequence`` through (the ONNX
    session is built once per process and config/model; the few most recent ones are kept)."""
    cfg = segmentation_config(config)
    model_key = None
    if kind == "onnx":  # keyed by the file it reads, so a changed $D2SLAM_SEG_MODEL gets a session of its own
        model_key = str(Path(model).expanduser() if model is not None else default_model_path())
    key = (id(sequence), kind, cfg, model_key)
    cached = _CACHED.get(key)
    if cached is None or cached.sequence is not sequence:
        if kind == "onnx":
            seg = _SESSIONS.get((cfg, model_key))
            if seg is None:
                seg = _SESSIONS[(cfg, model_key)] = get_segmenter("onnx", config=cfg, model=model)
        else:
            seg = get_segmenter(kind, sequence, cfg)
        if len(_CACHED) >= _MAX_CACHED:
            _CACHED.pop(next(iter(_CACHED))).flush()  # its newly segmented frames, before it is dropped
        cached = _CACHED[key] = CachedSegmenter(seg, sequence)
    return cached


def masks_for(sequence, index: int, kind: str = "onnx", config: AnyConfig | SegmentationConfig | None = None,
              model: str | Path | None = None) -> list[PersonInstance]:
    """Persons of frame ``index`` of ``sequence``: the pipeline's entry point. ``onnx`` goes through the mask
    cache (filled on demand; the ONNX session is built once per process and config/model); ``sim``/``gt`` read
    the sequence's label images."""
    return cached_segmenter(sequence, kind, config, model).instances(index)


LABEL_FOLDERS = {"sim": "mask_sim/", "gt": "mask_gt/", "truth": "mask_gt/ and scene.json"}


def masks_origin(sequence, kind: str, config: AnyConfig | SegmentationConfig | None = None,
                 frames: int | None = None, progress: bool = True) -> str:
    """Where the ``kind`` masks of ``sequence`` come from, for a run's summary: the model file and the mask cache
    for ``onnx`` (whose first ``frames`` frames are segmented into the cache now when missing: announced and
    followed with ``progress``), the label folder of the sequence otherwise."""
    if kind == "onnx":
        cached = cached_segmenter(sequence, kind, config)
        cached.fill(progress=progress, frames=frames, recheck=False)
        return f"{Path(cached.segmenter.model_path).name}, cached in {cached.dir}"
    return f"{LABEL_FOLDERS.get(kind, kind)} of {Path(sequence.root).resolve()}"


def flush_masks() -> None:
    """Write the frames ``masks_for`` segmented so far into their cache files now (they are written every
    ``SegmentationConfig.cache_flush_frames`` frames, when a sequence is complete and at exit): before another
    process reads masks this one segmented for part of a sequence."""
    for cached in list(_CACHED.values()):
        cached.flush()


def mask_source(sequence, masks_from):
    """The sequence whose masks a run on ``sequence`` reads: ``sequence`` itself, or ``masks_from`` (``d2slam run
    --masks-from``; the study's ``oracle`` on a static twin reads its dynamic sibling's truth, the *occluded twin*),
    which must have the same frames: as many, at the same timestamps (a clear error otherwise, not masks of other
    frames)."""
    if masks_from is None or masks_from is sequence:
        return sequence
    n, m = len(sequence), len(masks_from)
    if m < n:
        raise D2SlamError(f"the masks' sequence has {m} frames, the run's {n}",
                          path=getattr(masks_from, "root", None))
    ts = np.asarray(sequence.timestamps[:n], dtype=np.float64)
    other = np.asarray(masks_from.timestamps[:n], dtype=np.float64)
    if not np.allclose(ts, other, rtol=0.0, atol=1e-6):
        k = int(np.flatnonzero(~np.isclose(ts, other, rtol=0.0, atol=1e-6))[0])
        raise D2SlamError(f"the masks' sequence is not at the run's frames: frame {k} is at {other[k]:.6f} s there "
                          f"and at {ts[k]:.6f} s here", path=getattr(masks_from, "root", None))
    return masks_from
