"""The identity of a run's result (``d2slam study --resume`` reuses a finished run whose key is unchanged) and the
code digests the manifest records."""

from __future__ import annotations

import json
from functools import lru_cache
from importlib import metadata
from pathlib import Path

from d2slam.baselines.vocab import resolve_vocabulary
from d2slam.cachefiles import sha256_file
from d2slam.config import DEFAULT
from d2slam.digests import digest, source_digest
from d2slam.ranges import flat_fields
from d2slam.run.methods import get_method, masks_read, methods, run_reads
from d2slam.study.grid import ORBSLAM3, REPEATED, RunSpec
from d2slam.study.runner import RunOptions
from d2slam.synth.version import generator_version

RUN_PACKAGES = ("numpy", "scipy", "opencv-python-headless", "onnxruntime", "gtsam", "g2opy", "evo", "pyorbslam3")


def code_info() -> dict:
    """The source digests of the runs, per method (:func:`d2slam.digests.source_digest` of what the method reads,
    :func:`d2slam.run.methods.run_reads`: comments and docstrings left out). Two studies with the same digests ran
    the same code, whatever their commits."""
    out = {}
    for name in methods():
        m = get_method(name)
        out[name] = source_digest(run_reads(m, DEFAULT, masks_read(m, None, synthetic=True))[1])
    return out


def worker_fingerprint(code: dict | None = None) -> dict:
    """What a process computes the runs with, as their keys record it: the source digests of the methods
    (:func:`code_info`, or ``code`` when already taken), the numeric packages' versions and the sequence generator's
    version. A Dask worker must have this process's (:func:`d2slam.study.core.check_dask_workers`)."""
    return {"code": code_info() if code is None else code, "packages": _packages(), "generator": generator_version()}


def fingerprint_differences(mine: dict, theirs: dict) -> list[str]:
    """What differs between two :func:`worker_fingerprint` (``theirs`` against ``mine``), in words; [] when equal."""
    out = []
    code_a, code_b = mine.get("code") or {}, theirs.get("code") or {}
    changed = [m for m in sorted(set(code_a) | set(code_b)) if code_a.get(m) != code_b.get(m)]
    if changed:
        out.append(f"the code of {', '.join(changed)}")
    pk_a, pk_b = mine.get("packages") or {}, theirs.get("packages") or {}
    out += [f"{n} {pk_b.get(n)} (here {pk_a.get(n)})" for n in sorted(set(pk_a) | set(pk_b))
            if pk_a.get(n) != pk_b.get(n)]
    if mine.get("generator") != theirs.get("generator"):
        out.append("the sequence generator")
    return out


def run_ident(spec: RunSpec, options: RunOptions) -> dict:
    """What a run's numbers depend on, and nothing else: the run, the config values its method reads and the source
    of the code it runs (:func:`d2slam.run.methods.run_reads`), its masks, the generator version of a synthetic
    sequence, the versions of the numeric packages and, for ORB-SLAM3, its repeats and vocabulary file (the engine's
    vocabulary file when it closes loops)."""
    if spec.method not in methods():
        return {"spec": spec.to_dict()}  # an unknown method's run fails with its own message
    method = get_method(spec.method)
    # an online run's filter reads the real segmenter's masks, computed in its own thread, whatever the study's --masks
    masks = masks_read(method, "onnx" if spec.online else options.masks,
                       synthetic=spec.source in ("synth", "composite"))
    reads, code = run_reads(method, options.config, masks)
    if spec.online:
        reads = {**reads, "online": online_reads(spec, options.config)}
        code = code + (ONLINE_STUDY_CODE if spec.method == ORBSLAM3 else ONLINE_CODE)
    ident = {"spec": spec.to_dict(), "config": reads, "code": source_digest(code), "masks": masks,
             "tum_root": options.tum_root, "packages": _packages()}
    if spec.source in ("synth", "composite"):
        ident["generator"] = generator_version()
    if spec.method in REPEATED:
        ident["repeats"] = options.orbslam3_repeats
        ident["vocabulary"] = _vocabulary_sha()
    elif spec.loop_closing and options.config.engine.loop_closing:
        vocab = options.config.engine.vocabulary
        ident["vocabulary"] = _file_sha(vocab) if vocab else _vocabulary_sha()
    return ident


# What an online run reads beyond its offline run's code: the study's online phase and, for the engine, the online
# run path; the real ORB-SLAM3's online camera (its worker, d2slam.data.live) is in its offline code already.
ONLINE_STUDY_CODE = ("study/online.py",)
ONLINE_CODE = ("run/online.py",) + ONLINE_STUDY_CODE


def online_reads(spec: RunSpec, config) -> dict:
    """The ``online`` config fields an online run reads: all of them for the engine, the rate for ORB-SLAM3 (its
    threads and masks are its own)."""
    fields = flat_fields(config.online)
    return {"rate_hz": fields["rate_hz"]} if spec.method == ORBSLAM3 else fields


def run_key(spec: RunSpec, options: RunOptions) -> str:
    """The run's key: the digest of :func:`run_ident`. Equal keys => a finished run can be reused (``--resume``)."""
    return digest(run_ident(spec, options))


def key_parts(ident: dict) -> dict:
    """Each part of a run's ident as a digest, and the config values it read (flattened to dotted names): what a
    saved run keeps, so that ``--resume`` can say why a run is run again (:func:`why_changed`)."""
    return {"parts": {k: digest({"v": v}) for k, v in ident.items()}, "config": _flat(ident.get("config", {}))}


def why_changed(saved: dict | None, ident: dict) -> str:
    """Why a run whose saved record holds ``saved`` (its :func:`key_parts`, None when it has none) is run again
    under ``ident``: the first part that changed (``config: dynamics.delta_a``, ``code``, ``generator``, ...)."""
    if not saved:
        return "no earlier result"
    now = key_parts(ident)
    for part, d in now["parts"].items():
        if saved["parts"].get(part) == d:
            continue
        if part == "config":
            old, new = saved.get("config") or {}, now["config"]
            names = sorted(k for k in set(old) | set(new) if old.get(k, _MISSING) != new.get(k, _MISSING))
            return "config: " + (", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")
                                 if names else "changed")
        return part
    return "changed"


_MISSING = object()


def _flat(reads: dict) -> dict:
    """{section.field: value} of a run's config reads (each section's fields already dotted: ``flat_fields``; a value
    as JSON, comparable after a round trip)."""
    return {f"{sec}.{k}": json.loads(json.dumps(v, default=str)) for sec, fields in reads.items()
            for k, v in fields.items()}


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
