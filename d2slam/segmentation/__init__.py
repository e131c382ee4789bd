"""Person segmentation: one interface (frame -> list of ``PersonInstance``), three implementations.

* ``onnx``: YOLOv8n-seg through onnxruntime (``d2slam.segmentation.onnx.OnnxSegmenter``), any sequence;
* ``sim``: the synthetic sequence's simulated segmenter output ``mask_sim/`` (the default for synthetic runs);
* ``gt``: the synthetic sequence's ground-truth person ids in ``mask_gt/``.

``get_segmenter(kind, sequence, config)`` builds one; ``CachedSegmenter(segmenter, sequence)`` or
``masks_for(sequence, i, kind)`` (what the pipeline calls) reads the per-frame mask cache and fills it on demand.
"""

from __future__ import annotations

from pathlib import Path

from d2slam.config import DEFAULT, Config, SegmentationConfig
from d2slam.errors import D2SlamError
from d2slam.segmentation.base import PersonInstance, Segmenter, stack_masks
from d2slam.segmentation.cache import CachedSegmenter

KINDS = ("onnx", "sim", "gt")

__all__ = ["KINDS", "PersonInstance", "Segmenter", "stack_masks", "CachedSegmenter", "get_segmenter", "masks_for",
           "segmentation_config"]


def segmentation_config(config: Config | SegmentationConfig | None = None) -> SegmentationConfig:
    if config is None:
        return DEFAULT.segmentation
    if isinstance(config, Config):
        return config.segmentation
    if isinstance(config, SegmentationConfig):
        return config
    raise TypeError(f"expected Config or SegmentationConfig, got {type(config).__name__}")


def get_segmenter(kind: str, sequence=None, config: Config | SegmentationConfig | None = None,
                  model: str | Path | None = None, allow_unknown_model: bool | None = None):
    """A segmenter of ``kind`` ("onnx", "sim" or "gt"). ``sequence`` is needed by sim/gt (its ``mask_*``
    folders); ``model`` overrides ``$D2SLAM_SEG_MODEL`` for onnx."""
    if kind == "onnx":
        from d2slam.segmentation.onnx import OnnxSegmenter

        return OnnxSegmenter(model, segmentation_config(config), allow_unknown_model)
    if kind in ("sim", "gt"):
        from d2slam.segmentation.sim import LabelSegmenter

        return LabelSegmenter(sequence, kind)
    raise D2SlamError(f"unknown segmenter kind {kind!r}; choose one of {', '.join(KINDS)}")


_CACHED: dict[tuple, CachedSegmenter] = {}


def masks_for(sequence, index: int, kind: str = "onnx", config: Config | SegmentationConfig | None = None,
              model: str | Path | None = None) -> list[PersonInstance]:
    """Persons of frame ``index`` of ``sequence`` through the mask cache (filled on demand). The segmenter (and
    its ONNX session) is built once per (sequence, kind, config, model) and reused."""
    cfg = segmentation_config(config)
    key = (id(sequence), kind, cfg, None if model is None else str(model))
    cached = _CACHED.get(key)
    if cached is None or cached.sequence is not sequence:
        cached = CachedSegmenter(get_segmenter(kind, sequence, cfg, model), sequence)
        _CACHED[key] = cached
    return cached.instances(index)
