"""YOLOv8n-seg person segmentation through onnxruntime (CPU), decoded in numpy.

The model (``d2slam.assets``: the shared folder or the cache): input ``images`` float32 NCHW RGB in [0, 1] of a fixed size; output
``output0`` [1, 4 + nc + nm, N] = box (cx, cy, w, h in input pixels), nc class scores (already sigmoid), nm mask
coefficients; output ``output1`` [1, nm, H/4, W/4] mask prototypes.

Per frame (``OnnxSegmenter.segment``):
1. preprocess: resize the frame to the model input, each axis scaled on its own (no letterbox, no padding: a
   640x480 frame is scaled by 0.8 for the 384x512 file and by 0.5 for the 256x320 file; the 320x320 int8 file
   gets 0.5 x 0.667), RGB / 255, NCHW;
2. inference (onnxruntime, CPU provider, explicit threads and graph optimisation);
3. decode (vectorised numpy, no loop over proposals): keep proposals whose best class is person (class 0) and whose
   person score exceeds ``score_threshold`` (the Ultralytics ``classes=[0]`` rule), NMS (``cv2.dnn.NMSBoxes``)
   at ``nms_iou``, at most ``max_persons``; boxes scaled back to frame pixels;
4. masks: ``sigmoid(coefficients . prototypes)`` for the kept persons (one matrix product), upsampled to the frame
   in one ``cv2.resize`` call (instances as channels), cropped to each box (broadcast comparison),
   thresholded at ``mask_threshold``, optionally dilated by ``dilation_px``.

Grey (2-D or HxWx1) frames are converted to RGB by replicating the channel and RGBA frames lose their alpha
(documented recovery); any frame size works (the input is resized per axis; masks come back at frame size).
"""

from __future__ import annotations

import os
import time
import warnings
from dataclasses import asdict
from pathlib import Path

import cv2
import numpy as np
import onnxruntime as ort

from d2slam.assets import DERIVED, DOWNLOADS, assets_cache, find
from d2slam.cachefiles import sha256_file
from d2slam.errors import D2SlamError
from d2slam.segmentation.base import PersonInstance
from d2slam.segmentation.config import NOT_IN_KEY, SegmentationConfig

MODEL_ENV = "D2SLAM_SEG_MODEL"
ALLOW_UNKNOWN_ENV = "D2SLAM_SEG_ALLOW_UNKNOWN"
DEFAULT_MODEL_NAME = "yolov8n-seg_deq_384x512.onnx"
# Version of the decoding below: part of the mask-cache key, bump when decoding changes masks.
DECODER_VERSION = 1

#: sha256 -> file name of the three YOLOv8n-seg files (``d2slam.assets``).
KNOWN_MODELS: dict[str, str] = {a.sha256: Path(a.path).name for a in (*DOWNLOADS, *DERIVED)
                                if a.path.startswith("models/")}

HOW_TO_GET_A_MODEL = (
    "Run `d2slam assets fetch` (which `make test` and `make demo` run) to put the YOLOv8n-seg ONNX files in the cache "
    "($D2SLAM_CACHE/assets/models/; the shared folder $D2SLAM_SHARED/models/ is read too); nothing is downloaded at "
    f"run time. To use another copy set ${MODEL_ENV}=/path/to/model.onnx (`d2slam segment` and `d2slam bench "
    "segmentation` also take --model). To export one yourself with Ultralytics: "
    "`pip install ultralytics && yolo export model=yolov8n-seg.pt format=onnx imgsz=384,512`, then set "
    f"${MODEL_ENV} to the exported file; a file whose sha256 is not one of the three known files needs "
    f"${ALLOW_UNKNOWN_ENV}=1 (or `d2slam segment --allow-unknown-model`)."
)

_SHA_CACHE: dict[tuple[str, int, int], str] = {}


