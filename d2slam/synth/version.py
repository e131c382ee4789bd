"""The generator version: what ``d2slam.synth`` would write, as 16 hex digits (:func:`generator_version`). The
study's sequence cache and the vocabulary's training frames are keyed by it, so a changed generator never feeds them
stale frames."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from functools import lru_cache
from pathlib import Path

import d2slam
from d2slam.digests import code_text
from d2slam.synth.config import SYNTH_CAMERA, SynthConfig
from d2slam.synth.generate import FORMAT

SYNTH = Path(__file__).resolve().parent


@lru_cache(maxsize=1)
def generator_version() -> str:
    """16 hex digits identifying what ``d2slam.synth`` would write: a digest of the synthetic format, the package
    version, every ``SynthConfig`` value, the synthetic camera (``SYNTH_CAMERA``: intrinsics, depth factor, depth
    noise) and the code of ``d2slam/synth/*.py`` (comments and docstrings left out)."""
    h = hashlib.sha256()
    h.update(f"{FORMAT}|{d2slam.__version__}|".encode())
    h.update(json.dumps(dataclasses.asdict(SynthConfig()), sort_keys=True, default=str).encode())
    h.update(json.dumps(dataclasses.asdict(SYNTH_CAMERA), sort_keys=True, default=str).encode())
    for path in sorted(SYNTH.glob("*.py")):
        h.update(path.name.encode())
        h.update(code_text(path.read_text()).encode())
    return h.hexdigest()[:16]
