"""The engine's bag of words (ORB-SLAM3 ``ORBVocabulary``, DBoW2's ``TemplatedVocabulary::transform``): the DBoW2
text vocabulary that the real ORB-SLAM3 loads (:mod:`d2slam.slam.dbow2`; ``d2slam vocab build``, or
``$PYORBSLAM3_VOCAB``), read once per process from a ``.npz`` derived from the text file (keyed by its sha256, written
atomically into the cache).

A descriptor descends the tree from the root to a leaf, taking at each level the child with the smallest Hamming
distance (the first on ties, as DBoW2); the leaf is its word (word id = node id) and the node it passed at depth
``L - levelsup`` its feature-vector node (ORB-SLAM3 ``levelsup = 4``, used to match by words). A bag of words adds
each descriptor's word weight (TF-IDF: the leaf's idf; words of weight 0 are dropped) and is L1-normalised; two bags
score DBoW2's L1 score ``1 - |v - w|_1 / 2`` (= the sum over common words of ``min(v_i, w_i)``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from numba import njit

from d2slam.cachefiles import Damaged, load_npz, report_damaged, sha256_file
from d2slam.errors import D2SlamError
from d2slam.outputs import remove_stale_temps, staged_file
from d2slam.paths import cache_dir
from d2slam.slam.dbow2 import Vocabulary
from d2slam.slam.matching import hamming_at


@dataclass(frozen=True)
class BowVocabulary:
    k: int
    L: int
    children: np.ndarray  # (n_nodes, k) int64 child ids in file order, -1 padded
    desc: np.ndarray  # (n_nodes, 4) uint64 node descriptors (the root's unused)
    weight: np.ndarray  # (n_nodes,) float64: idf on leaves, 0 elsewhere
    sha256: str = ""
    path: str = ""

    @property
    def n_nodes(self) -> int:
        return len(self.weight)

    def transform(self, desc: np.ndarray, levelsup: int) -> tuple[np.ndarray, np.ndarray]:
        """(word id, feature-vector node id) of each (N, 32) uint8 descriptor."""
        d = np.ascontiguousarray(desc, dtype=np.uint8).reshape(-1, 32).view(np.uint64)
        return _descend(self.children, self.desc, d, max(self.L - int(levelsup), 0))

    def bow(self, desc: np.ndarray, levelsup: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The bag of words of the descriptors: (sorted word ids, L1-normalised weights), and each descriptor's
        (word, feature-vector node)."""
        words, nodes = self.transform(desc, levelsup)
        w = self.weight[words]
        keep = w > 0
        ids, inv = np.unique(words[keep], return_inverse=True)
        vals = np.bincount(inv, weights=w[keep], minlength=len(ids))
        total = vals.sum()
        return ids, (vals / total if total > 0 else vals), words, nodes


@njit(cache=True, nogil=True)
def _descend(children, node_desc, desc, fv_depth):
    n, k = desc.shape[0], children.shape[1]
    words = np.zeros(n, np.int64)
    nodes = np.zeros(n, np.int64)
    for i in range(n):  # nodes[i] stays 0 (the root) when fv_depth is 0, as DBoW2
        cur, depth = 0, 0
        while True:
            best, best_d = -1, 1 << 30
            for j in range(k):
                c = children[cur, j]
                if c < 0:
                    break
                d = hamming_at(node_desc, c, desc, i)
                if d < best_d:
                    best, best_d = c, d
            if best < 0:
                break
            cur = best
            depth += 1
            if depth == fv_depth:
                nodes[i] = cur
        words[i] = cur
        if depth < fv_depth:  # a leaf above that depth (never in the project's vocabularies): the leaf itself
            nodes[i] = cur
    return words, nodes


def score(ids_a: np.ndarray, w_a: np.ndarray, ids_b: np.ndarray, w_b: np.ndarray) -> float:
    """DBoW2's L1 score of two L1-normalised bags (sorted word ids, weights), in [0, 1]."""
    common, ia, ib = np.intersect1d(ids_a, ids_b, assume_unique=True, return_indices=True)
    return float(np.minimum(w_a[ia], w_b[ib]).sum()) if len(common) else 0.0


