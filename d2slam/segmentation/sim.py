"""Segmenters that read a synthetic sequence's label images instead of running a model.

* ``sim``: ``mask_sim/<stem>.png``, the simulated segmenter output (person instances labelled 1..n, 0 = none);
* ``gt``: ``mask_gt/<stem>.png``, the ground-truth object ids, of which the ``person_ids`` of ``scene.json`` are
  persons (one instance per person id present in the frame);
* ``truth``: the same ``mask_gt/`` with one instance per *dynamic* id of the frame (every person, and a moved object
  during its moving intervals: ``SyntheticSequence.dynamic_ids``), i.e. exactly the keypoint truth of
  ``d2slam.eval.keypoints``. Not a segmenter anyone could have: it feeds the ``oracle`` upper bound and "what if the
  masks were perfect" runs (``--masks truth``).

``<stem>`` is the RGB file's stem (its timestamp); format in CONTRIBUTING.md. ``instances(i)`` (what
``masks_for`` and ``CachedSegmenter`` call) uses the reader's ``person_masks_sim(i)`` / ``person_masks_gt(i)``
((n, H, W) bool, ``d2slam.data.synthetic.SyntheticSequence``) when the sequence has them; ``__call__(frame)`` reads
the label image named by ``frame.rgb_path``'s stem under the sequence root (same files, same instances).
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from d2slam.errors import D2SlamError
from d2slam.segmentation.base import PersonInstance


def boxes_of_masks(masks: np.ndarray) -> np.ndarray:
    """(k, 4) float32 boxes x0, y0, x1, y1 (x1, y1 exclusive pixel edges) of (k, H, W) non-empty bool masks."""
    k, H, W = masks.shape
    rows, cols = masks.any(axis=2), masks.any(axis=1)
    y0, x0 = rows.argmax(axis=1), cols.argmax(axis=1)
    y1, x1 = H - rows[:, ::-1].argmax(axis=1), W - cols[:, ::-1].argmax(axis=1)
    return np.stack([x0, y0, x1, y1], axis=1).astype(np.float32)


def instances_from_masks(masks: np.ndarray, score: float = 1.0) -> list[PersonInstance]:
    """(k, H, W) bool masks -> instances (empty masks dropped), boxes from the masks, a fixed score."""
    masks = np.asarray(masks, dtype=bool)
    if masks.ndim != 3:
        raise D2SlamError(f"expected (k, H, W) masks, got shape {masks.shape}")
    masks = masks[masks.any(axis=(1, 2))]
    boxes = boxes_of_masks(masks)
    return [PersonInstance(mask=m, score=float(score), box=tuple(float(v) for v in b)) for m, b in zip(masks, boxes)]


def instances_from_labels(labels: np.ndarray, ids: np.ndarray | None = None, score: float = 1.0
                          ) -> list[PersonInstance]:
    """Label image (H, W) -> one instance per id in ``ids`` present in the image (default: every nonzero label)."""
    labels = np.asarray(labels)
    present = np.unique(labels)
    present = present[present != 0]
    if ids is not None:
        present = present[np.isin(present, np.asarray(ids))]
    masks = labels[None, :, :] == present[:, None, None]
    return instances_from_masks(masks, score)


def read_label_png(path: Path) -> np.ndarray:
    if not path.is_file():
        raise D2SlamError("mask image not found", path=path)
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise D2SlamError("cannot read mask image (corrupt or not a PNG)", path=path)
    if img.ndim != 2:
        raise D2SlamError(f"mask image must be single-channel, got shape {img.shape}", path=path)
    return img


class LabelSegmenter:
    """``sim``, ``gt`` or ``truth`` instances of a synthetic sequence (see the module docstring)."""

    cacheable = False  # reading a label PNG is as cheap as reading a cache file

    def __init__(self, sequence, kind: str = "sim"):
        if kind not in ("sim", "gt", "truth"):
            raise D2SlamError(f"label segmenter kind must be 'sim', 'gt' or 'truth', got {kind!r}")
        if sequence is None:
            raise D2SlamError(f"the '{kind}' segmenter needs a synthetic sequence (mask_{kind}/ and scene.json)")
        self.name = kind
        self.sequence = sequence
        self.root = Path(getattr(sequence, "root", sequence))
        self.folder = self.root / ("mask_sim" if kind == "sim" else "mask_gt")
        if not self.folder.is_dir():
            raise D2SlamError(f"no {self.folder.name}/ folder: the '{kind}' masks exist only for synthetic sequences "
                              "(`d2slam synth`); use --masks onnx for real data", path=self.folder)
        if kind == "truth" and not callable(getattr(sequence, "dynamic_ids", None)):
            raise D2SlamError("the 'truth' masks need the synthetic reader (d2slam.data.synthetic: dynamic_ids)",
                              path=self.root)
        self.person_ids = self._person_ids() if kind == "gt" else None

    def _person_ids(self) -> np.ndarray:
        path = self.root / "scene.json"
        if not path.is_file():
            raise D2SlamError("scene.json not found (needed for the person ids of mask_gt/)", path=path)
        try:
            scene = json.loads(path.read_text())
            return np.asarray(scene["person_ids"], dtype=np.int64)
        except (ValueError, KeyError, TypeError) as exc:
            raise D2SlamError(f"cannot read person_ids: {exc}", path=path) from None

    def identity(self) -> dict:
        return {"kind": self.name}

    def labels_for_stem(self, stem: str) -> np.ndarray:
        return read_label_png(self.folder / f"{stem}.png")

    def __call__(self, frame) -> list[PersonInstance]:
        rgb_path = getattr(frame, "rgb_path", None)
        if rgb_path is None:
            raise D2SlamError(f"the '{self.name}' segmenter needs frames that know their RGB file (rgb_path)")
        labels = self.labels_for_stem(Path(rgb_path).stem)
        shape = getattr(frame, "rgb", labels).shape[:2]
        if labels.shape != shape:
            raise D2SlamError(f"mask size {labels.shape} differs from the frame's {shape}",
                              path=self.folder / f"{Path(rgb_path).stem}.png")
        ids = self.sequence.dynamic_ids(frame.index) if self.name == "truth" else self.person_ids
        return instances_from_labels(labels, ids)

    def instances(self, index: int) -> list[PersonInstance]:
        """Persons of frame ``index``, through the reader's ``person_masks_<kind>(i)`` when it has one (``truth``:
        the reader's ``mask_gt(i)`` restricted to its ``dynamic_ids(i)``)."""
        if self.name == "truth":
            return instances_from_labels(self.sequence.mask_gt(index), self.sequence.dynamic_ids(index))
        reader = getattr(self.sequence, f"person_masks_{self.name}", None)
        if reader is not None:
            out = reader(index)
            if isinstance(out, np.ndarray) and out.ndim == 2:  # a label image
                return instances_from_labels(out, self.person_ids)
            if isinstance(out, np.ndarray):  # (k, H, W) masks
                return instances_from_masks(out)
            return instances_from_masks(np.asarray(list(out)).reshape(-1, *np.shape(out[0])) if len(out) else
                                        np.zeros((0, 1, 1), bool))
        return self(self.sequence[index])
