"""A DBoW2 vocabulary for ORB-SLAM3, built by the project (the official ``ORBvoc.txt`` is not reachable here).

Training is DBoW2's hierarchical k-majority on ORB descriptors: a tree of branching factor ``k`` and depth ``L``;
each node's descriptors are split into ``k`` clusters (k-means++ seeding, Hamming distance, bitwise-majority
centres, as DBoW2's ``FORB::meanValue``); the leaves are the words, weighted by ``idf = ln(N / n_word)`` (N training
images, ``n_word`` images having a descriptor that falls in the word, DBoW2 ``setNodeWeights`` with TF-IDF).

The tree is built one level at a time for *all* nodes of the level together (the bit counts of every cluster in
one sparse product), so there is no Python loop over descriptors or over nodes: the loops run over the L levels,
the k seeding steps and the k-majority iterations only.

ORB-SLAM3 (the one pyorbslam3 bundles) reads only this text format (``loadFromTextFile``), in well under a second
for the project's vocabulary (about 100,000 nodes); the file is the one the upstream binary reads too.

Text format read by ORB-SLAM3's ``TemplatedVocabulary::loadFromTextFile``::

    k L scoring weighting                     # ORB-SLAM: "10 6 0 0" (L1-norm scoring, TF-IDF)
    parentId isLeaf b0 b1 ... b31 weight      # one line per non-root node, breadth-first; node id = line number
    ...                                       # no trailing newline (the loader would add an empty node)

ORB-SLAM3 stores each feature's node ``levelsup = 4`` levels above the leaves (``FeatureVector``); a leaf shallower
than ``L - levelsup`` would leave that node id unset in DBoW2's ``transform``, so such clusters are extended by a
single-child chain down to that depth (DBoW2 itself can produce them; we never do).
"""

from __future__ import annotations

import glob
import hashlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
from scipy import sparse

from d2slam import __version__
from d2slam.assets import tum_frames
from d2slam.baselines import child_env
from d2slam.baselines.config import BaselineConfig
from d2slam.cachefiles import Damaged, folder_manifest, folder_problems, read_json, report_damaged, sha256_file
from d2slam.data import open_sequence
from d2slam.errors import D2SlamError
from d2slam.outputs import file_lock, remove_stale_temps, staged_dir, write_bytes
from d2slam.paths import cache_dir
from d2slam.progress import Progress
from d2slam.slam.config import OrbConfig
from d2slam.slam.dbow2 import DESCRIPTOR_BYTES, Vocabulary
from d2slam.slam.matching import hamming
from d2slam.slam.orb_vocabulary import default_vocabulary_path as default_vocab_path
from d2slam.synth.config import SynthConfig
from d2slam.synth.generate import write_image, render_frame, stamp
from d2slam.synth.scene import Scene
from d2slam.synth.version import generator_version
from d2slam.synth.world import WorldRenderer

FORMAT = "d2slam-dbow2-vocab/1"


# --------------------------------------------------------------------------------------------------
# Hamming distances (numpy popcount on 64-bit words)
# --------------------------------------------------------------------------------------------------
def _majority(desc: np.ndarray, keys: np.ndarray, n_keys: int, bits: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray]:
    """Bitwise majority of the descriptors sharing each key (DBoW2 ``FORB::meanValue``: a bit is set when at least
    ceil(n / 2) members have it). Returns (n_keys, 32) uint8 centres and (n_keys,) member counts (0 = empty).

    The per-key bit counts are one sparse product (key membership x unpacked bits): exact (integers below 2^24 in
    float32), and 15-25x faster than a segment reduction over sorted keys. ``bits``: ``desc`` unpacked to (n, 256)
    float32 by the caller, when it asks several times."""

    keys = np.asarray(keys, np.int64)
    counts = np.bincount(keys, minlength=n_keys)
    member = sparse.csr_matrix((np.ones(len(keys), np.float32), (keys, np.arange(len(keys)))),
                               shape=(n_keys, len(keys)))
    if bits is None:
        bits = np.unpackbits(desc, axis=1).astype(np.float32)
    sums = member @ bits  # (n_keys, 256) bit counts
    need = counts // 2 + counts % 2
    centres = np.packbits((sums >= need[:, None]) & (counts[:, None] > 0), axis=1)
    return centres, counts


