"""Are the people composited into a real recording seen as the synthetic office's are? The real segmenter on both
(``d2slam bench realism --composite SEQ``; docs/real_people.md).

For every ``stride``-th frame of a composite (``d2slam synth real_walking --on TUM_DIR``) with somebody in it, and
of the synthetic office's walking scenarios (rendered in memory, ``d2slam.eval.segmentation.synthetic_rows``), one
row per visible person: its share of the image, its median depth, the best IoU of the segmenter's masks with its
truth mask (``mask_gt``), and the camera's roll (the angle between the world's up and the image's up: fr1/rpy rolls
up to about 50 degrees, the fr3 walking sequences hardly). A composite's person depth is read where its depth image
shows that person (``mask_depth``: the depth is taken at another instant than the colour).

The same frames are also segmented *upright*: turned about the image centre by the roll (onto a canvas that holds the
whole turned image), the masks turned back: what the segmenter makes of the same people without the camera's roll;
and *isolated*: upright, every pixel outside the objects' truth masks grey: the people without the background.

The comparison at matched distance and coverage (:func:`matched`): the office's people weighted so that their
histogram over (depth bin, area bin) is the composite's.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from d2slam.eval.segmentation import frame_rows, person_ious
from d2slam.synth.generate import render_frame
from d2slam.synth.realism import sample_indices
from d2slam.synth.scene import Scene
from d2slam.synth.world import WorldRenderer

AREA_BINS = (0.03, 0.06, 0.12, 0.25)  # image share bins of the matched comparison (inner edges)


def roll_deg(T_world_camera: np.ndarray) -> float:
    """The camera's roll (degrees): the angle from the image's up to the world's up (+Z) seen in the image,
    positive when the world's up leans to the image's right."""
    up = np.asarray(T_world_camera, float)[:3, :3].T @ np.array([0.0, 0.0, 1.0])
    return float(np.degrees(np.arctan2(up[0], -up[1])))


def upright_masks(segmenter, rgb: np.ndarray, roll: float) -> list[np.ndarray]:
    """The segmenter's person masks of ``rgb`` turned by ``roll`` degrees (so that the world's up is the image's up)
    on a canvas holding the whole turned image, turned back into ``rgb``'s pixels."""
    H, W = rgb.shape[:2]
    side = int(np.ceil(np.hypot(H, W)))
    c = np.array([W / 2.0, H / 2.0])
    A = cv2.getRotationMatrix2D((float(c[0]), float(c[1])), float(roll), 1.0)
    A[:, 2] += np.array([side / 2.0, side / 2.0]) - c  # the image centre to the canvas centre
    turned = cv2.warpAffine(rgb, A, (side, side), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                            borderValue=(114, 114, 114))
    back = cv2.invertAffineTransform(A)
    out = []
    for p in segmenter(turned):
        m = cv2.warpAffine(p.mask.astype(np.uint8), back, (W, H), flags=cv2.INTER_NEAREST,
                           borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        out.append(m > 0)
    return out


def _variants(segmenter, rgb, ids, people: list[dict], roll: float) -> None:
    """``iou_upright`` and ``iou_isolated`` of each row of ``people`` (module docstring), in place."""
    if not people:
        return
    pids = [r["id"] for r in people]
    grey = rgb.copy()
    grey[ids == 0] = 128
    for key, img in (("iou_upright", rgb), ("iou_isolated", grey)):
        iou = person_ious(ids, pids, upright_masks(segmenter, img, roll))
        for r, row in zip(people, iou):
            r[key] = float(row.max()) if row.size else 0.0


def composite_rows(seq, segmenter, stride: int = 5, upright: bool = True) -> list[dict]:
    """One row per person visible in every ``stride``-th frame of the composite ``seq`` (a ``SyntheticSequence``):
    ``frame``, ``id``, ``area``, ``depth`` (median of its pixels in the depth image), ``iou`` (the segmenter on the
    frame), ``iou_upright`` (on the frame turned upright; with ``upright``), ``roll`` (degrees)."""
    rows = []
    pids = [int(p) for p in seq.person_ids]
    for i in tqdm(range(0, len(seq), int(stride)), desc="segment composite", unit="frame", disable=None):
        ids = seq.mask_gt(i)
        if not np.isin(ids, pids).any():
            continue
        f = seq[i]
        md = cv2.imread(str(Path(seq.root) / "mask_depth" / Path(seq.depth_files[i]).name), cv2.IMREAD_UNCHANGED)
        zmap = np.zeros(ids.shape, np.float32)
        for pid in pids:  # each person's depth where the depth image shows it, spread over its colour mask
            z = f.depth[(md == pid) & (f.depth > 0)] if md is not None else np.zeros(0)
            zmap[ids == pid] = float(np.median(z)) if z.size else np.nan
        masks = [p.mask for p in segmenter(f.rgb)]
        roll = roll_deg(seq.gt_pose(f.timestamp))
        people = frame_rows(ids, zmap, pids, masks)
        if upright:
            _variants(segmenter, f.rgb, ids, people, roll)
        rows += [dict(r, frame=i, roll=roll) for r in people]
    return rows


def office_rows(scenarios, seeds, frames: int, stride: int, segmenter, config, upright: bool = True) -> list[dict]:
    """The synthetic office's rows as :func:`composite_rows` gives a composite's, for ``scenarios`` x ``seeds``
    (rendered in memory: ``d2slam.eval.segmentation.synthetic_rows``'s frames), with the roll and the upright IoU."""
    rows = []
    runs = [(s, int(seed)) for s in scenarios for seed in seeds]
    with tqdm(total=len(runs) * len(sample_indices(frames, stride)), desc="segment office", unit="frame",
              disable=None) as bar:
        for scenario, seed in runs:
            scene = Scene(scenario, seed, frames, False, config.synth)
            renderer = WorldRenderer(scene)
            try:
                for i in sample_indices(frames, stride):
                    f = render_frame(scene, renderer, int(i))
                    masks = [p.mask for p in segmenter(f["rgb"])]
                    roll = roll_deg(f["pose"])
                    people = frame_rows(f["mask_gt"], f["depth_clean"], scene.person_ids, masks)
                    if upright:
                        _variants(segmenter, f["rgb"], f["mask_gt"], people, roll)
                    rows += [dict(r, scenario=scenario, seed=seed, frame=int(i), roll=roll) for r in people]
                    bar.update()
            finally:
                renderer.close()
    return rows


def column(rows: list[dict], key: str) -> np.ndarray:
    return np.array([r.get(key, np.nan) for r in rows], float).reshape(-1)


def _bins(values: np.ndarray, edges) -> np.ndarray:
    return np.digitize(values, np.asarray(edges, float))


def matched(composite: list[dict], office: list[dict], depth_edges, key: str = "iou", min_area: float = 0.03,
            iou: float = 0.5) -> dict:
    """The office against the composite at matched distance and coverage, people of at least ``min_area``: each
    office person weighted by the composite's share of its (depth bin, area bin) over the office's; ``rate``
    (detected at IoU >= ``iou``) and mean ``key`` of both, over the cells both hold, and the composite's people in
    cells the office lacks (``unmatched``)."""
    def cells(rows):
        a, z = column(rows, "area"), column(rows, "depth")
        keep = (a >= min_area) & np.isfinite(z)
        return _bins(z, depth_edges) * 100 + _bins(a, AREA_BINS), keep

    cc, ck = cells(composite)
    oc, ok = cells(office)
    cv, ov = column(composite, key), column(office, key)
    weights = np.zeros(len(office))
    n_c = ck.sum()
    unmatched = 0
    for cell in np.unique(cc[ck]):
        nc = int(((cc == cell) & ck).sum())
        no = int(((oc == cell) & ok).sum())
        if no == 0:
            unmatched += nc
            continue
        weights[(oc == cell) & ok] = nc / no
    used = ck & np.isin(cc, oc[ok])
    w = weights / max(weights.sum(), 1e-12)
    return {"people": int(n_c), "unmatched": int(unmatched),
            "composite_rate": float((cv[used] >= iou).mean()) if used.any() else float("nan"),
            "composite_mean": float(cv[used].mean()) if used.any() else float("nan"),
            "office_rate": float((w * (ov >= iou)).sum()) if weights.sum() > 0 else float("nan"),
            "office_mean": float((w * np.nan_to_num(ov)).sum()) if weights.sum() > 0 else float("nan")}


def coverage(ids_frames, depth_frames, person_ids) -> dict:
    """How much of the sequence the people fill: over frames (``ids_frames``: each frame's object ids), the share
    with somebody covering at least 3 % of the image (``in_view``), the people's image share per frame over those
    with anybody (``share``: p10, p50, p90), and the median depth of each visible person (``depth``: p10, p50, p90;
    ``depth_frames``: each frame's depth where it shows its people, m)."""
    share, depths = [], []
    for ids, z in zip(ids_frames, depth_frames):
        person = np.isin(ids, list(person_ids))
        share.append(float(person.mean()))
        for pid in person_ids:
            v = z[(ids == pid) & (z > 0)]
            if v.size >= 50:
                depths.append(float(np.median(v)))
    share = np.asarray(share)
    seen = share[share > 0]
    pct = (lambda v: [float(x) for x in np.percentile(v, (10, 50, 90))] if len(v) else [np.nan] * 3)
    return {"frames": int(len(share)), "in_view": float((share >= 0.03).mean()) if len(share) else np.nan,
            "share": pct(seen), "depth": pct(np.asarray(depths))}


def composite_coverage(seq, stride: int = 1) -> dict:
    """:func:`coverage` of a composite: its colour truth (``mask_gt``) for the shares, its depth where the depth image
    shows each person (``mask_depth``) for the depths."""
    idx = range(0, len(seq), int(stride))
    ids = [seq.mask_gt(i) for i in idx]
    md = [cv2.imread(str(Path(seq.root) / "mask_depth" / Path(seq.depth_files[i]).name), cv2.IMREAD_UNCHANGED)
          for i in idx]
    z = [np.where(m > 0, seq.depth_image(i), 0.0) for i, m in zip(idx, md)]
    share = coverage(ids, [np.zeros(i.shape) for i in ids], list(seq.person_ids))
    depth = coverage(md, z, list(seq.person_ids))
    return {**share, "depth": depth["depth"]}


# --------------------------------------------------------------------------------------------------
# figures (notebooks/12_real_people.ipynb)
# --------------------------------------------------------------------------------------------------
def room_figure(room, camera_centres: np.ndarray, ax=None):
    """The room a composite's people were planned in, from above (room frame: the floor at Z = 0, the cameras' mean
    view along +y): occupied cells, known free floor, where a person may stand (seen free, never seen), out of view,
    the camera's centres and the lattice where a person would be seen (``RealRoom.visibility``, coloured by the
    largest image share)."""
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    s = room.space
    img = np.ones(s.shape + (3,))
    classes = [(s.out_of_view & s.standable, (0.62, 0.66, 0.95), "standable, out of view"),
               (s.never_in_view & s.standable & ~s.out_of_view, (0.85, 0.75, 0.97), "standable, never in view"),
               (s.known_free, (0.70, 0.90, 0.70), "seen free"),
               (s.known_free & s.standable, (0.20, 0.65, 0.25), "standable, seen free"),
               (s.occupied, (0.75, 0.15, 0.15), "occupied (fused depth, the operator)")]
    for sel, colour, _ in classes:
        img[sel] = colour
    if ax is None:
        _, ax = plt.subplots(figsize=(6.5, 6))
    ext = [s.origin[0], s.origin[0] + s.shape[0] * s.cell, s.origin[1], s.origin[1] + s.shape[1] * s.cell]
    ax.imshow(img.transpose(1, 0, 2), origin="lower", extent=ext, interpolation="nearest")
    ax.plot(camera_centres[:, 0], camera_centres[:, 1], "k.", ms=2, label="camera centres")
    v = room.visibility
    sc = ax.scatter(v.xy[:, 0], v.xy[:, 1], c=v.coverage.max(axis=1, initial=0.0), s=14, cmap="viridis", vmin=0,
                    vmax=0.5, edgecolors="k", linewidths=0.3)
    plt.colorbar(sc, ax=ax, fraction=0.04, label="largest image share of a person there")
    ax.legend(handles=[Patch(color=c, label=lab) for _, c, lab in classes], loc="upper right", fontsize=7)
    ix, iy = np.nonzero(s.occupied | s.known_free)  # what the depth saw, and a metre round it
    lo = s.origin + np.array([ix.min(), iy.min()]) * s.cell - 1.0
    hi = s.origin + (np.array([ix.max(), iy.max()]) + 1) * s.cell + 1.0
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    return ax


def composite_figure(seq, real, frames, axes=None):
    """Rows of frames of a composite ``seq`` beside its recording ``real`` (a ``TumSequence``; frame ``i`` of ``seq``
    is frame ``real_index[i]`` of ``real``, the same timestamps): the real colour image, the composite's, its truth
    (``mask_gt`` over it), and its depth image with what it shows of the people (``mask_depth``, outlined)."""
    import matplotlib.pyplot as plt

    frames = list(frames)
    if axes is None:
        _, axes = plt.subplots(len(frames), 4, figsize=(13, 2.6 * len(frames)), squeeze=False)
    where = {round(float(t), 6): k for k, t in enumerate(real.timestamps)}
    colours = np.array([[0, 0, 0], [230, 60, 40], [40, 120, 230], [240, 200, 40]], float)
    for row, i in zip(axes, frames):
        k = where[round(float(seq.timestamps[i]), 6)]
        c = seq[i]
        ids = seq.mask_gt(i)
        over = c.rgb.astype(float)
        lab = np.clip(ids, 0, 3)
        lab[ids >= 10] = 3  # a moved object
        sel = ids > 0
        over[sel] = 0.45 * over[sel] + 0.55 * colours[lab[sel]]
        md = cv2.imread(str(Path(seq.root) / "mask_depth" / Path(seq.depth_files[i]).name), cv2.IMREAD_UNCHANGED)
        edge = (cv2.dilate((md > 0).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0) & ~(md > 0)
        depth = np.ma.masked_where(c.depth <= 0, c.depth)  # holes: white
        row[0].imshow(real.rgb_frame(k).rgb)
        row[1].imshow(c.rgb)
        row[2].imshow(over.astype(np.uint8))
        row[3].imshow(depth, cmap="turbo", vmin=0.5, vmax=4.0)
        row[3].imshow(np.ma.masked_where(~edge, edge), cmap="gray_r", vmin=0, vmax=1)
        for ax, title in zip(row, ("real", "composite", "truth (mask_gt)", "depth; people outlined (mask_depth)")):
            ax.set_title(f"frame {i}: {title}", fontsize=8)
            ax.axis("off")
    return axes
