"""One segmenter interface: frame -> list of person instances (mask, score, box)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np


@dataclass
class PersonInstance:
    mask: np.ndarray  # (H, W) bool at the frame's resolution
    score: float  # detector confidence in [0, 1] (1.0 for ground truth)
    box: tuple[float, float, float, float]  # x0, y0, x1, y1 in frame pixels

    @property
    def area(self) -> int:
        return int(self.mask.sum())


class Segmenter(Protocol):
    name: str

    def __call__(self, frame) -> list[PersonInstance]:  # frame: d2slam.data.base.RGBDFrame
        ...


def stack_masks(instances: list[PersonInstance], shape: tuple[int, int]) -> np.ndarray:
    """(n, H, W) bool array of the instances' masks ((0, H, W) when there are none): the hook's ``masks``."""
    if not instances:
        return np.zeros((0, *shape), dtype=bool)
    return np.stack([inst.mask.astype(bool, copy=False) for inst in instances])
