"""Seeded procedural textures that give ORB plenty of corners: rectangles, lines, text-like marks, blobs.

Every texture is a function of ``(rng, kind, width, height)`` only, so the same seed gives the same pixels.
Textures are HxWx3 uint8 in RGB order. They are built once per sequence (set-up cost, not per frame).
"""

from __future__ import annotations

import string

import cv2
import numpy as np

_FONTS = (cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_COMPLEX, cv2.FONT_HERSHEY_PLAIN,
          cv2.FONT_HERSHEY_TRIPLEX)
_CHARS = np.array(list(string.ascii_letters + string.digits + "#%&+=?"))

KINDS = ("wall", "floor", "ceiling", "poster", "books", "box", "wood", "screen", "cloth", "trousers", "skin",
         "hair", "chair")


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


def make_texture(rng: np.random.Generator, kind: str, width: int, height: int) -> np.ndarray:
    """A ``height x width`` RGB texture of the given kind (see ``KINDS``), drawn with ``rng``."""
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
    elif kind == "cloth":
        # Patterned clothes: stripes or checks, a printed logo and text, so a person yields ORB features.
        a, b = _colour(rng, 0, 255), _colour(rng, 0, 255)
        img[:] = a
        step = int(rng.integers(10, 26))
        if rng.random() < 0.5:
            for y in range(0, height, 2 * step):
                cv2.rectangle(img, (0, y), (width, y + step - 1), b, -1)
        else:
            for y in range(0, height, step):
                for x in range((y // step) % 2 * step, width, 2 * step):
                    cv2.rectangle(img, (x, y), (x + step - 1, y + step - 1), b, -1)
        pal = [_colour(rng) for _ in range(5)]
        _blobs(img, rng, 6 + area // 4000, max(6, min(width, height) // 10), pal)
        _rects(img, rng, 4 + area // 6000, max(10, min(width, height) // 5), pal)
        _text(img, rng, 6 + area // 3000, (0.6, 1.8), [(255, 255, 255), (0, 0, 0)] + pal[:2], (1, 3))
        img = _grain(img, rng, 5.0)
    elif kind == "trousers":
        base = _colour(rng, 20, 120)
        img[:] = base
        _lines(img, rng, 10 + area // 2000, [_jitter(base, rng, 80) for _ in range(4)], (1, 3))
        _rects(img, rng, 4 + area // 5000, max(8, min(width, height) // 5), [_colour(rng) for _ in range(3)])
        _blobs(img, rng, 4 + area // 6000, 8, [_colour(rng) for _ in range(3)])
        img = _grain(img, rng, 6.0)
    elif kind == "skin":
        base = (int(rng.integers(120, 235)), int(rng.integers(85, 185)), int(rng.integers(60, 150)))
        img[:] = base
        _blobs(img, rng, 6 + area // 3000, max(4, min(width, height) // 12), [_jitter(base, rng, 55)])
        # a face: eyes, mouth (the front face of a head gets the whole texture)
        cx, cy = width // 2, height // 2
        for dx in (-width // 5, width // 5):
            cv2.circle(img, (cx + dx, cy - height // 8), max(2, width // 14), (30, 30, 30), -1)
        cv2.line(img, (cx - width // 6, cy + height // 5), (cx + width // 6, cy + height // 5), (120, 40, 40), 3)
        img = _grain(img, rng, 4.0)
    elif kind == "hair":
        base = _colour(rng, 10, 110)
        img[:] = base
        _lines(img, rng, 30 + area // 300, [_jitter(base, rng, 70) for _ in range(3)], (1, 2))
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
