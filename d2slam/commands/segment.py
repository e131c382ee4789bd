"""``d2slam segment``: person masks of images (printed, JSON, overlays) or of a whole sequence (into the cache)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import cv2

from d2slam.config import DEFAULT
from d2slam.errors import D2SlamError
from d2slam.outputs import check_output_dir, check_outputs, write_bytes
from d2slam.segmentation import CachedSegmenter, get_segmenter
from d2slam.segmentation.cache import RgbListSequence
from d2slam.segmentation.draw import overlay
from d2slam.segmentation.onnx import read_rgb


def register(sub) -> None:
    p = sub.add_parser(
        "segment", help="segment persons in images, or fill the mask cache of a sequence",
        description="`d2slam segment IMAGE...` prints, per image, the persons found by the YOLOv8n-seg ONNX model "
        "(score, box x0 y0 x1 y1 in pixels, mask area). `d2slam segment SEQUENCE_DIR` segments every image listed "
        "in the folder's rgb.txt into the mask cache (what `--masks onnx` runs read). The model is "
        "$D2SLAM_SEG_MODEL or the 384x512 file of the shared folder; its sha256 must be a known file unless "
        "--allow-unknown-model.")
    p.add_argument("inputs", nargs="+", metavar="IMAGE|SEQUENCE_DIR", help="image files, or one sequence folder")
    p.add_argument("--json", action="store_true", help="one JSON object per line and image, with a `persons` list")
    p.add_argument("--overlay", metavar="DIR", help="write <image stem>_persons.png overlays into DIR")
    p.add_argument("--model", metavar="PATH", help="ONNX model (default: $D2SLAM_SEG_MODEL or the shared 384x512)")
    p.add_argument("--allow-unknown-model", action="store_true",
                   help="use a model whose sha256 is not one of the known files (with a warning)")
    p.add_argument("--score", type=float, metavar="S", help="person score threshold (default: the config's)")
    p.set_defaults(func=run)


def run(args) -> int:
    cfg = DEFAULT.segmentation
    if args.score is not None:
        if not 0.0 < args.score < 1.0:
            raise D2SlamError(f"--score must be in (0, 1), got {args.score}")
        cfg = dataclasses.replace(cfg, score_threshold=args.score)

    paths = [Path(p) for p in args.inputs]
    dirs = [p for p in paths if p.is_dir()]
    if dirs and len(paths) > 1:
        raise D2SlamError("give either image files or one sequence folder", path=dirs[0])
    if args.overlay:
        check_output_dir(args.overlay, "--overlay")
        images = [("image", p) for p in paths]
        check_outputs([("--overlay", args.overlay)], images, folders=True)
        # one overlay per image: none of them an input, no two the same file (two images of one name)
        check_outputs([(f"the overlay of {p}", overlay_path(args.overlay, p)) for p in paths if not p.is_dir()],
                      images)
    segmenter = get_segmenter("onnx", config=cfg, model=args.model,
                              allow_unknown_model=True if args.allow_unknown_model else None)

    if dirs:
        seq = RgbListSequence(dirs[0])
        cached = CachedSegmenter(segmenter, seq)
        hits, misses = cached.fill()
        msg = {"sequence": str(dirs[0]), "frames": len(seq), "cached_before": hits, "segmented": misses,
               "recovered": cached.recovered, "cache": str(cached.dir)}
        print(json.dumps(msg) if args.json else
              f"{dirs[0]}: {len(seq)} frames, {hits} already cached, {misses} segmented"
              + (f", {cached.recovered} corrupt cache files recomputed" if cached.recovered else "")
              + f"\ncache: {cached.dir}")
        return 0

    out_dir = Path(args.overlay) if args.overlay else None
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
    for path in paths:
        rgb = read_rgb(path)
        persons = segmenter.segment(rgb, path=path)
        H, W = rgb.shape[:2]
        if out_dir is not None:
            target = overlay_path(out_dir, path)
            ok, png = cv2.imencode(".png", cv2.cvtColor(overlay(rgb, persons), cv2.COLOR_RGB2BGR))
            if not ok:
                raise D2SlamError("cannot encode the overlay", path=target)
            write_bytes(target, png.tobytes())
        if args.json:
            print(json.dumps({"image": str(path), "width": W, "height": H, "model": segmenter.model_path.name,
                              "persons": [{"score": round(p.score, 4), "box": [round(v, 1) for v in p.box],
                                           "area": p.area} for p in persons]}))
        else:
            print(f"{path}: {len(persons)} person{'s' if len(persons) != 1 else ''}")
            for i, p in enumerate(persons, 1):
                x0, y0, x1, y1 = p.box
                print(f"  {i}: score {p.score:.2f}  box {x0:.0f} {y0:.0f} {x1:.0f} {y1:.0f}  "
                      f"area {p.area} px ({100 * p.area / (H * W):.1f} %)")
    return 0


def overlay_path(out_dir, image) -> Path:
    """Where ``--overlay DIR`` puts the overlay of ``image``: ``DIR/<image stem>_persons.png``."""
    return Path(out_dir) / f"{Path(image).stem}_persons.png"
