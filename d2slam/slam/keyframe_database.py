"""Place recognition (ORB-SLAM3 ``KeyFrameDatabase``): each keyframe's bag of words, an inverted file from words to
the keyframes that hold them, the covisibility graph that the candidate rules read, and the two queries of ORB-SLAM:
loop candidates and relocalisation candidates.

A keyframe's bag of words is made of its static keypoints only: a keypoint the hook flags dynamic
(``KeyFrame.dynamic``) gives no word, so a person standing in two views cannot make them look alike. Without a filter
(``none``) every keypoint counts, as in ORB-SLAM3 (and with ``LoopConfig.loop_dynamic_keypoints``, an ablation).

The covisibility graph follows ORB-SLAM's ``UpdateConnections``: when a keyframe enters the database its weights
(shared map points) to the others are counted once; a connection (at least ``covisibility_min_shared`` points) is
recorded on both sides, and the keyframe's parent in the spanning tree is the one it shares most points with. The
loop closer updates the connections of the keyframes it corrects.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from numba import njit

from d2slam.slam.config import EngineConfig
from d2slam.slam.map import KeyFrame, Map
from d2slam.slam.orb_vocabulary import BowVocabulary


@dataclass
class Bow:
    words: np.ndarray  # (W,) sorted word ids
    weights: np.ndarray  # (W,) L1-normalised weights
    kp_words: np.ndarray = field(default=None, repr=False)  # (N,) word of each keypoint (-1: not in the bag)
    kp_nodes: np.ndarray = field(default=None, repr=False)  # (N,) feature-vector node of each keypoint (-1: idem)


class KeyFrameDatabase:
    def __init__(self, vocabulary: BowVocabulary, map_: Map, cfg: EngineConfig):
        self.voc = vocabulary
        self.map = map_
        self.cfg = cfg
        # Inverted file as linked lists in flat arrays: the postings of word w are post_kf[head[w]],
        # post_kf[nxt[head[w]]], ... (newest first, -1 ends); bags of words are stored flat, keyframe k's at
        # bow_start[k]:bow_start[k] + bow_len[k].
        self.head = np.full(vocabulary.n_nodes, -1, np.int64)
        self.nxt = np.zeros(0, np.int64)
        self.post_kf = np.zeros(0, np.int64)
        self.n_post = 0
        self.bow_words = np.zeros(0, np.int64)
        self.bow_weights = np.zeros(0, np.float64)
        self.bow_start = np.zeros(0, np.int64)
        self.bow_len = np.zeros(0, np.int64)
        self._dense = np.zeros(vocabulary.n_nodes, np.float64)  # scratch: a query's weights by word
        self.bows: dict[int, Bow] = {}
        self.weights: dict[int, dict[int, int]] = {}  # keyframe -> {connected keyframe: shared points}
        self._order: dict[int, list[int]] = {}  # keyframe -> its connections, most shared points first
        self.parent: dict[int, int] = {}  # spanning tree (the first keyframe has none)

    # ------------------------------------------------------------------ bags of words
    def bow(self, desc: np.ndarray, usable: np.ndarray | None) -> Bow:
        """The bag of words of the ``usable`` keypoints (None: all) of a frame or keyframe."""
        n = len(desc)
        sel = np.arange(n) if usable is None else np.flatnonzero(usable)
        words, weights, w, nd = self.voc.bow(desc[sel], self.cfg.loops.bow_levelsup)
        kp_words, kp_nodes = np.full(n, -1, np.int64), np.full(n, -1, np.int64)
        kp_words[sel], kp_nodes[sel] = w, nd
        return Bow(words, weights, kp_words, kp_nodes)

    def add(self, kf: KeyFrame) -> Bow:
        """Enter ``kf``: its bag of words (static keypoints), the inverted file, its connections and parent."""
        bow = self.bow(kf.desc, None if kf.dynamic is None or self.cfg.loops.loop_dynamic_keypoints else ~kf.dynamic)
        self.bows[kf.id] = bow
        m = len(bow.words)
        n0 = self.n_post
        self.post_kf = _grow(self.post_kf, n0 + m)
        self.nxt = _grow(self.nxt, n0 + m)
        self.post_kf[n0:n0 + m] = kf.id
        self.nxt[n0:n0 + m] = self.head[bow.words]
        self.head[bow.words] = np.arange(n0, n0 + m)
        self.n_post = n0 + m
        k = kf.id
        self.bow_start = _grow(self.bow_start, k + 1)
        self.bow_len = _grow(self.bow_len, k + 1)
        b0 = int(self.bow_start[k - 1] + self.bow_len[k - 1]) if k else 0
        self.bow_words = _grow(self.bow_words, b0 + m)
        self.bow_weights = _grow(self.bow_weights, b0 + m)
        self.bow_words[b0:b0 + m], self.bow_weights[b0:b0 + m] = bow.words, bow.weights
        self.bow_start[k], self.bow_len[k] = b0, m
        self.update_connections(kf.id, first=True)
        return bow

    # ------------------------------------------------------------------ covisibility graph
    def update_connections(self, kf_id: int, first: bool = False) -> None:
        """ORB-SLAM ``UpdateConnections``: the keyframe's weights to every keyframe it shares at least
        ``covisibility_min_shared`` points with, on both sides; on entry (``first``) its parent is the one it shares
        most points with (the previous keyframe when it shares none)."""
        w = self.map.covisibility(kf_id)
        conn = np.flatnonzero(w >= self.cfg.covisibility_min_shared)
        conn = [int(k) for k in conn if not self.map.keyframes[k].bad]
        old = self.weights.get(kf_id, {})
        for k in old:
            if k not in conn:
                self.weights.get(k, {}).pop(kf_id, None)
                self._order.pop(k, None)
        mine = {k: int(w[k]) for k in conn}
        self.weights[kf_id] = mine
        self._order.pop(kf_id, None)
        for k, n in mine.items():
            self.weights.setdefault(k, {})[kf_id] = n
            self._order.pop(k, None)
        if first and kf_id > 0:
            best = max(mine, key=lambda k: (mine[k], -k)) if mine else None
            if best is None:
                earlier = [k for k in self.bows if k < kf_id and not self.map.keyframes[k].bad]
                best = max(earlier) if earlier else None
            if best is not None:
                self.parent[kf_id] = best

    def connected(self, kf_id: int) -> list[int]:
        """The good keyframes connected to ``kf_id``, most shared points first (ties: lower id first)."""
        order = self._order.get(kf_id)
        if order is None:
            items = self.weights.get(kf_id, {}).items()
            order = self._order[kf_id] = [k for k, _ in sorted(items, key=lambda x: (-x[1], x[0]))]
        kfs = self.map.keyframes
        return [k for k in order if not kfs[k].bad]

    def best_covisibles(self, kf_id: int, n: int) -> list[int]:
        return self.connected(kf_id)[:n]

    def tree_parent(self, kf_id: int) -> int | None:
        """The keyframe's parent in the spanning tree, skipping culled ancestors (ORB-SLAM hands a culled
        keyframe's children to its parent)."""
        p = self.parent.get(kf_id)
        while p is not None and self.map.keyframes[p].bad:
            p = self.parent.get(p)
        return p

    # ------------------------------------------------------------------ queries
    def _sharing(self, bow: Bow, exclude: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(keyframe ids, common words) of the good keyframes sharing a word with ``bow``, not in ``exclude``."""
        counts = _common_words(self.head, self.nxt, self.post_kf, bow.words, len(self.map.keyframes))
        counts[exclude] = 0
        counts[[k.id for k in self.map.keyframes if k.bad]] = 0
        kfs = np.flatnonzero(counts)
        return kfs, counts[kfs]

    def scores(self, bow: Bow, kfs: np.ndarray) -> np.ndarray:
        """DBoW2 L1 scores of ``bow`` against the keyframes ``kfs`` (all at once)."""
        kfs = np.asarray(kfs, np.int64)
        if len(kfs) == 0:
            return np.zeros(0)
        d = self._dense
        d[bow.words] = bow.weights
        try:
            return _scores(d, self.bow_words, self.bow_weights, self.bow_start, self.bow_len, kfs)
        finally:
            d[bow.words] = 0.0

    def _grouped(self, bow: Bow, exclude: np.ndarray, min_score: float | None):
        """ORB-SLAM's candidate rules: keyframes sharing more than ``loop_common_words`` of the best one's common
        words, scoring at least ``min_score`` (None: any), then grouped with their ``loop_group_size`` best
        covisibles; each group's accumulated score, its best keyframe. Returns (best keyframe per group, group score,
        keyframe score) of the groups above ``loop_group_ratio`` of the best group, and the (keyframe, score) pairs
        that passed the score rule."""
        cfg = self.cfg
        kfs, common = self._sharing(bow, exclude)
        if len(kfs) == 0:
            return [], []
        keep = common > cfg.loops.loop_common_words * common.max()
        kfs = kfs[keep]
        sc = self.scores(bow, kfs)
        if min_score is not None:
            ok = sc >= min_score
            kfs, sc = kfs[ok], sc[ok]
        if len(kfs) == 0:
            return [], []
        score_of = dict(zip(kfs.tolist(), sc.tolist()))
        groups = []
        for k in kfs.tolist():
            best, best_s, acc = k, score_of[k], score_of[k]
            for c in self.best_covisibles(k, cfg.loops.loop_group_size):
                s = score_of.get(c)
                if s is None:
                    continue
                acc += s
                if s > best_s:
                    best, best_s = c, s
            groups.append((best, acc, best_s))
        top = max(g[1] for g in groups)
        out, seen = [], set()
        for best, acc, s in groups:
            if acc > cfg.loops.loop_group_ratio * top and best not in seen:
                seen.add(best)
                out.append((best, acc, s))
        return out, list(score_of.items())

    def loop_candidates(self, kf_id: int, min_score: float):
        """ORB-SLAM ``DetectLoopCandidates`` for keyframe ``kf_id`` (itself and its connected keyframes excluded):
        (candidates as (keyframe, group score, score), every (keyframe, score) above ``min_score``)."""
        exclude = np.array([kf_id] + self.connected(kf_id), dtype=np.int64)
        return self._grouped(self.bows[kf_id], exclude, min_score)

    def relocalisation_candidates(self, desc: np.ndarray, usable: np.ndarray) -> list[int]:
        """ORB-SLAM ``DetectRelocalizationCandidates``: the candidate keyframes of a frame's static keypoints, best
        group first."""
        out, _ = self._grouped(self.bow(desc, usable), np.zeros(0, np.int64), None)
        return [k for k, _, _ in sorted(out, key=lambda g: (-g[1], g[0]))]


def _grow(a: np.ndarray, need: int) -> np.ndarray:
    """``a`` with room for ``need`` entries (capacity doubling; the extra entries are garbage until written)."""
    if len(a) >= need:
        return a
    out = np.empty(max(need, 2 * len(a), 1024), a.dtype)
    out[:len(a)] = a
    return out


@njit(cache=True, nogil=True)
def _common_words(head, nxt, post_kf, words, n_kf):
    counts = np.zeros(n_kf, np.int64)
    for w in words:
        p = head[w]
        while p >= 0:
            counts[post_kf[p]] += 1
            p = nxt[p]
    return counts


@njit(cache=True, nogil=True)
def _scores(dense, bow_words, bow_weights, bow_start, bow_len, kfs):
    out = np.zeros(len(kfs))
    for i in range(len(kfs)):
        k = kfs[i]
        s = 0.0
        for j in range(bow_start[k], bow_start[k] + bow_len[k]):
            q = dense[bow_words[j]]
            if q > 0:
                s += min(q, bow_weights[j])
        out[i] = s
    return out
