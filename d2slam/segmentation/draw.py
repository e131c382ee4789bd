"""Overlay of person masks on a frame (for ``d2slam segment --overlay`` and the notebook)."""

from __future__ import annotations

import cv2
import numpy as np

from d2slam.segmentation.base import PersonInstance

# One colour per instance (RGB), cycled.
PALETTE = np.array([[230, 25, 75], [60, 180, 75], [0, 130, 200], [245, 130, 48], [145, 30, 180], [70, 240, 240],
                    [240, 50, 230], [210, 245, 60]], dtype=np.float32)


def overlay(rgb: np.ndarray, persons: list[PersonInstance], alpha: float = 0.5, boxes: bool = True) -> np.ndarray:
    """RGB image with each mask tinted in its own colour (alpha blend), its box and its score drawn."""
    out = np.asarray(rgb, dtype=np.float32).copy()
    if out.ndim == 2:
        out = np.repeat(out[:, :, None], 3, axis=2)
    if persons:
        masks = np.stack([p.mask for p in persons])
        colours = PALETTE[np.arange(len(persons)) % len(PALETTE)]
        owner = masks.argmax(axis=0)  # the first (highest-score) instance covering a pixel
        covered = masks.any(axis=0)
        out[covered] = (1 - alpha) * out[covered] + alpha * colours[owner[covered]]
    out = np.clip(out, 0, 255).astype(np.uint8)
    if boxes:
        for i, p in enumerate(persons):
            colour = tuple(int(c) for c in PALETTE[i % len(PALETTE)])
            x0, y0, x1, y1 = (int(round(v)) for v in p.box)
            cv2.rectangle(out, (x0, y0), (x1 - 1, y1 - 1), colour, 2)
            cv2.putText(out, f"{p.score:.2f}", (x0 + 3, max(y0 + 16, 16)), cv2.FONT_HERSHEY_SIMPLEX, 0.55, colour, 2)
    return out
