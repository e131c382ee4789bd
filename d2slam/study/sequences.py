"""The study's sequence cache: synthetic sequences generated once and reused, keyed by scenario, seed, frames,
static twin and *generator version* (:func:`d2slam.synth.version.generator_version`).

``cache_dir("study", "sequences", "<scenario>_s<seed>_n<frames>[_twin]-<generator version>")``. The generator version
is a digest of the synthetic format, the package version, every ``SynthConfig`` value and the code of
``d2slam/synth/*.py`` (comments and docstrings left out, as in the run keys): a changed generator never feeds a
study a stale sequence. A sequence counts as present only
when its ``.complete`` marker (written last, holding the key and the manifest of its files: size, modification time,
sha256) is there and its files match it (:func:`d2slam.cachefiles.folder_problems`: sizes and times on every use,
a file whose time changed hashed again); a damaged one is said in one line and generated again (the generator is
deterministic: the same bytes). A sequence cached before markers held a manifest is adopted: its files are recorded
as they are. It is generated into a temporary folder and renamed into place (:func:`d2slam.outputs.staged_dir`),
under a lock file, so concurrent workers (processes or a Dask cluster sharing the cache) never read a half-written
sequence and never generate the same one twice. :func:`remove_stale_temps` removes the temporary folders of
processes that were killed before they could.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from d2slam.assets import real_full
from d2slam.cachefiles import Damaged, folder_manifest, folder_problems, read_json, report_damaged
from d2slam.digests import digest
from d2slam.errors import D2SlamError
from d2slam.outputs import file_lock, remove_stale_temps as remove, staged_dir, write_bytes
from d2slam.paths import cache_dir
from d2slam.progress import announce
from d2slam.study.grid import TUM_FOLDERS
from d2slam.synth import generate
from d2slam.synth.generate import estimated_seconds
from d2slam.synth.scene import resolve_frames
from d2slam.synth.twin import read_recording
from d2slam.synth.version import generator_version

MARKER = ".complete"


def sequence_name(scenario: str, seed: int, frames: int, twin: bool) -> str:
    return f"{scenario}_s{int(seed)}_n{int(frames)}{'_twin' if twin else ''}"


def sequence_dir(scenario: str, seed: int, frames: int, twin: bool, root: str | Path | None = None) -> Path:
    """Where the cached sequence lives (it may not exist yet)."""
    base = Path(root) if root is not None else cache_dir("study", "sequences")
    return base / f"{sequence_name(scenario, seed, frames, twin)}-{generator_version()}"


def is_complete(path: Path) -> bool:
    """The sequence is there (its marker is; :func:`sequence_problems` says whether its files are intact)."""
    return (Path(path) / MARKER).is_file()


def sequence_problems(path: Path, full: bool = False, adopt: bool = True) -> list[str]:
    """What is wrong with the cached sequence at ``path`` (empty: nothing): a marker missing or damaged, files that
    differ from its manifest (``full``: every file hashed). A marker without a manifest (written before markers had
    one) is given one now (``adopt``), from the files as they are."""
    marker = Path(path) / MARKER
    try:
        record = read_json(marker)
    except FileNotFoundError:
        return ["not generated (no marker)"]
    except Damaged as exc:
        return [f"{MARKER}: {exc}"]
    if not isinstance(record.get("files"), dict):
        try:
            if adopt:
                write_bytes(marker, json.dumps({**record, "files": folder_manifest(path, skip=(MARKER,))}) + "\n")
        except D2SlamError:  # a read-only cache: checked again next time
            pass
        return []
    return folder_problems(path, record["files"], full=full)


def ensure_sequence(scenario: str, seed: int, frames: int, twin: bool = False, root: str | Path | None = None,
                    progress: bool = True) -> Path:
    """The cached sequence's folder, generated (single process, deterministic) if missing, incomplete or damaged
    (said in one line); with ``progress`` the generation is announced with an estimate and followed
    (:mod:`d2slam.progress`)."""
    path = sequence_dir(scenario, seed, frames, twin, root)
    if is_complete(path) and not sequence_problems(path):
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    name = sequence_name(scenario, seed, frames, twin)
    with file_lock(path.parent / (path.name + ".lock")):  # another worker may be generating it: wait, then reuse
        problems = sequence_problems(path)
        if not problems:
            return path

        if is_complete(path):
            report_damaged(path, "cached sequence", "; ".join(problems), "generating it again")
        if progress:
            announce(f"generating {name} (once; cached in {path.parent})", estimated_seconds(int(frames), 1))
        with staged_dir(path) as tmp:  # replaces an incomplete or damaged one; removed if interrupted
            generate(scenario, tmp, frames=int(frames), seed=int(seed), static_twin=bool(twin), workers=1,
                     progress=progress)
            key = {"scenario": scenario, "seed": int(seed), "frames": int(frames), "static_twin": bool(twin),
                   "generator_version": generator_version()}
            (tmp / MARKER).write_text(json.dumps({**key, "files": folder_manifest(tmp)}) + "\n")
    return path


def composite_dir(scenario: str, seed: int, frames: int, recording: str | Path,
                  root: str | Path | None = None) -> Path:
    """Where the cached composite of ``scenario`` (``grid.COMPOSITE_SCENARIOS``) into the real ``recording`` lives:
    keyed by the recording (its folder's name and a digest of its lists and ground truth), scenario, seed, frames
    (0: all) and the generator version."""
    rec = Path(recording)
    lists = digest({n: hashlib.sha256((rec / n).read_bytes()).hexdigest() if (rec / n).is_file() else None
                    for n in ("rgb.txt", "depth.txt", "groundtruth.txt")})
    base = Path(root) if root is not None else cache_dir("study", "sequences")
    return base / f"{scenario}_on_{rec.resolve().name}-{lists[:8]}_s{int(seed)}_n{int(frames)}-{generator_version()}"


def ensure_composite(scenario: str, seed: int, frames: int, recording: str | Path, root: str | Path | None = None,
                     progress: bool = True) -> Path:
    """The cached composite's folder (:func:`composite_dir`), generated (single process, deterministic) if missing,
    incomplete or damaged, as :func:`ensure_sequence` does a synthetic sequence: the people of ``scenario`` put into
    the real ``recording``'s first ``frames`` frames (0: all; ``d2slam.synth.compositing``)."""
    path = composite_dir(scenario, seed, frames, recording, root)
    if is_complete(path) and not sequence_problems(path):
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    with file_lock(path.parent / (path.name + ".lock")):
        problems = sequence_problems(path)
        if not problems:
            return path

        if is_complete(path):
            report_damaged(path, "cached sequence", "; ".join(problems), "generating it again")
        rec = read_recording(recording)
        n = resolve_frames(scenario, int(frames) or None, recorded=len(rec))
        if progress:
            announce(f"generating {path.name} (once; cached in {path.parent})",
                     estimated_seconds(n, 1, scenario=scenario))
        with staged_dir(path) as tmp:
            generate(scenario, tmp, frames=n, seed=int(seed), workers=1, progress=progress, recording=rec)
            key = {"scenario": scenario, "seed": int(seed), "frames": int(frames), "recording": str(recording),
                   "generator_version": generator_version()}
            (tmp / MARKER).write_text(json.dumps({**key, "files": folder_manifest(tmp)}) + "\n")
    return path


def tum_sequence_dir(tum_root: str | Path, scenario: str) -> Path:
    """The fr3 folder of ``scenario`` under a real TUM copy (``rgbd_dataset_freiburg3_<scenario>``)."""
    root = Path(tum_root).expanduser()
    path = root / TUM_FOLDERS[scenario]
    if not path.is_dir():
        raise D2SlamError(f"TUM sequence {TUM_FOLDERS[scenario]} not found under the TUM root", path=root)
    return path


def real_sequence_dir(scenario: str) -> Path:
    """The folder of the real recording ``scenario`` (``grid.REAL_SCENARIOS``): the whole TUM fr1/rpy in the shared
    folder or the cache (``d2slam.assets.real_full``); a D2SlamError naming the command that fetches it."""
    path = real_full()
    if scenario != "fr1_rpy" or path is None:
        raise D2SlamError(f"the real recording {scenario} is not in the cache: `d2slam assets fetch --full-real` "
                          "fetches the whole TUM fr1/rpy")
    return path


def remove_stale_temps(root: str | Path | None = None) -> list[Path]:
    """Remove the temporary sequence folders (``<name>.tmp-<pid>...``) of processes that are gone, under ``root``
    (default: the study's sequence cache); the work of running processes is left alone."""
    return remove(Path(root) if root is not None else cache_dir("study", "sequences"))
