"""Seeded procedural textures. The room's give ORB plenty of corners (rectangles, lines, text-like marks, blobs).
People wear clothes built from a base colour: shirts with stripes or checks (or plain), folds, small printed marks
and at most one logo; plain trousers with seams; skin with a face; hair strands; all blurred like fabric. Their
constants (``SynthConfig.cloth_*``) are calibrated with ``d2slam bench realism`` so that the share of the engine's
ORB keypoints on people over their area matches real TUM fr3 frames, about 0.4-0.7 (measured: docs/deviations.md,
``SynthConfig.cloth_*``).

Every texture is a function of ``(rng, kind, width, height)`` (and the config) only, so the same seed gives the
same pixels.
Textures are HxWx3 uint8 in RGB order. They are built once per sequence (set-up cost, not per frame).
"""

from __future__ import annotations

import string

import cv2
import numpy as np

from d2slam.config import SynthConfig

_FONTS = (cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_COMPLEX, cv2.FONT_HERSHEY_PLAIN,
          cv2.FONT_HERSHEY_TRIPLEX)
_CHARS = np.array(list(string.ascii_letters + string.digits + "#%&+=?"))

KINDS = ("wall", "floor", "ceiling", "poster", "books", "box", "wood", "screen", "cloth", "trousers", "skin",
         "hair", "chair", "paint", "floor_plain", "beams", "cork", "desk", "plastic", "keyboard", "seat")


def _colour(rng, lo=0, hi=255) -> tuple[int, int, int]:
    return tuple(int(c) for c in rng.integers(lo, hi + 1, size=3))


def _jitter(base, rng, amount) -> tuple[int, int, int]:
    return tuple(int(np.clip(c + rng.integers(-amount, amount + 1), 0, 255)) for c in base)


def _text(img, rng, n, scale=(0.4, 1.2), colours=None, thickness=(1, 2)):
    h, w = img.shape[:2]
    for _ in range(n):
        word = "".join(rng.choice(_CHARS, size=int(rng.integers(2, 9))))
        org = (int(rng.integers(-10, w)), int(rng.integers(8, h + 10)))
        col = colours[int(rng.integers(len(colours)))] if colours else _colour(rng)
        cv2.putText(img, word, org, _FONTS[int(rng.integers(len(_FONTS)))], float(rng.uniform(*scale)), col,
                    int(rng.integers(thickness[0], thickness[1] + 1)), cv2.LINE_AA)