def default_model_path() -> Path:
    """``$D2SLAM_SEG_MODEL``, else the 384x512 file of the shared folder or the cache (``d2slam.assets.find``);
    when neither holds it, its would-be place in the cache (``check_model`` then says how to fetch it)."""
    env = os.environ.get(MODEL_ENV)
    if env:
        return Path(env).expanduser()
    rel = f"models/{DEFAULT_MODEL_NAME}"
    return find(rel) or assets_cache() / rel


def file_sha256(path: str | Path) -> str:
    """sha256 of a file (memoised per path, size and mtime)."""
    path = Path(path)
    st = path.stat()
    key = (str(path.resolve()), st.st_size, st.st_mtime_ns)
    if key not in _SHA_CACHE:
        _SHA_CACHE[key] = sha256_file(path)
    return _SHA_CACHE[key]


def check_model(path: str | Path | None = None, allow_unknown: bool | None = None) -> tuple[Path, str]:
    """Resolve the model path and verify its sha256 against ``KNOWN_MODELS``.

    A missing file raises ``D2SlamError`` explaining how to obtain or export one. A file with an unknown hash raises
    unless ``allow_unknown`` (default: ``$D2SLAM_SEG_ALLOW_UNKNOWN`` = 1) is set, in which case it is used with a
    warning. Returns ``(path, sha256)``.
    """
    path = Path(path).expanduser() if path is not None else default_model_path()
    if allow_unknown is None:
        allow_unknown = os.environ.get(ALLOW_UNKNOWN_ENV, "") not in ("", "0")
    if not path.is_file():
        raise D2SlamError(f"segmentation model not found. {HOW_TO_GET_A_MODEL}", path=path)
    digest = file_sha256(path)
    if digest not in KNOWN_MODELS:
        if not allow_unknown:
            raise D2SlamError(
                f"unknown model file (sha256 {digest[:16]}...) is not one of the known YOLOv8n-seg files "
                f"({', '.join(sorted(KNOWN_MODELS.values()))}); it may be corrupt or truncated. To use your own "
                f"export anyway set {ALLOW_UNKNOWN_ENV}=1 (`d2slam segment` also takes --allow-unknown-model). "
                f"{HOW_TO_GET_A_MODEL}",
                path=path,
            )
        warnings.warn(f"{path}: model sha256 {digest[:16]}... is not a known YOLOv8n-seg file; using it anyway "
                      "(allow_unknown)", stacklevel=2)
    return path, digest


