"""Per-stage wall-clock timing: ``with timer("track"): ...`` adds the block's seconds to ``timer.seconds["track"]``."""

from __future__ import annotations

import time
from contextlib import contextmanager


class StageTimer:
    def __init__(self, *stages: str):
        self.seconds: dict[str, float] = dict.fromkeys(stages, 0.0)

    @contextmanager
    def __call__(self, stage: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[stage] = self.seconds.get(stage, 0.0) + time.perf_counter() - t0