def _segment_sample(weights: np.ndarray, starts: np.ndarray, sizes: np.ndarray, u: np.ndarray) -> np.ndarray:
    """For each contiguous segment, draw one index with probability proportional to ``weights`` (uniform draw
    ``u`` in [0, 1) per segment); a segment whose weights are all zero gets its first index."""
    cs = np.cumsum(weights)
    before = np.where(starts > 0, cs[np.maximum(starts - 1, 0)], 0.0)
    total = cs[starts + sizes - 1] - before
    target = before + u * total
    idx = np.searchsorted(cs, target, side="right")
    idx = np.clip(idx, starts, starts + sizes - 1)
    return np.where(total > 0, idx, starts)


def _kmajority(desc: np.ndarray, starts: np.ndarray, sizes: np.ndarray, k: int, rng: np.random.Generator,
               max_iter: int) -> np.ndarray:
    """k-majority clustering of every contiguous segment of ``desc`` at once (k-means++ seeding, Hamming, majority
    centres). Returns per-descriptor labels in [0, k)."""
    n, g = len(desc), len(starts)
    seg = np.repeat(np.arange(g), sizes)
    centres = np.zeros((g, k, DESCRIPTOR_BYTES), np.uint8)
    # k-means++ seeding: first centre uniform, then proportional to D(x)^2 to the nearest chosen centre.
    first = starts + np.minimum((rng.random(g) * sizes).astype(np.int64), sizes - 1)
    centres[:, 0] = desc[first]
    mind = hamming(desc, centres[seg, 0]).astype(np.float64)
    for j in range(1, k):
        pick = _segment_sample(mind**2, starts, sizes, rng.random(g))
        centres[:, j] = desc[pick]
        mind = np.minimum(mind, hamming(desc, centres[seg, j]))
    labels = np.full(n, -1, np.int64)
    bits = np.unpackbits(desc, axis=1).astype(np.float32)
    for _ in range(max_iter):
        dist = hamming(desc[:, None, :], centres[seg])  # (n, k)
        new = np.argmin(dist, axis=1)
        if np.array_equal(new, labels):
            break
        labels = new
        upd, counts = _majority(desc, seg * k + labels, g * k, bits)
        keep = counts.reshape(g, k) > 0  # an emptied cluster keeps its previous centre
        centres = np.where(keep[..., None], upd.reshape(g, k, DESCRIPTOR_BYTES), centres)
    return labels


