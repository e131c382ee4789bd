"""The identity of a run's result (``d2slam study --resume`` reuses a finished run whose key is unchanged) and the
code digests the manifest records."""

from __future__ import annotations

from functools import lru_cache
from importlib import metadata
from pathlib import Path

from d2slam.baselines.vocab import resolve_vocabulary
from d2slam.cachefiles import sha256_file
from d2slam.digests import digest, source_digest
from d2slam.study.grid import ORBSLAM3, ORBSLAM3_MASKED, REPEATED, RunSpec
from d2slam.study.runner import RunOptions
from d2slam.synth.version import generator_version

# Source that decides an engine run's numbers, and an ORB-SLAM3 run's (which never touches the engine or dynamics).
ENGINE_CODE = ("slam", "dynamics", "segmentation", "data", "eval", "methods.py", "pipeline.py", "record.py",
               "config.py", "study/runner.py")
ORBSLAM3_CODE = ("baselines", "data", "eval", "record.py", "config.py", "study/runner.py")
ORBSLAM3_MASKED_CODE = ORBSLAM3_CODE + ("segmentation",)  # ... and the masks it removes
RUN_PACKAGES = ("numpy", "scipy", "opencv-python-headless", "onnxruntime", "gtsam", "g2opy", "evo", "pyorbslam3")


def code_info() -> dict:
    """The source digests that key the runs (:func:`d2slam.digests.source_digest`: comments and docstrings left out):
    ``engine`` for the engine's runs, ``orbslam3`` for ORB-SLAM3's, ``orbslam3-masked`` for ORB-SLAM3's on masked
    frames. Two studies with the same digests ran the same code, whatever their commits."""
    return {"engine": source_digest(ENGINE_CODE), "orbslam3": source_digest(ORBSLAM3_CODE),
            "orbslam3-masked": source_digest(ORBSLAM3_MASKED_CODE)}


def run_key(spec: RunSpec, options: RunOptions) -> str:
    """What a run's numbers depend on: the run, the config (seeded), the masks, the generator version, the source
    of the code that computes them and the versions of the numeric packages (and, for ORB-SLAM3, its repeats and
    vocabulary file). Equal keys => a finished run can be reused (``--resume``)."""
    orb = spec.method in REPEATED
    code = {ORBSLAM3: ORBSLAM3_CODE, ORBSLAM3_MASKED: ORBSLAM3_MASKED_CODE}.get(spec.method, ENGINE_CODE)
    ident = {"spec": spec.to_dict(), "config": options.config.to_dict(), "masks": options.masks,
             "tum_root": options.tum_root, "code": source_digest(code), "packages": _packages()}
    if spec.source == "synth":
        ident["generator"] = generator_version()
    if orb:
        ident["repeats"] = options.orbslam3_repeats
        ident["vocabulary"] = _vocabulary_sha()
    elif spec.loop_closing and options.config.engine.loop_closing:
        vocab = options.config.engine.vocabulary
        ident["vocabulary"] = _file_sha(vocab) if vocab else _vocabulary_sha()
    return digest(ident)


def _file_sha(path: str):
    try:
        return sha256_file(Path(path).expanduser())
    except OSError:
        return None


def package_versions(names) -> dict:
    """The installed version of each distribution in ``names`` (None: not installed)."""
    out = {}
    for n in names:
        try:
            out[n] = metadata.version(n)
        except metadata.PackageNotFoundError:
            out[n] = None
    return out


@lru_cache(maxsize=1)
def _packages() -> dict:
    return package_versions(RUN_PACKAGES)


@lru_cache(maxsize=1)
def _vocabulary_sha():
    try:
        return resolve_vocabulary(None, build=False, progress=False)["sha256"]
    except Exception:  # noqa: BLE001 - no vocabulary yet: the key says so
        return None
