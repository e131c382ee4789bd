"""``d2slam cache check [--full] [--fix] [--study DIR]``: what in the cache a run would trip on.

Every kind of cache file is checked by the reader that uses it (:mod:`d2slam.cachefiles`): the mask files and their
memos, the vocabulary text (its manifest's sha256 and its structure), its bag-of-words ``.npz``, the vocabulary's
training frames and the cached sequences (their manifests), the extracted features, numba's compiled kernels, the
fetched assets (their pinned sha256), the download records; with ``--study DIR`` also a study's run records. A run
would remake what is damaged (saying so); ``--fix`` removes it now, with what killed processes left behind.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

from d2slam.assets import DERIVED, DOWNLOADS, assets_cache, find
from d2slam.baselines.vocab import check_vocabulary_file, default_vocab_path, manifest_path, training_problems
from d2slam.cachefiles import Damaged, load_npz, read_json, sha256_file, unsealed
from d2slam.data.download import load_records, record_path
from d2slam.errors import D2SlamError
from d2slam.kernel_cache import cache_files, check_file
from d2slam.outputs import _probe, stale_temp
from d2slam.paths import cache_root
from d2slam.segmentation.cache import STORE_NAME, read_store
from d2slam.slam.features import CachedFeatures
from d2slam.slam.orb_vocabulary import read_bow
from d2slam.study.sequences import sequence_problems


def register(sub) -> None:
    parser = sub.add_parser(
        "cache", help="check the cache (what a run would trip on) and clean it",
        description="The cache ($D2SLAM_CACHE, default ~/.cache/d2slam) holds only derived files: masks, "
        "vocabularies, sequences, features, compiled kernels, fetched assets. A damaged file is remade by the run "
        "that needs it, which says so in one line; `d2slam cache check` finds them beforehand.")
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    c = actions.add_parser("check", help="check every cache file; exit 1 when something is wrong",
                           description="Check every file of the cache with the reader that uses it and list, one "
                           "line each, what is damaged, stale (left by a killed process) or not writable. Exit 0 "
                           "when nothing is wrong (or everything was fixed), 1 otherwise.")
    c.add_argument("--full", action="store_true", help="hash every file of the cached sequences and training frames "
                   "(default: sizes and modification times, and the files whose time changed)")
    c.add_argument("--fix", action="store_true", help="remove what is damaged (the next run makes it again) and what "
                   "killed processes left")
    c.add_argument("--study", action="append", default=[], metavar="DIR",
                   help="also check the run records of the study in DIR (what --resume would reuse)")
    c.set_defaults(func=run)


class Findings:
    """What the check found: one line per problem on stdout, ``--fix`` removing what can be remade."""

    def __init__(self, fix: bool):
        self.fix, self.checked, self.problems, self.fixed = fix, 0, 0, 0

    def ok(self, n: int = 1) -> None:
        self.checked += n

    def bad(self, kind: str, path: Path, problem: str, removable: bool = True) -> None:
        self.checked += 1
        self.problems += 1
        done = ""
        if self.fix and removable:
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path, ignore_errors=True)
            else:
                path.unlink(missing_ok=True)
            self.fixed += 1
            done = " (removed: made again on next use)"
        print(f"{kind} {path}: {problem}{done}")


def run(args) -> int:
    root = cache_root()
    found = Findings(args.fix)
    if root.exists() and not root.is_dir():
        found.bad("cache folder", root, "is not a folder: every command that writes the cache would fail; set "
                  "$D2SLAM_CACHE to a folder", removable=False)
        return 1
    if not root.is_dir():
        print(f"d2slam cache check: {root}: no cache yet (nothing to check)")
        return 0
    try:
        _probe(root, "the cache")
    except D2SlamError:
        found.bad("cache folder", root, "not writable: runs that write the cache would fail; set $D2SLAM_CACHE to a "
                  "writable folder", removable=False)
    for check in (_stale_temps, _masks, _vocabulary, _training, _sequences, _features, _kernels, _assets,
                  _download_records):
        check(root, found, args.full)
    for study in args.study:
        _study(Path(study).expanduser(), found)
    remaining = found.problems - found.fixed
    print(f"d2slam cache check: {root}: {found.checked} files or folders checked, {found.problems} "
          f"problem{'s' if found.problems != 1 else ''}" + (f", {found.fixed} removed" if args.fix else ""))
    return 1 if remaining else 0


def _stale_temps(root: Path, found: Findings, full: bool) -> None:
    for p in sorted(root.rglob("*.tmp-*")) + sorted(root.rglob(".tmp-*")):
        if stale_temp(p.name):
            found.bad("temporary file", p, "left by a process that was killed")


def _masks(root: Path, found: Findings, full: bool) -> None:
    for path in sorted((root / "masks").glob(f"*/*/{STORE_NAME}")):
        try:
            read_store(path)
            found.ok()
        except Exception as exc:  # noqa: BLE001 - whatever the reader would meet
            found.bad("mask cache file", path, _why(exc))
    for path in sorted((root / "masks" / "stamps").glob("*.json")):
        try:
            read_json(path)
            found.ok()
        except Damaged as exc:
            found.bad("mask cache memo", path, str(exc))


def _vocabulary(root: Path, found: Findings, full: bool) -> None:
    voc = default_vocab_path()
    if voc.is_file():
        try:
            manifest = read_json(manifest_path(voc))
            if manifest.get("sha256") != sha256_file(voc):
                raise Damaged("its sha256 is not the one its manifest recorded")
            found.ok()
        except FileNotFoundError:
            found.bad("vocabulary", voc, "no manifest (it would be built again)")
        except Damaged as exc:
            found.bad("vocabulary", voc, str(exc))
    external = os.environ.get("PYORBSLAM3_VOCAB")
    if external:  # the user's file: reported, never removed
        try:
            check_vocabulary_file(external)
            found.ok()
        except Exception as exc:  # noqa: BLE001
            found.bad("vocabulary ($PYORBSLAM3_VOCAB)", Path(external), _why(exc), removable=False)
    for path in sorted((root / "vocab" / "bow").glob("*.npz")):
        if ".tmp-" in path.name:
            continue
        try:
            read_bow(path)
            found.ok()
        except Damaged as exc:
            found.bad("bag-of-words vocabulary", path, str(exc))


def _training(root: Path, found: Findings, full: bool) -> None:
    for folder in sorted((root / "vocab" / "train").glob("*/*")):
        if folder.is_dir() and ".tmp-" not in folder.name:
            problems = training_problems(folder, full=full, report=False, adopt=False)
            if problems and problems != ["not rendered"]:
                found.bad("vocabulary training frames", folder, "; ".join(problems))
            else:
                found.ok()


def _sequences(root: Path, found: Findings, full: bool) -> None:
    for folder in sorted((root / "study" / "sequences").glob("*")):
        if folder.is_dir() and ".tmp-" not in folder.name:
            problems = sequence_problems(folder, full=full, adopt=False)
            if problems:
                found.bad("cached sequence", folder, "; ".join(problems))
            else:
                found.ok()


def _features(root: Path, found: Findings, full: bool) -> None:
    for path in sorted((root / "study" / "features").glob("*.npz")):
        if ".tmp-" in path.name:
            continue
        try:
            CachedFeatures(path)
            found.ok()
        except Damaged as exc:
            found.bad("feature file", path, str(exc))


def _kernels(root: Path, found: Findings, full: bool) -> None:
    for path in cache_files():
        problem = check_file(path)
        if problem:
            found.bad("compiled kernel", path, problem)
        else:
            found.ok()


def _assets(root: Path, found: Findings, full: bool) -> None:
    for asset in DOWNLOADS + DERIVED:
        path = find(asset.path)
        if path is None:
            continue
        if sha256_file(path) != asset.sha256:
            ours = path.is_relative_to(assets_cache())
            found.bad("asset", path, f"not the pinned file (sha256 differs){'' if ours else ': fix the shared folder'}",
                      removable=ours)
        else:
            found.ok()


def _download_records(root: Path, found: Findings, full: bool) -> None:
    if record_path().is_file():
        try:
            load_records()
            found.ok()
        except D2SlamError as exc:  # checksums trusted on first use: never remade silently
            found.bad("download records", record_path(), str(exc).split(": ", 1)[-1], removable=False)


def _study(out: Path, found: Findings) -> None:
    runs = out / "runs"
    if not runs.is_dir():
        found.bad("study", out, "no runs/ folder: not a study's output", removable=False)
        return
    for path in sorted(runs.glob("*.json")):
        try:
            record = unsealed(read_json(path))
            npz = path.with_suffix(".npz")
            if record.get("arrays_sha256") and (not npz.is_file() or sha256_file(npz) != record["arrays_sha256"]):
                raise Damaged(f"{npz.name} is not the one it records")
            if npz.is_file():
                load_npz(npz)
            found.ok()
        except (Damaged, json.JSONDecodeError) as exc:
            found.bad("study run record", path, str(exc))


def _why(exc: BaseException) -> str:
    return str(exc) if str(exc) else type(exc).__name__