def as_rgb(image: np.ndarray, path: str | Path | None = None) -> np.ndarray:
    """HxWx3 uint8 RGB from a frame. Grey (HxW or HxWx1) is replicated to three channels, RGBA loses alpha;
    anything else (empty, float, 16-bit, other channel counts) is a ``D2SlamError``."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        raise D2SlamError(f"expected an 8-bit image, got dtype {img.dtype}", path=path)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    elif img.ndim == 3 and img.shape[2] == 4:
        img = img[:, :, :3]
    if img.ndim != 3 or img.shape[2] != 3:
        raise D2SlamError(f"expected an HxW grey or HxWx3 RGB image, got shape {img.shape}", path=path)
    if img.shape[0] < 2 or img.shape[1] < 2:
        raise D2SlamError(f"image is empty or too small: shape {img.shape}", path=path)
    return img


def read_rgb(path: str | Path) -> np.ndarray:
    """Read an image file as HxWx3 uint8 RGB (grey images replicated), ``D2SlamError`` when unreadable."""
    path = Path(path)
    if not path.is_file():
        raise D2SlamError("image not found", path=path)
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise D2SlamError("cannot read image (not an image file, or corrupt)", path=path)
    if img.dtype != np.uint8:
        raise D2SlamError(f"expected an 8-bit image, got {img.dtype}", path=path)
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    elif img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    return as_rgb(img, path)


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-x))


class OnnxSegmenter:
    """YOLOv8n-seg persons through onnxruntime. ``segmenter(frame)`` or ``segmenter.segment(rgb)`` ->
    ``list[PersonInstance]`` sorted by decreasing score. ``timings`` holds the last call's
    (preprocess, inference, postprocess) seconds."""

    name = "onnx"

    def __init__(self, model_path: str | Path | None = None, config: SegmentationConfig | None = None,
                 allow_unknown_model: bool | None = None):
        self.config = config or SegmentationConfig()
        self.model_path, self.sha256 = check_model(model_path, allow_unknown_model)
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = int(self.config.intra_op_threads)
        opts.inter_op_num_threads = 1
        opts.add_session_config_entry("session.intra_op.allow_spinning", "1" if self.config.allow_spinning else "0")
        opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        opts.log_severity_level = 3
        try:
            self.session = ort.InferenceSession(str(self.model_path), sess_options=opts,
                                                providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own exception types for corrupt/invalid files
            raise D2SlamError(f"cannot load the ONNX model (corrupt or not an ONNX file): "
                              f"{type(exc).__name__}: {str(exc).splitlines()[0][:200]}. {HOW_TO_GET_A_MODEL}",
                              path=self.model_path) from None
        inputs, outputs = self.session.get_inputs(), self.session.get_outputs()
        shape = inputs[0].shape if inputs else None
        if (len(inputs) != 1 or len(outputs) != 2 or len(shape) != 4 or shape[1] != 3
                or not all(isinstance(s, int) and s > 0 for s in shape[2:])):
            raise D2SlamError("not a YOLOv8-seg model with a fixed 1x3xHxW input and two outputs "
                              f"(inputs {[(i.name, i.shape) for i in inputs]}, outputs "
                              f"{[(o.name, o.shape) for o in outputs]})", path=self.model_path)
        self.input_name = inputs[0].name
        # The 3-D output holds the proposals, the 4-D one the prototypes (in either order).
        ranks = sorted((len(o.shape), o.name) for o in outputs)
        if [r for r, _ in ranks] != [3, 4]:
            raise D2SlamError(f"expected a 3-D proposal output and a 4-D prototype output, got "
                              f"{[(o.name, o.shape) for o in outputs]}", path=self.model_path)
        self.output_names = [name for _, name in ranks]
        self.input_hw = (int(shape[2]), int(shape[3]))
        self.timings = (0.0, 0.0, 0.0)

    # ------------------------------------------------------------------------------------------------
    def identity(self) -> dict:
        """Everything that changes the masks: the mask-cache key."""
        cfg = asdict(self.config)
        for key in NOT_IN_KEY:
            cfg.pop(key, None)
        return {"kind": self.name, "model_sha256": self.sha256, "decoder": DECODER_VERSION, "config": cfg}

    def __call__(self, frame) -> list[PersonInstance]:
        if isinstance(frame, np.ndarray):
            return self.segment(frame)
        return self.segment(frame.rgb, path=getattr(frame, "rgb_path", None))

    def preprocess(self, rgb: np.ndarray) -> np.ndarray:
        """Per-axis resize to the model input (no padding), [0, 1] float32 NCHW."""
        h_in, w_in = self.input_hw
        resized = cv2.resize(rgb, (w_in, h_in), interpolation=cv2.INTER_LINEAR)
        blob = resized.transpose(2, 0, 1)[None].astype(np.float32)
        blob *= np.float32(1.0 / 255.0)
        return blob

    def segment(self, image: np.ndarray, path: str | Path | None = None) -> list[PersonInstance]:
        t0 = time.perf_counter()
        rgb = as_rgb(image, path)
        blob = self.preprocess(rgb)
        t1 = time.perf_counter()
        try:
            out0, out1 = self.session.run(self.output_names, {self.input_name: blob})
        except Exception as exc:
            raise D2SlamError(f"onnxruntime failed: {type(exc).__name__}: {str(exc).splitlines()[0][:200]}",
                              path=self.model_path) from None
        t2 = time.perf_counter()
        persons = self.decode(out0, out1, rgb.shape[:2])
        self.timings = (t1 - t0, t2 - t1, time.perf_counter() - t2)
        return persons

    def decode(self, out0: np.ndarray, out1: np.ndarray, frame_hw: tuple[int, int]) -> list[PersonInstance]:
        """Raw model outputs -> persons at frame resolution (``decode_persons``)."""
        return decode_persons(out0, out1, frame_hw, self.input_hw, self.config, self.model_path)


def decode_persons(out0: np.ndarray, out1: np.ndarray, frame_hw: tuple[int, int], input_hw: tuple[int, int],
                   config: SegmentationConfig, model_path: str | Path | None = None) -> list[PersonInstance]:
    """YOLOv8-seg outputs -> persons at frame resolution, vectorised (steps 3-4 of the module docstring).

    ``out0`` [1, 4 + nc + nm, N], ``out1`` [1, nm, ph, pw]; ``frame_hw`` the frame size, ``input_hw`` the model
    input size (boxes are scaled per axis by frame / input). Returns instances by decreasing score.
    """
    cfg = config
    H, W = frame_hw
    h_in, w_in = input_hw
    protos = out1[0]  # (nm, ph, pw)
    nm = protos.shape[0]
    pred = out0[0]  # (4 + nc + nm, N)
    nc = pred.shape[0] - 4 - nm
    if nc < 1:
        raise D2SlamError(f"unexpected model output shapes {out0.shape} / {out1.shape}", path=model_path)
    cls = pred[4:4 + nc]
    person = cls[0]
    keep = (person > cfg.score_threshold) & (cls.argmax(axis=0) == 0)
    if not keep.any():
        return []
    idx = np.flatnonzero(keep)
    scores = person[idx].astype(np.float32)
    cx, cy, bw, bh = pred[0:4, idx]
    sx, sy = W / w_in, H / h_in
    boxes = np.stack([(cx - bw / 2) * sx, (cy - bh / 2) * sy, (cx + bw / 2) * sx, (cy + bh / 2) * sy], axis=1)
    boxes = np.clip(boxes, 0.0, [W, H, W, H]).astype(np.float32)
    xywh = np.column_stack([boxes[:, :2], boxes[:, 2:] - boxes[:, :2]])
    kept = np.asarray(cv2.dnn.NMSBoxes(xywh.tolist(), scores.tolist(), float(cfg.score_threshold),
                                       float(cfg.nms_iou)), dtype=np.int64).reshape(-1)
    kept = kept[np.argsort(-scores[kept], kind="stable")][: cfg.max_persons]
    if kept.size == 0:
        return []
    boxes, scores = boxes[kept], scores[kept]
    coeffs = pred[4 + nc:, idx[kept]].T  # (k, nm)
    k = len(kept)
    prob = _sigmoid(coeffs @ protos.reshape(nm, -1)).reshape(k, *protos.shape[1:])
    # All instances at once: channels-last, one bilinear resize to the frame.
    up = cv2.resize(np.ascontiguousarray(prob.transpose(1, 2, 0)), (W, H), interpolation=cv2.INTER_LINEAR)
    up = up.reshape(H, W, k)
    ys = np.arange(H, dtype=np.float32) + 0.5
    xs = np.arange(W, dtype=np.float32) + 0.5
    in_y = (ys[None, :] >= boxes[:, 1:2]) & (ys[None, :] <= boxes[:, 3:4])  # (k, H)
    in_x = (xs[None, :] >= boxes[:, 0:1]) & (xs[None, :] <= boxes[:, 2:3])  # (k, W)
    masks = np.ascontiguousarray((up.transpose(2, 0, 1) > cfg.mask_threshold) & in_y[:, :, None] & in_x[:, None, :])
    if cfg.dilation_px > 0:
        r = int(cfg.dilation_px)
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        dil = cv2.dilate(np.ascontiguousarray(masks.transpose(1, 2, 0)).astype(np.uint8), kernel)
        masks = np.ascontiguousarray(dil.reshape(H, W, k).transpose(2, 0, 1).astype(bool))
    return [PersonInstance(mask=m, score=float(s), box=tuple(float(v) for v in b))
            for m, s, b in zip(masks, scores, boxes)]
