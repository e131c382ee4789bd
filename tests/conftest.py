"""Shared fixtures."""

from __future__ import annotations

import pytest


@pytest.fixture
def assets_kept(monkeypatch):
    """The segmentation models and the real TUM frames stay where they were found when a test moves
    ``$D2SLAM_CACHE``: a clone without ../shared keeps them in the cache (``d2slam assets fetch``), which the test's
    own cache would hide (the segmenter, and the vocabulary built from the real frames, need them)."""
    from d2slam.assets import INT8_MODEL, asset_path

    model = asset_path(INT8_MODEL)
    monkeypatch.setenv("D2SLAM_SHARED", str(model.parents[1]))