# --------------------------------------------------------------------------------------------------
# The tree
# --------------------------------------------------------------------------------------------------
def build_tree(desc: np.ndarray, image_ids: np.ndarray, k: int = 10, L: int = 6, levelsup: int = 4,
               seed: int = 0, max_iter: int = 10, on_level=None) -> Vocabulary:
    """Hierarchical k-majority (DBoW2 ``create``) over ORB descriptors ``desc`` (n, 32) uint8 taken from the
    training images ``image_ids`` (n,), then idf leaf weights ``ln(N / n_word)``. ``on_level()`` is called after
    each level (progress)."""
    desc = np.ascontiguousarray(desc, dtype=np.uint8)
    if desc.ndim != 2 or desc.shape[1] != DESCRIPTOR_BYTES or len(desc) < k:
        raise D2SlamError(f"need at least k={k} ORB descriptors of 32 bytes to train a vocabulary, got {desc.shape}")
    rng = np.random.default_rng(seed)
    min_leaf_depth = max(1, L - levelsup)
    parent = [np.array([-1])]
    descs = [np.zeros((1, DESCRIPTOR_BYTES), np.uint8)]
    node_of = np.zeros(len(desc), np.int64)  # current node of each descriptor (-1: it reached a leaf)
    n_nodes = 1
    for depth in range(L):
        alive = np.flatnonzero(node_of >= 0)
        nodes, sizes = np.unique(node_of[alive], return_counts=True)
        split = (sizes > 1) | (depth < min_leaf_depth)
        node_of[alive[~split[np.searchsorted(nodes, node_of[alive])]]] = -1  # these nodes are leaves
        nodes, sizes = nodes[split], sizes[split]
        if not len(nodes):
            break
        # descriptors of the splitting nodes, contiguous per node
        members = np.flatnonzero(node_of >= 0)
        members = members[np.argsort(node_of[members], kind="stable")]
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        seg = np.repeat(np.arange(len(nodes)), sizes)
        labels = np.empty(len(members), np.int64)
        in_small = (sizes <= k)[seg]  # DBoW2: at most k descriptors -> one cluster each
        labels[in_small] = (np.arange(len(members)) - starts[seg])[in_small]
        big_sizes = sizes[sizes > k]
        if len(big_sizes):
            big_starts = np.concatenate([[0], np.cumsum(big_sizes)[:-1]])
            labels[~in_small] = _kmajority(desc[members[~in_small]], big_starts, big_sizes, k, rng, max_iter)
        key = seg * k + labels
        centres, counts = _majority(desc[members], key, len(nodes) * k)
        present = np.flatnonzero(counts)  # sorted by parent node, then label: breadth-first order
        remap = np.full(len(nodes) * k, -1, np.int64)
        remap[present] = n_nodes + np.arange(len(present))
        parent.append(nodes[present // k])
        descs.append(centres[present])
        node_of[members] = remap[key]
        n_nodes += len(present)
        if on_level is not None:
            on_level()
    parent = np.concatenate(parent)
    descriptors = np.concatenate(descs)
    has_child = np.zeros(n_nodes, bool)
    has_child[parent[1:]] = True
    vocab = Vocabulary(k=k, L=L, parent=parent, descriptors=descriptors, is_leaf=~has_child,
                       weight=np.zeros(n_nodes))
    vocab.is_leaf[0] = False
    vocab.weight = _idf(vocab, desc, image_ids)
    return vocab


def _idf(vocab: Vocabulary, desc: np.ndarray, image_ids: np.ndarray) -> np.ndarray:
    """Each node's weight: a word's idf ``ln(N / n_word)`` (N training images, n_word the images with at least one
    descriptor falling in the word by DBoW2's descent), 0 for inner nodes."""
    leaf = vocab.transform(desc)
    n_images = int(len(np.unique(image_ids)))
    pairs = np.unique(np.stack([leaf, np.asarray(image_ids, np.int64)], axis=1), axis=0)
    n_word = np.bincount(pairs[:, 0], minlength=len(vocab.parent))
    # a word no training descriptor reaches by descent (possible with k-majority) counts as seen once (rarest)
    idf = np.log(n_images / np.maximum(n_word, 1))
    return np.where(vocab.is_leaf, idf, 0.0)


# --------------------------------------------------------------------------------------------------
# Training data: ORB descriptors of real frames and of synthetic sequences (seeds 900-999)
# --------------------------------------------------------------------------------------------------
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".ppm", ".pgm")


def orb_extractor(orb: OrbConfig = OrbConfig()):
    """OpenCV ORB with ORB-SLAM3's settings (features, scale factor, levels, FAST threshold, patch)."""
    return cv2.ORB_create(nfeatures=orb.n_features, scaleFactor=orb.scale_factor, nlevels=orb.n_levels,
                          edgeThreshold=orb.edge_threshold, patchSize=orb.patch_size,
                          fastThreshold=orb.fast_threshold)


def _read_gray(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise D2SlamError("cannot read image (missing, corrupt or not an image)", path=path)
    return img


def images_of_dir(directory: str | Path) -> list[Path]:
    directory = Path(directory)
    if not directory.is_dir():
        raise D2SlamError("image folder not found", path=directory)
    files = sorted(p for p in directory.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise D2SlamError(f"no images ({', '.join(IMAGE_SUFFIXES)}) in folder", path=directory)
    return files


def images_of_sequence(root: str | Path, stride: int = 1) -> list[Path]:
    """RGB files of a TUM-layout sequence (every ``stride``-th associated frame)."""
    seq = open_sequence(root)
    idx = np.arange(0, len(seq), max(1, stride))
    paths = [seq.rgb_files[i] if hasattr(seq, "rgb_files") else seq[i].rgb_path for i in idx]
    return [Path(p) for p in paths]


def extract_descriptors(images: list[Path], orb: OrbConfig = OrbConfig(), progress: bool = True,
                        interval: float = BaselineConfig().vocab_log_interval_s):
    """ORB descriptors of every image: ((n, 32) uint8, (n,) image index)."""
    extractor = orb_extractor(orb)
    descs, ids = [], []
    bar = Progress("vocabulary: ORB descriptors of images", len(images), "image", progress, interval=interval)
    for i, path in enumerate(images):
        _, d = extractor.detectAndCompute(_read_gray(path), None)
        if d is not None and len(d):
            descs.append(d)
            ids.append(np.full(len(d), i, np.int64))
        bar.update()
    bar.close()
    if not descs:
        raise D2SlamError("no ORB features in any training image")
    return np.concatenate(descs), np.concatenate(ids)


def training_jobs(cfg: BaselineConfig = BaselineConfig()) -> list[dict]:
    """The synthetic training images, one job per (scenario, seed) of ``vocab_train_scenarios`` x
    ``vocab_train_seeds`` (seeds 900-999, never used by the benchmarks): every ``vocab_train_stride``-th frame of the
    ``vocab_train_frames``-frame sequence, i.e. the generator's own frames (:func:`d2slam.synth.generate.
    render_frame`, written as ``d2slam synth`` writes them, so the files are those of the full sequence) without the
    frames in between. Each job's ``out`` folder is in the cache under the generator version; ``done`` says whether
    it is already rendered (:func:`render_training_frames`)."""
    seeds = tuple(cfg.vocab_train_seeds)
    bad = [s for s in seeds if not 900 <= s <= 999]
    if bad:
        raise D2SlamError(f"vocabulary training seeds must be in 900-999 (benchmarks use the others), got {bad}")
    root = cache_training_root() / generator_version()
    jobs = []
    for scenario in cfg.vocab_train_scenarios:
        for seed in seeds:
            out = root / f"{scenario}_s{seed}_n{cfg.vocab_train_frames}_every{cfg.vocab_train_stride}"
            jobs.append({"scenario": scenario, "seed": seed, "frames": cfg.vocab_train_frames,
                         "stride": cfg.vocab_train_stride, "out": str(out), "done": not training_problems(out)})
    return jobs


def training_problems(out: str | Path, full: bool = False, report: bool = True, adopt: bool = True) -> list[str]:
    """What is wrong with a job's rendered training frames (empty: nothing): not rendered (no marker), or frames
    that differ from the marker's manifest (sizes and times, a file whose time changed hashed again; ``full``: every
    file). A damaged folder is said in one line (``report``) and rendered again by the build. A marker without a
    manifest (written before markers had one) is given one from the files as they are (``adopt``)."""
    out = Path(out)
    marker = out / MARKER
    try:
        record = read_json(marker)
    except FileNotFoundError:
        return ["not rendered"]
    except Damaged as exc:
        problems = [f"{MARKER}: {exc}"]
    else:
        if not isinstance(record.get("files"), dict):
            try:
                if adopt:
                    write_bytes(marker, json.dumps({**record, "files": folder_manifest(out, skip=(MARKER,))}))
            except D2SlamError:
                pass
            return []
        problems = folder_problems(out, record["files"], full=full)
    if problems and report:
        report_damaged(out, "vocabulary training frames", "; ".join(problems), "rendering them again")
    return problems


def _n_rendered(jobs: list[dict]) -> int:
    return sum(len(range(0, j["frames"], j["stride"])) for j in jobs)


MARKER = ".complete"


def render_training_frames(jobs: list[dict], cfg: BaselineConfig = BaselineConfig(), progress: bool = True) -> None:
    """Render the training frames of ``jobs`` (``scenario, seed, frames, stride, out``) in one child process (its
    OpenGL context and the generator's state stay out of this one), following its progress."""
    total = _n_rendered(jobs)
    for job in jobs:  # what a killed build left half-rendered
        remove_stale_temps(Path(job["out"]).parent, f"{Path(job['out']).name}.tmp-*")
    cmd = [sys.executable, "-m", "d2slam.baselines.vocab", "render", json.dumps(jobs)]
    bar = Progress("vocabulary: render training frames", total, "frame", progress,
                   interval=cfg.vocab_log_interval_s)

    with subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=child_env()) as proc:
        for line in proc.stdout:
            if line.startswith("frame"):
                bar.update()
        err = proc.stderr.read()
    bar.close()
    if proc.returncode != 0:
        tail = " | ".join(err.strip().splitlines()[-2:])
        raise D2SlamError(f"rendering the vocabulary's training frames failed (exit {proc.returncode}): {tail}",
                          path=jobs[0]["out"])


def _render_main(jobs: list[dict]) -> None:
    """The child of :func:`render_training_frames`: one ``frame`` line on stdout per frame written."""
    cv2.setNumThreads(1)
    synth = SynthConfig()
    parent = os.getppid()
    for job in jobs:
        out = Path(job["out"])
        with staged_dir(out) as tmp:  # the previous (damaged) folder is replaced only by a whole new one
            scene = Scene(job["scenario"], job["seed"], job["frames"], False, synth)
            renderer = WorldRenderer(scene)
            try:
                for i in range(0, job["frames"], job["stride"]):
                    if os.getppid() != parent:  # the build was killed: stop (the folder is removed)
                        raise SystemExit(1)
                    rgb = render_frame(scene, renderer, i)["rgb"]
                    name = stamp(scene.t0 + scene.t_rel[i]) + ".png"
                    write_image(tmp / name, rgb, synth.png_compression)
                    print("frame", flush=True)
            finally:
                renderer.close()
            done = {k: v for k, v in job.items() if k != "done"}
            (tmp / MARKER).write_text(json.dumps({**done, "files": folder_manifest(tmp)}))


def cache_training_root() -> Path:
    return cache_dir("vocab", "train")


def manifest_path(vocab_path: str | Path) -> Path:
    vocab_path = Path(vocab_path)
    return vocab_path.with_name(vocab_path.name + ".json")


def build_vocabulary(out: str | Path | None = None, images_dirs: list[str | Path] = (),
                     sequences: list[str | Path] = (), synthetic: bool = True, real: bool = True,
                     cfg: BaselineConfig = BaselineConfig(), orb: OrbConfig = OrbConfig(), force: bool = False,
                     progress: bool = True) -> dict:
    """Build (or reuse from the cache) a DBoW2 text vocabulary; returns its manifest.

    Sources: the five real TUM fr3 frames (``real``, ``d2slam.assets``), every image of ``images_dirs``, every
    ``vocab_train_stride``-th frame of ``sequences`` and the synthetic training frames (``synthetic``, seeds 900-999,
    :func:`training_jobs`). The manifest (``VOCAB.txt.json``) records sources with their sha256, seeds, parameters,
    sizes, the vocabulary's sha256 and the build time; an identical request reuses the cached file. A build is
    announced on stderr with its estimated duration (always: it happens once, often inside a longer command), and
    each stage shows its progress when ``progress`` (:class:`Progress`). Two processes asking for the same file
    build it once: the second waits for the first (a lock file beside it) and reuses its result."""

    out = Path(out) if out else default_vocab_path()
    groups = _image_groups(images_dirs, sequences, real, cfg)
    jobs = training_jobs(cfg) if synthetic else []
    if not groups and not jobs:
        raise D2SlamError("no training images: give --images-dir or --sequences, or allow the default sources")
    out.parent.mkdir(parents=True, exist_ok=True)
    with file_lock(out.with_name(out.name + ".lock"),
                   waiting=f"vocabulary: another process is building {out}; waiting for it"):
        remove_stale_temps(out.parent, f"{glob.escape(out.name)}*.tmp-*")  # what a killed build was writing
        if synthetic and not all(j["done"] for j in jobs):
            jobs = training_jobs(cfg)  # another process may have rendered them while this one waited
        todo = [j for j in jobs if not j["done"]]
        n_images = sum(len(f) for _, _, f in groups) + _n_rendered(jobs)

        def announce() -> None:
            est = cfg.vocab_estimate_s[0] + cfg.vocab_estimate_s[1] * _n_rendered(todo) \
                + cfg.vocab_estimate_s[2] * n_images
            print(f"vocabulary: building the DBoW2 vocabulary ORB-SLAM3 needs, once (about {est:.0f} s on an idle "
                  "machine): "
                  f"{n_images} training images ({_n_rendered(todo)} to render), ORB descriptors, k-majority tree "
                  f"-> {out}", file=sys.stderr, flush=True)

        t0 = time.perf_counter()
        if todo:
            announce()
            render_training_frames(todo, cfg, progress)
        t_render = time.perf_counter() - t0
        groups += [("synthetic", Path(j["out"]), images_of_dir(j["out"])) for j in jobs]
        sources, params, key = _request(groups, jobs, cfg, orb)
        cached = _cached(out, key, force)
        if cached:
            return cached
        if not todo:
            announce()
        manifest = _build(out, groups, sources, params, key, cfg, orb, progress)
        manifest["seconds"]["render"] = round(t_render, 3)
        manifest["seconds"]["total"] = round(manifest["seconds"]["total"] + t_render, 3)
        print(f"vocabulary: built in {manifest['seconds']['total']:.0f} s: {manifest['n_words']} words, "
              f"{manifest['bytes'] / 1e6:.1f} MB", file=sys.stderr, flush=True)
        return manifest


def _image_groups(images_dirs, sequences, real: bool, cfg: BaselineConfig) -> list[tuple[str, Path, list[Path]]]:
    """The training images other than the synthetic ones, by source: (kind, folder, images)."""
    groups: list[tuple[str, Path, list[Path]]] = []
    if real:
        frames = tum_frames()
        groups.append(("real", frames[0].parent, frames))
    for d in images_dirs:
        groups.append(("images", Path(d), images_of_dir(d)))
    for s in sequences:
        groups.append(("sequence", Path(s), images_of_sequence(s, cfg.vocab_train_stride)))
    return groups


def _request(groups: list, jobs: list[dict], cfg: BaselineConfig, orb: OrbConfig) -> tuple[list, dict, str]:
    """The build request: its sources (kind, path, images, sha256 of names and contents), parameters and key."""
    sources = []
    for kind, root, files in groups:
        h = hashlib.sha256()
        for f in files:
            h.update(f"{f.name} {sha256_file(f)}\n".encode())
        sources.append({"kind": kind, "path": str(root), "images": len(files), "sha256": h.hexdigest()})
    params = {"k": cfg.vocab_k, "L": cfg.vocab_levels, "levelsup": cfg.vocab_levelsup, "scoring": 0,
              "weighting": 0, "seed": cfg.vocab_seed, "max_iter": cfg.vocab_max_iter,
              "orb": {"n_features": orb.n_features, "scale_factor": orb.scale_factor, "n_levels": orb.n_levels,
                      "fast_threshold": orb.fast_threshold, "edge_threshold": orb.edge_threshold,
                      "patch_size": orb.patch_size},
              "train_stride": cfg.vocab_train_stride, "synthetic_seeds": sorted({j["seed"] for j in jobs})}
    key = hashlib.sha256(json.dumps({"params": params, "sources": [s["sha256"] for s in sources]},
                                    sort_keys=True).encode()).hexdigest()
    return sources, params, key


def _build(out: Path, groups: list, sources: list, params: dict, key: str, cfg: BaselineConfig, orb: OrbConfig,
           progress: bool) -> dict:
    t0 = time.perf_counter()
    images = [f for _, _, files in groups for f in files]
    desc, image_ids = extract_descriptors(images, orb, progress=progress, interval=cfg.vocab_log_interval_s)
    t1 = time.perf_counter()
    bar = Progress("vocabulary: k-majority tree levels", cfg.vocab_levels, "level", progress,
                   interval=cfg.vocab_log_interval_s)
    vocab = build_tree(desc, image_ids, k=cfg.vocab_k, L=cfg.vocab_levels, levelsup=cfg.vocab_levelsup,
                       seed=cfg.vocab_seed, max_iter=cfg.vocab_max_iter, on_level=bar.update)
    bar.close()
    t2 = time.perf_counter()
    sha = vocab.save(out)
    t3 = time.perf_counter()
    depth = vocab.depth()
    manifest = {
        "format": FORMAT, "key": key, "path": str(out), "sha256": sha, "bytes": out.stat().st_size,
        "kind": "built", "params": params, "sources": sources, "n_images": len(images),
        "n_descriptors": int(len(desc)), "n_nodes": int(vocab.n_nodes), "n_words": int(vocab.n_words),
        "leaf_depths": {str(d): int(c) for d, c in enumerate(np.bincount(depth[vocab.is_leaf])) if c},
        "stopped_words": int((vocab.weight[vocab.is_leaf] <= 0).sum()),
        "seconds": {"descriptors": round(t1 - t0, 3), "tree": round(t2 - t1, 3), "write": round(t3 - t2, 3),
                    "total": round(t3 - t0, 3)},
        "d2slam_version": __version__, "cached": False,
    }
    write_bytes(manifest_path(out), json.dumps(manifest, indent=2))
    return manifest


def _cached(out: Path, key: str | None, force: bool) -> dict | None:
    """The manifest of ``out`` when it was built from the request ``key`` (any request when None) and the file is
    unchanged since; None otherwise or with ``force``. A vocabulary that no longer matches the sha256 its manifest
    recorded (or whose manifest cannot be read) is damaged: said in one line, and built again by the caller."""
    mpath = manifest_path(out)
    if force or not out.is_file() or not mpath.is_file():
        return None
    try:
        old = read_json(mpath)
    except Damaged as exc:
        report_damaged(mpath, "vocabulary manifest", exc, "building the vocabulary again")
        return None
    if old.get("sha256") != sha256_file(out):
        report_damaged(out, "vocabulary", "its sha256 is not the one its manifest recorded",
                       "building it again")
        return None
    if key is None or old.get("key") == key:
        old["cached"] = True
        return old
    return None


# --------------------------------------------------------------------------------------------------
# Which vocabulary a run uses
# --------------------------------------------------------------------------------------------------
def resolve_vocabulary(path: str | Path | None = None, build: bool = True, progress: bool = True) -> dict:
    """The vocabulary a run uses: ``path`` if given, else ``$PYORBSLAM3_VOCAB`` (e.g. the official ORBvoc.txt),
    else the project-built one in the cache (built on first use when ``build``). Never downloads.

    Returns ``{"path", "sha256", "kind": "built" | "official" | "external", "source"}`` after checking the file's
    structure (ORB-SLAM3's own loader accepts garbage and crashes later): once per file content and process, and
    not at all for the file a build wrote (its manifest holds its sha256)."""

    if path is not None:
        chosen, source = Path(path), "argument"
    elif os.environ.get("PYORBSLAM3_VOCAB"):
        chosen, source = Path(os.environ["PYORBSLAM3_VOCAB"]), "PYORBSLAM3_VOCAB"
        if not chosen.is_file():
            raise D2SlamError("PYORBSLAM3_VOCAB points at no file (unset it to use the project-built vocabulary)",
                              path=chosen)
    else:
        chosen, source = default_vocab_path(), "cache"
        if not chosen.is_file() and not build:
            raise D2SlamError("no ORB vocabulary: run `d2slam vocab build` (or set PYORBSLAM3_VOCAB)", path=chosen)
        if build and str(chosen) not in _CURRENT:
            # built if missing, rebuilt if stale: a vocabulary trained on another generator's frames, or with other
            # parameters, changes loop closing's and ORB-SLAM3's results (build_vocabulary reuses a current file)
            build_vocabulary(chosen, progress=progress)
            _CURRENT.add(str(chosen))
    chosen = chosen.expanduser().resolve()
    if not chosen.is_file():
        check_vocabulary_file(chosen)  # the reader's one-line error
    sha = sha256_file(chosen)
    kind = "external"
    mpath = manifest_path(chosen)
    if mpath.is_file():
        try:
            if read_json(mpath).get("sha256") == sha:
                kind = "built"
        except Damaged:  # checked as any other file below
            pass
    if kind != "built" and (str(chosen), sha) not in _CHECKED:
        check_vocabulary_file(chosen)
        _CHECKED.add((str(chosen), sha))
    if kind == "external" and (source == "PYORBSLAM3_VOCAB" or chosen.name == "ORBvoc.txt"):
        kind = "official"
    return {"path": str(chosen), "sha256": sha, "kind": kind, "source": source}


_CHECKED: set[tuple[str, str]] = set()  # (path, sha256) of the vocabulary files this process has checked
_CURRENT: set[str] = set()  # the cache's vocabulary files this process has found current (or built)


def check_vocabulary_file(path: str | Path) -> None:
    """Structural check of a DBoW2 text vocabulary (header range, 35 fields per node line, parents defined
    before their children, leaf flags consistent with the tree, no trailing newline); raises D2SlamError naming
    the file and line."""
    Vocabulary.load(path)


if __name__ == "__main__":  # the child of render_training_frames: python -m d2slam.baselines.vocab render JOBS

    if sys.argv[1:2] == ["render"] and len(sys.argv) == 3:
        _render_main(json.loads(sys.argv[2]))
    else:
        sys.exit("usage: python -m d2slam.baselines.vocab render JOBS_JSON (started by d2slam vocab build)")