def default_vocabulary_path() -> Path:
    """Where ``d2slam vocab build`` writes the project's vocabulary (in the cache)."""
    return cache_dir("vocab") / "d2slam_orbvoc.txt"


def vocabulary_path(path: str | None = None) -> Path:
    """The vocabulary file the engine reads: ``path`` (``EngineConfig.vocabulary``) when given, else
    ``$PYORBSLAM3_VOCAB`` (e.g. the official ORBvoc.txt), else the project's (:func:`default_vocabulary_path`)."""
    chosen = Path(path) if path else Path(os.environ["PYORBSLAM3_VOCAB"]) if os.environ.get("PYORBSLAM3_VOCAB") \
        else default_vocabulary_path()
    return chosen.expanduser().resolve()


def vocabulary_ready(path: str | None = None) -> bool:
    """Whether the engine can load the vocabulary :func:`vocabulary_path` picks from its derived ``.npz`` at once
    (False: the file is missing, or it has not been derived yet; the run path then checks or builds it first)."""
    chosen = vocabulary_path(path)
    if not chosen.is_file():
        return False
    stat = chosen.stat()
    return bow_path(str(chosen), _sha256(str(chosen), stat.st_size, stat.st_mtime_ns)).is_file()


def load_vocabulary(path: str | None = None) -> BowVocabulary:
    """The vocabulary file :func:`vocabulary_path` picks, loaded once per process: from its derived ``.npz`` in the
    cache when there is one, else from the text file (then derived). The engine loads a file and nothing else: the
    project's is built by ``d2slam vocab build`` (or by the run path, ``d2slam.run.sequence.ensure_vocabulary``)."""
    chosen = vocabulary_path(path)
    if not chosen.is_file():
        raise D2SlamError("no ORB vocabulary: run `d2slam vocab build` (or set PYORBSLAM3_VOCAB)", path=chosen)
    stat = chosen.stat()
    return _load(str(chosen), _sha256(str(chosen), stat.st_size, stat.st_mtime_ns))


@lru_cache(maxsize=4)
def _sha256(path: str, size: int, mtime_ns: int) -> str:
    return sha256_file(Path(path))


def bow_path(path: str, sha256: str) -> Path:
    return cache_dir("vocab", "bow") / f"{Path(path).stem}-{sha256[:16]}.npz"


BOW_ARRAYS = ("k", "L", "children", "desc", "weight")


def read_bow(npz: Path) -> tuple:
    """The arrays of a derived ``.npz`` (:data:`BOW_ARRAYS`), checked against each other;
    :class:`~d2slam.cachefiles.Damaged` when they cannot be read or do not fit."""
    z = load_npz(npz, BOW_ARRAYS)
    k, L, children, desc, weight = (z[n] for n in BOW_ARRAYS)
    n = len(weight)
    if children.ndim != 2 or children.shape != (n, int(k)) or desc.shape != (n, 4) or \
            not (-1 <= children.min(initial=0) and children.max(initial=0) < n):
        raise Damaged("its arrays do not fit together")
    return int(k), int(L), children, desc, weight


@lru_cache(maxsize=2)
def _load(path: str, sha256: str) -> BowVocabulary:
    npz = bow_path(path, sha256)
    if npz.is_file():
        try:
            k, L, children, desc, weight = read_bow(npz)
            return BowVocabulary(k, L, children, desc, weight, sha256, path)
        except Damaged as exc:  # derived from the text file: made again
            report_damaged(npz, "bag-of-words vocabulary", exc, "deriving it again from the vocabulary")
    v = Vocabulary.load(path)
    if v.weighting != 0 or v.scoring != 0:
        raise D2SlamError(f"the engine reads TF-IDF vocabularies with L1 scoring (weighting 0, scoring 0), not "
                          f"weighting {v.weighting}, scoring {v.scoring}", path=path)
    children = v.children_table()
    desc = np.ascontiguousarray(v.descriptors).view(np.uint64)
    remove_stale_temps(npz.parent)  # what a killed process was writing
    with staged_file(npz, ".npz") as tmp:
        np.savez(tmp, k=v.k, L=v.L, children=children, desc=desc, weight=v.weight)
    return BowVocabulary(v.k, v.L, children, desc, np.asarray(v.weight, np.float64), sha256, path)