def _rects(img, rng, n, size, colours=None, filled=0.7):
    h, w = img.shape[:2]
    for _ in range(n):
        x, y = int(rng.integers(-size // 2, w)), int(rng.integers(-size // 2, h))
        rw, rh = int(rng.integers(size // 4 + 1, size + 2)), int(rng.integers(size // 4 + 1, size + 2))
        col = colours[int(rng.integers(len(colours)))] if colours else _colour(rng)
        cv2.rectangle(img, (x, y), (x + rw, y + rh), col, -1 if rng.random() < filled else int(rng.integers(1, 4)))


def _blobs(img, rng, n, radius, colours=None):
    h, w = img.shape[:2]
    for _ in range(n):
        c = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        ax = (int(rng.integers(2, radius + 3)), int(rng.integers(2, radius + 3)))
        col = colours[int(rng.integers(len(colours)))] if colours else _colour(rng)
        cv2.ellipse(img, c, ax, float(rng.uniform(0, 180)), 0, 360, col, -1, cv2.LINE_AA)


def _lines(img, rng, n, colours=None, thickness=(1, 4)):
    h, w = img.shape[:2]
    for _ in range(n):
        p = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        q = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        col = colours[int(rng.integers(len(colours)))] if colours else _colour(rng)
        cv2.line(img, p, q, col, int(rng.integers(thickness[0], thickness[1] + 1)), cv2.LINE_AA)


def _grain(img, rng, amount):
    noise = rng.normal(0.0, amount, size=img.shape[:2] + (1,)).astype(np.float32)
    return np.clip(img.astype(np.float32) + noise, 0, 255).astype(np.uint8)


def make_texture(rng: np.random.Generator, kind: str, width: int, height: int, cfg: SynthConfig | None = None,
                 texels_per_m: float | None = None) -> np.ndarray:
    """A ``height x width`` RGB texture of the given kind (see ``KINDS``), drawn with ``rng``. Clothes, skin and
    hair (``cloth``, ``trousers``, ``skin``, ``hair``) follow the people constants of ``cfg`` (pattern sizes in
    metres, converted with ``texels_per_m``, default ``cfg.body_texels_per_m``)."""
    width, height = max(int(width), 16), max(int(height), 16)
    area = width * height
    img = np.empty((height, width, 3), np.uint8)
    if kind == "wall":
        base = _colour(rng, 150, 225)
        img[:] = base
        pal = [_jitter(base, rng, 60) for _ in range(6)] + [_colour(rng, 20, 120) for _ in range(3)]
        _rects(img, rng, area // 9000 + 6, max(20, min(width, height) // 6), pal, filled=0.6)
        _lines(img, rng, area // 25000 + 4, pal, (1, 3))
        _text(img, rng, area // 14000 + 4, (0.5, 1.4), [_colour(rng, 0, 90) for _ in range(3)])
        _blobs(img, rng, area // 20000 + 4, 18, pal)
        img = _grain(img, rng, 4.0)
    elif kind == "floor":
        base = _colour(rng, 80, 160)
        img[:] = base
        tile = int(rng.integers(40, 80))
        for y in range(0, height, tile):
            for x in range(0, width, tile):
                cv2.rectangle(img, (x, y), (x + tile - 2, y + tile - 2), _jitter(base, rng, 35), -1)
        _blobs(img, rng, area // 6000 + 10, 10, [_colour(rng, 20, 230) for _ in range(5)])
        _lines(img, rng, area // 30000 + 5, [_colour(rng, 0, 80)], (1, 3))
        img = _grain(img, rng, 6.0)
    elif kind == "ceiling":
        base = _colour(rng, 190, 235)
        img[:] = base
        step = int(rng.integers(50, 90))
        for x in range(0, width, step):
            cv2.line(img, (x, 0), (x, height), _jitter(base, rng, 70), 2)
        for y in range(0, height, step):
            cv2.line(img, (0, y), (width, y), _jitter(base, rng, 70), 2)
        _blobs(img, rng, area // 15000 + 4, 14, [_colour(rng, 80, 200)])
        img = _grain(img, rng, 3.0)
    elif kind == "poster":
        img[:] = _colour(rng, 180, 255)
        pal = [_colour(rng) for _ in range(8)]
        _rects(img, rng, 10 + area // 3000, max(16, min(width, height) // 3), pal)
        _blobs(img, rng, 8 + area // 5000, max(8, min(width, height) // 8), pal)
        _text(img, rng, 12 + area // 2500, (0.5, 2.0), [(0, 0, 0), (255, 255, 255)] + pal[:3], (1, 3))
        _lines(img, rng, 6, pal, (2, 5))
    elif kind == "books":
        img[:] = _colour(rng, 30, 90)
        shelf_h = int(rng.integers(height // 6, height // 4 + 1))
        for y in range(0, height, shelf_h):
            x = 0
            while x < width:
                bw = int(rng.integers(6, 28))
                top = y + int(rng.integers(4, shelf_h // 3 + 5))
                col = _colour(rng, 20, 240)
                cv2.rectangle(img, (x, top), (x + bw - 1, y + shelf_h - 6), col, -1)
                if rng.random() < 0.5:
                    cv2.line(img, (x + 1, top + 6), (x + bw - 2, top + 6), _colour(rng), 2)
                x += bw + int(rng.integers(0, 3))
            cv2.rectangle(img, (0, y + shelf_h - 6), (width, y + shelf_h), (120, 90, 60), -1)
        img = _grain(img, rng, 3.0)
    elif kind == "box":
        base = (int(rng.integers(150, 200)), int(rng.integers(110, 150)), int(rng.integers(60, 100)))
        img[:] = base
        _rects(img, rng, 4 + area // 6000, max(12, min(width, height) // 4), [_colour(rng) for _ in range(4)], 0.8)
        _text(img, rng, 6 + area // 3000, (0.5, 1.6), [(20, 20, 20), (200, 30, 30), (20, 40, 160)], (1, 3))
        _lines(img, rng, 4, [(60, 40, 20)], (2, 4))
        img = _grain(img, rng, 4.0)
    elif kind == "wood":
        base = _colour(rng, 90, 170)
        img[:] = base
        for y in range(0, height, 3):
            cv2.line(img, (0, y), (width, y + int(rng.integers(-6, 7))), _jitter(base, rng, 30), 2)
        _blobs(img, rng, area // 5000 + 6, 8, [_colour(rng, 0, 255) for _ in range(6)])
        _rects(img, rng, area // 8000 + 4, max(12, min(width, height) // 5), [_colour(rng) for _ in range(6)])
        _text(img, rng, area // 9000 + 3, (0.4, 1.0), [(10, 10, 10), (240, 240, 240)])
    elif kind == "screen":
        img[:] = _colour(rng, 0, 60)
        _rects(img, rng, 12, max(10, min(width, height) // 3), [_colour(rng, 60, 255) for _ in range(5)])
        _text(img, rng, 14, (0.4, 1.0), [(230, 230, 230), (120, 230, 120)])
    elif kind == "paint":  # a painted wall: one colour, faint panel seams
        base = _colour(rng, 185, 235)
        img[:] = base
        step = int(rng.integers(180, 300))
        for x in range(step, width, step):
            cv2.line(img, (x, 0), (x, height), _jitter(base, rng, 25), 2)
        # hall fittings: pipes and ducts along the top, switches and signs, a radiator, a dark window pane
        for _ in range(int(rng.integers(2, 5))):
            y = int(rng.integers(0, max(height // 4, 2)))
            cv2.line(img, (0, y), (width, y), _colour(rng, 90, 230), int(rng.integers(3, 10)))
        _rects(img, rng, area // 7000 + 3, max(6, min(width, height) // 15), [_colour(rng, 30, 230) for _ in range(6)],
               filled=0.6)
        _lines(img, rng, area // 50000 + 3, [_colour(rng, 40, 200) for _ in range(3)], (2, 6))
        if rng.random() < 0.7:
            x0, w0 = int(rng.integers(0, max(width // 2, 2))), int(rng.integers(width // 6, width // 3 + 2))
            y0 = int(rng.integers(height // 5, height // 2))
            cv2.rectangle(img, (x0, y0), (x0 + w0, y0 + height // 4), _colour(rng, 40, 110), -1)
            for x in range(x0, x0 + w0, max(w0 // 4, 2)):
                cv2.line(img, (x, y0), (x, y0 + height // 4), (220, 220, 220), 3)
        _text(img, rng, area // 20000 + 2, (0.4, 1.2), [(30, 30, 30), (180, 30, 30)])
        img = _grain(img, rng, 1.5)
    elif kind == "floor_plain":  # smooth grey floor with a few scuffs
        base = _colour(rng, 135, 185)
        img[:] = base
        _blobs(img, rng, area // 20000 + 3, 12, [_jitter(base, rng, 40) for _ in range(3)])
        _lines(img, rng, area // 60000 + 2, [(200, 190, 60), (40, 40, 40)], (3, 8))
        img = _grain(img, rng, 4.0)
    elif kind == "beams":  # a hall ceiling: beams, pipes and lamps
        base = _colour(rng, 150, 200)
        img[:] = base
        step = int(rng.integers(30, 60))
        for y in range(0, height, step):
            cv2.rectangle(img, (0, y), (width, y + step // 5), _colour(rng, 40, 110), -1)
        for _ in range(area // 40000 + 6):
            x = int(rng.integers(0, width))
            cv2.line(img, (x, 0), (x + int(rng.integers(-40, 41)), height), _colour(rng, 60, 230),
                     int(rng.integers(2, 6)))
        _rects(img, rng, area // 50000 + 4, max(12, min(width, height) // 10), [(250, 250, 245)], filled=1.0)
        img = _grain(img, rng, 3.0)
    elif kind == "cork":  # office partition board with pinned notes
        img[:] = (int(rng.integers(170, 200)), int(rng.integers(125, 150)), int(rng.integers(75, 100)))
        _rects(img, rng, area // 20000 + 2, max(8, min(width, height) // 6), [(240, 240, 235), (250, 240, 120)],
               filled=1.0)
        img = _grain(img, rng, 7.0)
    elif kind == "desk":
        img[:] = _colour(rng, 210, 240)
        img = _grain(img, rng, 1.5)
    elif kind == "plastic":
        img[:] = _colour(rng, 25, 120) if rng.random() < 0.6 else _colour(rng, 150, 210)
        img = _grain(img, rng, 2.0)
    elif kind == "keyboard":
        img[:] = _colour(rng, 15, 50)
        key = max(4, min(width, height) // 6)
        for y in range(2, height - key, key + 2):
            for x in range(2, width - key, key + 2):
                cv2.rectangle(img, (x, y), (x + key - 1, y + key - 1), _colour(rng, 60, 110), -1)
    elif kind == "seat":  # a plain chair: moulded wood or dark fabric
        img[:] = (int(rng.integers(200, 235)), int(rng.integers(150, 185)), int(rng.integers(60, 100))) \
            if rng.random() < 0.6 else _colour(rng, 20, 70)
        img = _grain(img, rng, 3.0)
    elif kind in _CLOTHES:
        return _clothes(rng, kind, width, height, cfg or SynthConfig(), texels_per_m)
    elif kind == "chair":
        base = _colour(rng, 10, 90)
        img[:] = base
        _rects(img, rng, 6, max(8, min(width, height) // 3), [_colour(rng) for _ in range(4)])
        _text(img, rng, 5, (0.5, 1.0), [(230, 230, 230)])
        _lines(img, rng, 8, [_jitter(base, rng, 90)], (1, 3))
        img = _grain(img, rng, 5.0)
    else:
        raise ValueError(f"unknown texture kind {kind!r}")
    return cv2.GaussianBlur(img, (3, 3), 0.6)


_CLOTHES = ("cloth", "trousers", "skin", "hair")


def _shifted(base, rng, contrast) -> tuple[int, int, int]:
    """A colour lighter or darker than ``base`` by about ``contrast`` grey levels (half to all of it)."""
    d = float(rng.choice([-1.0, 1.0])) * rng.uniform(0.7, 1.0) * contrast
    if not 0 <= np.mean(base) + d <= 255:
        d = -d
    return tuple(int(np.clip(c + d + rng.integers(-8, 9), 0, 255)) for c in base)


def _clothes(rng, kind, width, height, cfg: SynthConfig, texels_per_m: float | None) -> np.ndarray:
    """Clothes, skin and hair (see the module docstring); sizes in metres times ``texels_per_m``."""
    tpm = float(texels_per_m or cfg.body_texels_per_m)
    img = np.empty((height, width, 3), np.uint8)
    contrast = cfg.cloth_contrast
    if kind == "cloth":
        base = _colour(rng, 25, 225)
        img[:] = base
        other = _shifted(base, rng, contrast)
        u = rng.random()
        step = max(4, int(rng.uniform(*cfg.cloth_pattern_m) * tpm))
        if u >= cfg.cloth_plain_prob:
            if rng.random() >= cfg.cloth_check_prob:  # stripes, horizontal or vertical
                vertical = rng.random() < 0.3
                for k in range(0, width if vertical else height, step):
                    a, b = ((k, 0), (k + step // 2 - 1, height)) if vertical else ((0, k), (width, k + step // 2 - 1))
                    cv2.rectangle(img, a, b, other, -1)
            else:  # checks: stripes both ways, blended where they cross (plaid)
                layer = img.copy()
                for k in range(0, height, step):
                    cv2.rectangle(layer, (0, k), (width, k + step // 2 - 1), other, -1)
                img = cv2.addWeighted(img, 0.5, layer, 0.5, 0)
                layer = img.copy()
                for k in range(0, width, step):
                    cv2.rectangle(layer, (k, 0), (k + step // 2 - 1, height), other, -1)
                img = cv2.addWeighted(img, 0.5, layer, 0.5, 0)
        # soft folds
        _lines(img, rng, int(rng.integers(2, 6)), [_shifted(base, rng, contrast / 2)],
               (max(1, int(0.008 * tpm)), max(2, int(0.02 * tpm))))
        # small printed marks (motifs, buttons, letters), Poisson with cloth_marks_per_m2
        n_marks = int(rng.poisson(cfg.cloth_marks_per_m2 * width * height / tpm ** 2))
        if n_marks:
            pal = [_shifted(base, rng, cfg.cloth_print_contrast) for _ in range(2)]
            size = max(4, int(rng.uniform(*cfg.cloth_mark_m) * tpm))
            kinds = rng.integers(0, 3, size=n_marks)
            _rects(img, rng, int((kinds == 0).sum()), size, pal, filled=0.8)
            _blobs(img, rng, int((kinds == 1).sum()), size // 2, pal)
            _text(img, rng, int((kinds == 2).sum()), (size / 40, size / 25), pal, (1, 2))
        if rng.random() < cfg.cloth_print_prob:  # one printed logo: a patch and a short word on it
            size = rng.uniform(0.08, 0.16) * tpm
            x, y = int(rng.uniform(0.2, 0.6) * width), int(rng.uniform(0.15, 0.5) * height)
            col = _shifted(base, rng, cfg.cloth_print_contrast)
            if rng.random() < 0.5:
                cv2.rectangle(img, (x, y), (x + int(size), y + int(0.6 * size)), col, -1)
            else:
                cv2.ellipse(img, (x, y), (int(size / 2), int(size / 3)), 0.0, 0, 360, col, -1, cv2.LINE_AA)
            _text(img, rng, 1, (0.3 * size / 20, 0.5 * size / 20), [_shifted(col, rng, cfg.cloth_print_contrast)],
                  (1, 2))
    elif kind == "trousers":
        base = _colour(rng, 20, 130)
        img[:] = base
        seam = _shifted(base, rng, contrast / 2)
        _lines(img, rng, int(rng.integers(2, 6)), [seam], (max(1, int(0.006 * tpm)), max(2, int(0.015 * tpm))))
        for x in (int(rng.uniform(0.2, 0.35) * width), int(rng.uniform(0.65, 0.8) * width)):
            cv2.line(img, (x, 0), (x + int(rng.integers(-4, 5)), height), seam, max(1, int(0.005 * tpm)))
        if rng.random() < 0.5:  # a pocket
            w = int(0.12 * tpm)
            x, y = int(rng.uniform(0.1, 0.5) * width), int(rng.uniform(0.05, 0.3) * height)
            cv2.rectangle(img, (x, y), (x + w, y + w), seam, max(1, int(0.004 * tpm)))
    elif kind == "skin":
        base = (int(rng.integers(120, 235)), int(rng.integers(85, 185)), int(rng.integers(60, 150)))
        img[:] = base
        _blobs(img, rng, 2 + width * height // 20000, max(4, min(width, height) // 8), [_jitter(base, rng, 20)])
        # a face: eyes, mouth (the front face of a head gets the whole texture)
        cx, cy = width // 2, height // 2
        for dx in (-width // 5, width // 5):
            cv2.circle(img, (cx + dx, cy - height // 8), max(2, width // 16), _jitter((60, 45, 40), rng, 15), -1)
        cv2.line(img, (cx - width // 6, cy + height // 5), (cx + width // 6, cy + height // 5),
                 _jitter((140, 70, 60), rng, 15), 3)
    else:  # hair
        base = _colour(rng, 10, 110)
        img[:] = base
        _lines(img, rng, 8 + width * height // 4000, [_jitter(base, rng, contrast // 2) for _ in range(3)], (1, 2))
    img = _grain(img, rng, 2.0)
    sigma = max(cfg.cloth_blur_m * tpm, 0.6)
    return cv2.GaussianBlur(img, (0, 0), sigma)
