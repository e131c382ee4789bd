"""Synthetic TUM-like sequences written by ``d2slam synth``: a TUM folder plus masks and ``scene.json``.

Format (CONTRIBUTING.md, "Synthetic sequence format")::

    ROOT/rgb/ depth/ rgb.txt depth.txt groundtruth.txt    exactly the TUM layout (read by TumSequence)
    ROOT/mask_gt/<stem>.png    uint8 per-pixel object id (0 = static scene), <stem> = the RGB file's stem
    ROOT/mask_sim/<stem>.png   uint8 simulated segmenter output, person instances 1..n (0 = no person)
    ROOT/scene.json            format "d2slam-synth/2", scenario, seed, frames, static_twin, camera {fx, fy, cx,
                               cy, width, height, depth_factor [, dist, bf]}, objects [{id, kind, name, moved,
                               moving_intervals [[t0, t1], ...]}], person_ids, moved_object_ids, generator

Keypoint truth (:meth:`SyntheticSequence.dynamic_mask`): a pixel is dynamic when its ``mask_gt`` id is a person,
or a moved object's id while the frame's RGB timestamp lies in one of that object's moving intervals
(``t0 <= t <= t1``, both ends included).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np

from d2slam.data.base import Camera
from d2slam.data.tum import DEFAULT_MAX_DT, TumSequence
from d2slam.errors import D2SlamError

SCENE_FORMAT = "d2slam-synth/2"
OLD_FORMATS = ("d2slam-synth/1",)


class SyntheticSequence(TumSequence):
    """A ``d2slam synth`` sequence: everything of :class:`TumSequence` plus ground-truth and simulated masks.

    The camera comes from ``scene.json`` unless ``camera`` is given. Attributes from the scene: ``scene`` (the
    parsed JSON), ``scenario``, ``seed``, ``static_twin``, ``objects`` (id -> object dict), ``person_ids``,
    ``moved_object_ids`` (sorted int arrays), ``moving_intervals`` (id -> (k, 2) array of [t0, t1]).
    """

    def __init__(self, root: str | Path, camera: Camera | str | None = None, max_dt: float = DEFAULT_MAX_DT,
                 offset: float = 0.0):
        root = Path(root).expanduser()
        self.scene_path = root / "scene.json"
        if root.is_dir() and not self.scene_path.is_file():
            raise D2SlamError("scene.json not found: not a d2slam synthetic sequence (use TumSequence)",
                              path=self.scene_path)
        self._explicit_camera = camera
        if root.is_dir():
            self._parse_scene()
        super().__init__(root, camera=camera, max_dt=max_dt, offset=offset)

    # -- scene.json -------------------------------------------------------------------------------------------
    def _scene_error(self, message: str) -> D2SlamError:
        return D2SlamError(message, path=self.scene_path)

    def _parse_scene(self) -> None:
        try:
            scene = json.loads(self.scene_path.read_text())
        except json.JSONDecodeError as exc:
            raise D2SlamError(f"invalid JSON: {exc.msg}", path=self.scene_path, line=exc.lineno) from None
        except (OSError, UnicodeDecodeError) as exc:
            raise self._scene_error(f"cannot read: {exc}") from None
        if not isinstance(scene, dict):
            raise self._scene_error("expected a JSON object")
        if scene.get("format") in OLD_FORMATS:
            raise self._scene_error(
                f"this sequence was written by the old generator (format {scene['format']!r}: box people, texture "
                f"collage room); the reader needs {SCENE_FORMAT!r}: regenerate it with `d2slam synth SCENARIO --out "
                f"{self.scene_path.parent}` (same scenario, --frames and --seed)")
        if scene.get("format") != SCENE_FORMAT:
            raise self._scene_error(f"format is {scene.get('format')!r}, expected {SCENE_FORMAT!r}")
        for key in ("camera", "objects", "person_ids", "moved_object_ids"):
            if key not in scene:
                raise self._scene_error(f"missing key {key!r}")
        self.scene = scene
        self.scenario = scene.get("scenario")
        self.seed = scene.get("seed")
        self.static_twin = bool(scene.get("static_twin", False))
        self._scene_camera = self._camera_from_scene(scene["camera"])
        objects, intervals = self._objects(scene["objects"])
        persons = sorted(oid for oid, o in objects.items() if o["kind"] == "person")
        moved = sorted(oid for oid, o in objects.items() if o["kind"] == "object" and o.get("moved"))
        if sorted(scene["person_ids"]) != persons:
            raise self._scene_error(f"person_ids {scene['person_ids']} disagree with the objects of kind "
                                    f"'person' {persons}")
        if sorted(scene["moved_object_ids"]) != moved:
            raise self._scene_error(f"moved_object_ids {scene['moved_object_ids']} disagree with the objects "
                                    f"of kind 'object' with moved=true {moved}")
        self.objects = objects
        self.moving_intervals = intervals
        self.person_ids = np.asarray(persons, dtype=np.int64)
        self.moved_object_ids = np.asarray(moved, dtype=np.int64)
        self._known_lut = np.zeros(256, dtype=bool)
        self._known_lut[0] = True
        self._known_lut[list(objects)] = True
        self._person_lut = np.zeros(256, dtype=bool)
        self._person_lut[self.person_ids] = True

    def _objects(self, listed) -> tuple[dict[int, dict], dict[int, np.ndarray]]:
        """``scene.json``'s objects by id (each checked: an id in 1..255 listed once, a kind, finite moving intervals)
        and each one's moving intervals (K, 2)."""
        objects: dict[int, dict] = {}
        intervals: dict[int, np.ndarray] = {}
        if not isinstance(listed, list):
            raise self._scene_error("'objects' must be a list")
        for k, obj in enumerate(listed):
            if not isinstance(obj, dict) or "id" not in obj or "kind" not in obj:
                raise self._scene_error(f"objects[{k}] must be an object with 'id' and 'kind'")
            oid = obj["id"]
            if not isinstance(oid, int) or isinstance(oid, bool) or not 1 <= oid <= 255:
                raise self._scene_error(f"objects[{k}] id {oid!r} is not an integer in 1..255 (uint8 mask ids)")
            if oid in objects:
                raise self._scene_error(f"objects[{k}] id {oid} is listed twice")
            if obj["kind"] not in ("person", "object"):
                raise self._scene_error(f"objects[{k}] kind {obj['kind']!r} is not 'person' or 'object'")
            iv = obj.get("moving_intervals") or []
            try:
                arr = np.asarray(iv, dtype=np.float64).reshape(-1, 2)
            except (TypeError, ValueError):
                raise self._scene_error(f"objects[{k}] moving_intervals must be a list of [t0, t1]") from None
            if not np.isfinite(arr).all() or (arr[:, 1] < arr[:, 0]).any():
                raise self._scene_error(f"objects[{k}] moving_intervals must be finite with t0 <= t1")
            objects[oid] = obj
            intervals[oid] = arr
        return objects, intervals

    def _camera_from_scene(self, cam) -> Camera:
        if not isinstance(cam, dict):
            raise self._scene_error("'camera' must be an object")
        missing = [k for k in ("fx", "fy", "cx", "cy", "width", "height", "depth_factor") if k not in cam]
        if missing:
            raise self._scene_error(f"camera lacks {', '.join(missing)}")
        try:
            kwargs = {k: float(cam[k]) for k in ("fx", "fy", "cx", "cy", "depth_factor")}
            kwargs.update(width=int(cam["width"]), height=int(cam["height"]))
            if "bf" in cam:
                kwargs["bf"] = float(cam["bf"])
            if "dist" in cam:
                dist = tuple(float(c) for c in cam["dist"])
                if len(dist) != 5:
                    raise ValueError("dist needs 5 coefficients")
                kwargs["dist"] = dist
        except (TypeError, ValueError) as exc:
            raise self._scene_error(f"bad camera values: {exc}") from None
        if not all(math.isfinite(v) for v in kwargs.values() if isinstance(v, float)) or min(
                kwargs["fx"], kwargs["fy"], kwargs["depth_factor"], kwargs["width"], kwargs["height"]) <= 0:
            raise self._scene_error("camera fx, fy, depth_factor, width, height must be positive and finite")
        return Camera(name=str(cam.get("name", "synthetic")), **kwargs)

    def _load_camera(self, camera: Camera | str | None) -> Camera:
        """The scene's camera; an explicit ``camera`` must agree with it (any intrinsic, size or depth factor that
        differs is an error: the images were rendered with the scene's camera)."""
        if camera is None:
            return self._scene_camera
        given = super()._load_camera(camera)
        own = self._scene_camera
        differ = [f for f in ("fx", "fy", "cx", "cy", "width", "height", "dist", "depth_factor", "bf")
                  if not np.allclose(getattr(given, f), getattr(own, f), rtol=1e-6, atol=1e-9)]
        if differ:
            raise D2SlamError(f"camera {given.name!r} conflicts with this synthetic sequence's own camera "
                              f"(scene.json) in {', '.join(differ)}: "
                              + ", ".join(f"{f} {getattr(given, f)} vs {getattr(own, f)}" for f in differ[:3])
                              + "; drop --camera (synthetic sequences carry their camera)", path=self.root)
        return own

    # -- masks ------------------------------------------------------------------------------------------------
    def _check_index(self, index: int) -> int:
        index = int(index)
        if index < 0:
            index += len(self)
        if not 0 <= index < len(self):
            raise IndexError(f"frame {index} out of range for {len(self)} frames")
        return index

    def _read_mask(self, folder: str, index: int) -> np.ndarray:
        index = self._check_index(index)
        path = self.root / folder / (self.rgb_files[index].stem + ".png")
        if not path.is_file():
            raise D2SlamError(f"mask of frame {index} (t={self.timestamps[index]:.6f}) not found", path=path)
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise D2SlamError("mask cannot be decoded (corrupt or truncated PNG?)", path=path)
        shape = (self.camera.height, self.camera.width)
        if img.dtype != np.uint8 or img.shape != shape:
            raise D2SlamError(f"mask must be a {shape[1]}x{shape[0]} uint8 single-channel PNG, got dtype "
                              f"{img.dtype} shape {img.shape}", path=path)
        return img

    def mask_gt(self, index: int) -> np.ndarray:
        """(H, W) uint8 object ids of frame ``index`` (0 = static scene). Ids not in scene.json are an error."""
        mask = self._read_mask("mask_gt", index)
        known = self._known_lut[mask]
        if not known.all():
            bad = np.unique(mask[~known])
            raise D2SlamError(f"ids {bad.tolist()} are not objects of scene.json",
                              path=self.root / "mask_gt" / (self.rgb_files[self._check_index(index)].stem + ".png"))
        return mask

    def mask_sim(self, index: int) -> np.ndarray:
        """(H, W) uint8 simulated segmenter labels of frame ``index``: person instances 1..n, 0 = no person."""
        return self._read_mask("mask_sim", index)

    @staticmethod
    def _split(mask: np.ndarray, labels: np.ndarray) -> np.ndarray:
        return mask[None, :, :] == labels.astype(mask.dtype)[:, None, None]

    def person_masks_gt(self, index: int, return_ids: bool = False):
        """(n, H, W) bool: one mask per person visible in frame ``index`` (ascending person id; persons absent
        from the frame are left out). With ``return_ids``, also the (n,) person ids."""
        mask = self.mask_gt(index)
        present = np.flatnonzero(np.bincount(mask.ravel(), minlength=256) > 0)
        ids = present[self._person_lut[present]]
        masks = self._split(mask, ids)
        return (masks, ids) if return_ids else masks

    def person_masks_sim(self, index: int, return_labels: bool = False):
        """(n, H, W) bool: the simulated segmenter's person instances of frame ``index`` (ascending label, empty
        labels left out). With ``return_labels``, also the (n,) labels."""
        mask = self.mask_sim(index)
        present = np.flatnonzero(np.bincount(mask.ravel(), minlength=256) > 0)
        labels = present[present > 0]
        masks = self._split(mask, labels)
        return (masks, labels) if return_labels else masks

    def dynamic_ids(self, index: int) -> np.ndarray:
        """Ids that are dynamic at frame ``index``: every person, and every moved object whose moving intervals
        contain the frame's RGB timestamp (ends included)."""
        t = self.timestamps[self._check_index(index)]
        moving = [oid for oid in self.moved_object_ids.tolist()
                  if np.any((self.moving_intervals[oid][:, 0] <= t) & (t <= self.moving_intervals[oid][:, 1]))]
        return np.asarray(sorted(self.person_ids.tolist() + moving), dtype=np.int64)

    def dynamic_labels(self, index: int) -> np.ndarray:
        """(H, W) uint8 truth of frame ``index``: 1 where the gt id is a person, 2 where it is a moved object during
        one of its moving intervals at the frame's RGB timestamp, 0 elsewhere."""
        lut = np.zeros(256, dtype=np.uint8)
        lut[self.dynamic_ids(index)] = 2
        lut[self.person_ids] = 1
        return lut[self.mask_gt(index)]

    def dynamic_mask(self, index: int) -> np.ndarray:
        """(H, W) bool truth of frame ``index``: a person, or a moved object while it moves (``dynamic_labels``)."""
        return self.dynamic_labels(index) > 0
