"""DBoW2's text vocabulary, the file ORB-SLAM3 reads (``TemplatedVocabulary::loadFromTextFile``) and the engine's
bag of words is derived from (:mod:`d2slam.slam.orb_vocabulary`)::

    k L scoring weighting                     # ORB-SLAM: "10 6 0 0" (L1-norm scoring, TF-IDF)
    parentId isLeaf b0 b1 ... b31 weight      # one line per non-root node, breadth-first; node id = line number
    ...                                       # no trailing newline (the loader would add an empty node)

:class:`Vocabulary` reads it with the checks ORB-SLAM3's loader skips and writes it; building one is a tool above
the engine (:mod:`d2slam.baselines.vocab`, ``d2slam vocab build``).
"""

from __future__ import annotations

import hashlib
import io
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from d2slam.errors import D2SlamError, read_text
from d2slam.outputs import write_bytes
from d2slam.slam.matching import hamming

DESCRIPTOR_BYTES = 32
_BIG = np.uint16(60000)


@dataclass
class Vocabulary:
    """A DBoW2 vocabulary tree. Node 0 is the root; nodes are in breadth-first order."""

    k: int
    L: int
    parent: np.ndarray  # (n_nodes,) int64, -1 for the root
    descriptors: np.ndarray  # (n_nodes, 32) uint8 (root: zeros)
    is_leaf: np.ndarray  # (n_nodes,) bool
    weight: np.ndarray  # (n_nodes,) float64, idf on leaves, 0 elsewhere
    scoring: int = 0  # L1 norm
    weighting: int = 0  # TF-IDF
    meta: dict = field(default_factory=dict)

    @property
    def n_nodes(self) -> int:
        return len(self.parent)

    @property
    def n_words(self) -> int:
        return int(self.is_leaf.sum())

    def depth(self) -> np.ndarray:
        d = np.zeros(self.n_nodes, np.int64)
        for i in range(1, self.L + 1):  # parents precede children (BFS): L passes settle every depth
            d[1:] = d[self.parent[1:]] + 1
        return d

    def children_table(self) -> np.ndarray:
        """(n_nodes, k) child ids in file order, -1 padded."""
        table = np.full((self.n_nodes, self.k), -1, np.int64)
        child = np.arange(1, self.n_nodes)
        par = self.parent[1:]
        # rank of each child among its siblings (children of a node are contiguous in BFS order)
        first = np.searchsorted(par, par, side="left")
        table[par, child - 1 - first] = child
        return table

    def transform(self, desc: np.ndarray) -> np.ndarray:
        """Leaf node id of each descriptor by DBoW2's descent (nearest child at each level, first on ties)."""
        table = self.children_table()
        cur = np.zeros(len(desc), np.int64)
        for _ in range(self.L + 1):
            active = ~self.is_leaf[cur]
            if not active.any():
                break
            ch = table[cur[active]]
            d = hamming(desc[active][:, None, :], self.descriptors[np.maximum(ch, 0)])
            d = np.where(ch >= 0, d, _BIG)
            cur[active] = ch[np.arange(len(ch)), np.argmin(d, axis=1)]
        return cur

    # -- text file --------------------------------------------------------------------------------
    def to_text(self) -> bytes:
        header = f"{self.k} {self.L} {self.scoring} {self.weighting}"
        rows = np.column_stack([self.parent[1:], self.is_leaf[1:].astype(np.int64),
                                self.descriptors[1:].astype(np.int64)])
        buf = io.StringIO()
        buf.write(header + "\n")
        fmt = " ".join(["%d"] * rows.shape[1])
        body = io.StringIO()
        np.savetxt(body, rows, fmt=fmt)
        lines = body.getvalue().split("\n")[:-1]
        weights = [f"{w:.6g}" for w in self.weight[1:].tolist()]
        buf.write("\n".join(f"{a} {b}" for a, b in zip(lines, weights)))  # no trailing newline
        return buf.getvalue().encode()

    def save(self, path: str | Path) -> str:
        """Write the text file (atomically) and return its sha256."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        data = self.to_text()
        write_bytes(path, data)
        return hashlib.sha256(data).hexdigest()

    @classmethod
    def load(cls, path: str | Path) -> "Vocabulary":
        """Read a DBoW2 text vocabulary with the checks ORB-SLAM3's loader skips (it crashes or exits instead)."""
        path = Path(path)
        text = read_text(path, "vocabulary")
        nl = text.find("\n")
        header, body = (text, "") if nl < 0 else (text[:nl], text[nl + 1:])
        try:
            k, L, scoring, weighting = (int(v) for v in header.split())
        except ValueError:
            raise D2SlamError("vocabulary header must be 'k L scoring weighting' (e.g. '10 6 0 0')",
                              path=path, line=1) from None
        if not (2 <= k <= 20 and 1 <= L <= 10 and 0 <= scoring <= 5 and 0 <= weighting <= 3):
            raise D2SlamError(f"vocabulary header out of ORB-SLAM3's range: {header!r}", path=path, line=1)
        n_lines = body.count("\n") + 1 if body else 0
        if text.endswith("\n"):
            raise D2SlamError("vocabulary ends with a newline (ORB-SLAM3 would read an extra empty node)",
                              path=path, line=n_lines + 1)
        if n_lines == 0:
            raise D2SlamError("vocabulary has no nodes", path=path, line=1)
        n_fields = 3 + DESCRIPTOR_BYTES
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a bad token ends the parse early: caught by the count below
            try:
                values = np.fromstring(body, dtype=np.float64, sep=" ")
            except ValueError:  # the pinned numpy (2.4) raises on a bad token: the lines are read one by one below
                values = np.empty(0)
        if values.size != n_lines * n_fields or not np.isfinite(values).all():
            for i, row in enumerate(body.split("\n")):
                toks = row.split()
                try:
                    ok = len(toks) == n_fields and all(np.isfinite(float(t)) for t in toks)
                except ValueError:
                    ok = False
                if not ok:
                    raise D2SlamError(f"vocabulary node line must be {n_fields} numbers "
                                      "(parentId isLeaf b0..b31 weight)", path=path, line=i + 2)
            raise D2SlamError("vocabulary node lines are malformed", path=path, line=2)  # pragma: no cover
        rows = values.reshape(n_lines, n_fields)
        bytes_ = rows[:, 2:-1]
        bad_byte = np.flatnonzero(((bytes_ < 0) | (bytes_ > 255) | (bytes_ != np.round(bytes_))).any(axis=1))
        if len(bad_byte):
            raise D2SlamError("descriptor values must be integers 0-255", path=path, line=int(bad_byte[0]) + 2)
        parent = np.concatenate([[-1], rows[:, 0].astype(np.int64)])
        ids = np.arange(1, len(parent))
        bad = np.flatnonzero((parent[1:] < 0) | (parent[1:] >= ids))
        if len(bad):
            raise D2SlamError(f"node {bad[0] + 1} has parent {parent[bad[0] + 1]} not defined before it",
                              path=path, line=int(bad[0]) + 2)
        desc = np.concatenate([np.zeros((1, DESCRIPTOR_BYTES)), rows[:, 2:-1]]).astype(np.uint8)
        is_leaf = np.concatenate([[False], rows[:, 1] > 0])
        weight = np.concatenate([[0.0], rows[:, -1]])
        has_child = np.zeros(len(parent), bool)
        has_child[parent[1:]] = True
        inconsistent = np.flatnonzero(is_leaf == has_child)
        if len(inconsistent):
            i = int(inconsistent[0])
            raise D2SlamError(f"node {i} is {'a leaf with children' if is_leaf[i] else 'an inner node without children'}",
                              path=path, line=i + 1 if i else 1)
        return cls(k=k, L=L, parent=parent, descriptors=desc, is_leaf=is_leaf, weight=weight, scoring=scoring,
                   weighting=weighting)
