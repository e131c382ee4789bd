"""Datasets behind one interface (``d2slam.data.base.Sequence``): TUM RGB-D folders and d2slam synthetic
sequences. ``open_sequence(path)`` picks the right reader."""

from __future__ import annotations

from pathlib import Path

from d2slam.data.base import Camera, RGBDFrame, Sequence, Trajectory
from d2slam.data.synthetic import SyntheticSequence
from d2slam.data.tum import TumSequence, read_tum_trajectory, write_tum_trajectory

__all__ = ["Camera", "RGBDFrame", "Sequence", "Trajectory", "TumSequence", "SyntheticSequence", "open_sequence",
           "read_tum_trajectory", "write_tum_trajectory"]


def open_sequence(path: str | Path, **kwargs) -> TumSequence:
    """A :class:`SyntheticSequence` when ``path/scene.json`` exists, else a :class:`TumSequence`. ``kwargs``
    (camera, max_dt, offset) go to the reader."""
    path = Path(path).expanduser()
    if (path / "scene.json").is_file():
        return SyntheticSequence(path, **kwargs)
    return TumSequence(path, **kwargs)
