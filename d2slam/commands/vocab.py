"""``d2slam vocab build``: the DBoW2 vocabulary ORB-SLAM3 needs, built by the project (no download)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from d2slam.baselines.vocab import Vocabulary, build_vocabulary, default_vocab_path, manifest_path, resolve_vocabulary
from d2slam.cachefiles import Damaged, read_json
from d2slam.outputs import check_output_file, check_outputs
from d2slam.slam.orb_vocabulary import bow_path, read_bow


def register(sub) -> None:
    parser = sub.add_parser("vocab", help="build / check the ORB vocabulary for the real ORB-SLAM3 baseline",
                            description="DBoW2 text vocabulary for ORB-SLAM3 (pyorbslam3). The official ORBvoc.txt "
                            "is not reachable here; users who have it may set PYORBSLAM3_VOCAB instead.")
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    b = actions.add_parser("build", help="train a vocabulary (hierarchical k-majority on ORB descriptors)",
                           description="Train a DBoW2 vocabulary (k=10, L=6, L1 scoring, TF-IDF) on ORB descriptors "
                           "of the real TUM fr3 frames of the shared folder, of synthetic training frames (seeds "
                           "900-999, rendered once into the cache) and of any --images-dir / --sequences. "
                           "Deterministic; cached with a manifest (VOCAB.txt.json). Announced on stderr with an "
                           "estimate (about 30 s on 2 idle cores), with progress lines when stderr is not a "
                           "terminal.")
    b.add_argument("--images-dir", action="append", default=[], metavar="DIR", help="a folder of training images")
    b.add_argument("--sequences", action="append", default=[], metavar="DIR", nargs="+",
                   help="TUM-layout sequences (every n-th frame is used)")
    b.add_argument("--no-synthetic", action="store_true", help="do not use the synthetic training sequences")
    b.add_argument("--no-real", action="store_true", help="do not use the real fr3 frames of the shared folder")
    b.add_argument("--out", default=None, metavar="VOCAB.txt", help="output (default: the d2slam cache)")
    b.add_argument("--force", action="store_true", help="rebuild even if an identical build is cached")
    b.set_defaults(func=_build)
    c = actions.add_parser("check", help="check a vocabulary file's structure and print its figures")
    c.add_argument("path", nargs="?", default=None, help="default: the vocabulary a run would use")
    c.set_defaults(func=_check)


def _build(args) -> int:
    sequences = [s for group in args.sequences for s in group]
    if args.out and Path(args.out).expanduser().resolve() != default_vocab_path().resolve():  # the default is ours
        out = check_output_file(args.out, "--out")
        check_outputs([("--out", out), ("--out's manifest", manifest_path(out))],
                      [("--images-dir folder", d) for d in args.images_dir] + [("sequence", q) for q in sequences])
    m = build_vocabulary(args.out, images_dirs=args.images_dir, sequences=sequences,
                         synthetic=not args.no_synthetic, real=not args.no_real, force=args.force)
    state = "cached (identical build)" if m.get("cached") else f"built in {m['seconds']['total']:.1f} s"
    print(f"vocabulary: {m['path']}  {state}")
    print(f"  {m['n_images']} images, {m['n_descriptors']} descriptors -> {m['n_nodes']} nodes, "
          f"{m['n_words']} words, {m['bytes'] / 1e6:.1f} MB, sha256 {m['sha256'][:16]}...")
    if not m.get("cached"):
        print("  seconds: " + json.dumps(m["seconds"]))
    print(f"  manifest: {m['path']}.json")
    return 0


def _check(args) -> int:
    info = resolve_vocabulary(args.path, build=False)
    v = Vocabulary.load(info["path"])

    if Path(info["path"]) == default_vocab_path().resolve():  # the cache's: it must be the file its build wrote
        try:
            recorded = read_json(manifest_path(info["path"])).get("sha256")
        except (FileNotFoundError, Damaged) as exc:
            recorded = f"unreadable manifest ({exc})"
        if recorded != info["sha256"]:
            print(f"{info['path']}: damaged (its sha256 is not the one its manifest recorded: {recorded}): the next "
                  "run builds it again (`d2slam cache check --fix` removes it now)")
            return 1

    counts = np.bincount(v.depth()[v.is_leaf])
    depths = {d: int(c) for d, c in enumerate(counts) if c}
    npz = bow_path(info["path"], info["sha256"])  # what the engine reads instead of the text
    try:
        derived = f"; derived for the engine: {npz}" if read_bow(npz) else ""
    except FileNotFoundError:
        derived = ""
    except Damaged as exc:
        print(f"{npz}: damaged ({exc}): the engine's bag-of-words file derived from {info['path']}; the next run "
              "derives it again (`d2slam cache check --fix` removes it now)")
        return 1
    print(f"{info['path']}: ok ({info['kind']}, from {info['source']}), k={v.k} L={v.L}, {v.n_nodes - 1} nodes, "
          f"{v.n_words} words, words per depth {depths}, sha256 {info['sha256']}{derived}")
    return 0
