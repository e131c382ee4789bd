"""Seeded procedural textures. The room's give ORB plenty of corners (rectangles, lines, text-like marks, blobs).
People wear clothes built from a base colour: shirts with stripes or checks (or plain), folds, small printed marks
and at most one logo; plain trousers with seams; skin with a face; hair strands; all blurred like fabric. Their
constants (``ClothConfig.cloth_*``) are calibrated with ``d2slam bench realism`` so that the share of the engine's
ORB keypoints on people over their area matches real TUM fr3 frames, about 0.4-0.7 (measured: docs/deviations.md,
``ClothConfig.cloth_*``).

Every texture is a function of ``(rng, kind, width, height)`` (and the config) only, so the same seed gives the
same pixels.
Textures are HxWx3 uint8 in RGB order. They are built once per sequence (set-up cost, not per frame).
"""

from __future__ import annotations

import string

import cv2
import numpy as np

from d2slam.synth.config import SynthConfig

_FONTS = (cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_COMPLEX, cv2.FONT_HERSHEY_PLAIN,
          cv2.FONT_HERSHEY_TRIPLEX)
_CHARS = np.array(list(string.ascii_letters + string.digits + "#%&+=?"))

KINDS = ("wall", "floor", "ceiling", "poster", "books", "box", "wood", "screen", "cloth", "trousers", "skin",
         "hair", "chair", "paint", "floor_plain", "beams", "hall", "cork", "paper", "panels", "desk", "plastic",
         "keyboard", "seat")


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


def _truss(img, rng, bay: int, depth: int, colour, horizontal: bool = True):
    """A steel truss across the image: two chords ``depth`` apart with zig-zag lacing every ``bay`` texels
    (horizontal: along the top rows; else along the columns, as seen on a ceiling)."""
    h, w = img.shape[:2]
    n, a = (w, int(rng.integers(0, max(h // 6, 2)))) if horizontal else (h, int(rng.integers(0, max(w // 3, 2))))
    bay, depth = max(int(bay), 8), max(int(depth), 6)
    for off in range(a, (h if horizontal else w), (h if horizontal else w) + 1):
        pts = []
        for k, s in enumerate(range(0, n + bay, bay)):
            d = off + (depth if k % 2 else 0)
            pts.append((s, d) if horizontal else (d, s))
        line = lambda p, q: cv2.line(img, p, q, colour, 3, cv2.LINE_AA)  # noqa: E731
        for p, q in zip(pts[:-1], pts[1:]):
            line(p, q)
        first = [(0, off), (n, off)] if horizontal else [(off, 0), (off, n)]
        second = [(0, off + depth), (n, off + depth)] if horizontal else [(off + depth, 0), (off + depth, n)]
        line(*first)
        line(*second)


def _cladding(img, rng, base, tpm: float):
    """Profiled metal cladding of a hall wall: panels a metre or two wide in slightly different tones, each with
    vertical ribs every 4-7 cm (a lit and a shaded edge)."""
    h, w = img.shape[:2]
    x = 0
    while x < w:
        pw = int(rng.uniform(1.0, 2.2) * tpm)
        tone = _jitter(base, rng, 18)
        img[:, x:x + pw] = tone
        rib = max(int(rng.uniform(0.04, 0.07) * tpm), 5)
        lit, shade = _jitter(tone, rng, 6), tuple(max(c - int(rng.integers(28, 45)), 0) for c in tone)
        for rx in range(x + rib // 2, min(x + pw, w), rib):
            cv2.line(img, (rx, 0), (rx, h), shade, 2)
            cv2.line(img, (rx + 2, 0), (rx + 2, h), tuple(min(c + 20, 255) for c in lit), 1)
        cv2.line(img, (x, 0), (x, h), tuple(max(c - 60, 0) for c in tone), 2)  # the panel joint
        x += pw


def _slats(img, rng, tpm: float):
    """A wooden roof seen from below, as in the TUM fr3 hall: planks 6-10 cm wide along the rows, each its own tone,
    with a dark gap between them and a faint grain."""
    h, w = img.shape[:2]
    wood = (int(rng.integers(170, 215)), int(rng.integers(125, 160)), int(rng.integers(70, 100)))
    y = 0
    while y < h:
        ph = max(int(rng.uniform(0.06, 0.10) * tpm), 6)
        img[y:y + ph] = _jitter(wood, rng, 22)
        cv2.line(img, (0, y), (w, y), tuple(c // 3 for c in wood), 2)
        y += ph
    _lines(img, rng, (h * w) // 30000 + 4, [tuple(max(c - 35, 0) for c in wood)], (1, 1))


def _grain(img, rng, amount):
    """Grain of standard deviation ``amount`` grey levels (uniform: cheap to draw for the large room textures)."""
    noise = rng.random(size=img.shape[:2] + (1,), dtype=np.float32)
    noise -= np.float32(0.5)
    noise *= np.float32(amount * np.sqrt(12.0))
    return np.clip(img.astype(np.float32) + noise, 0, 255).astype(np.uint8)


def make_texture(rng: np.random.Generator, kind: str, width: int, height: int, cfg: SynthConfig | None = None,
                 texels_per_m: float | None = None, base: tuple | None = None, face: tuple | None = None) -> np.ndarray:
    """A ``height x width`` RGB texture of the given kind (see ``KINDS``), drawn with ``rng``. Clothes, skin and
    hair (``cloth``, ``trousers``, ``skin``, ``hair``) follow the people constants of ``cfg`` (pattern sizes in
    metres, converted with ``texels_per_m``, default ``cfg.body_texels_per_m``), in the colour ``base`` (RGB 0-255;
    drawn when None); ``face``: where a skin texture carries the face, ``(x, y, px_per_m_x)`` (texels; the eyes'
    centre and the horizontal scale), else at its centre."""
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
    elif kind == "floor_plain":  # smooth grey floor with scuffs, taped lines, cables and their covers
        base = _jitter((int(rng.integers(135, 185)),) * 3, rng, 8)
        img[:] = base
        _blobs(img, rng, area // 20000 + 3, 12, [_jitter(base, rng, 40) for _ in range(3)])
        _lines(img, rng, area // 60000 + 2, [(200, 190, 60), (40, 40, 40)], (3, 8))
        for _ in range(area // 80000 + 3):  # cables: wavy polylines
            p = np.array([rng.integers(0, width), rng.integers(0, height)], float)
            d = rng.normal(size=2)
            pts = [p.copy()]
            for _ in range(int(rng.integers(6, 20))):
                d = d + rng.normal(scale=0.5, size=2)
                p += 25 * d / np.linalg.norm(d)
                pts.append(p.copy())
            cv2.polylines(img, [np.int32(pts)], False, _colour(rng, 10, 70), int(rng.integers(2, 4)), cv2.LINE_AA)
        _rects(img, rng, area // 30000 + 3, 20, [_jitter(base, rng, 60) for _ in range(3)], filled=0.5)
        img = _grain(img, rng, 4.0)
    elif kind == "beams":  # a hall ceiling: trusses (chords and zig-zag lacing), purlins, pipes and lamps
        tpm = texels_per_m or 220.0
        base = _colour(rng, 150, 200)
        img[:] = base
        _slats(img, rng, tpm)
        steel = [_colour(rng, 40, 110) for _ in range(2)]
        step = int(rng.integers(30, 60))
        for y in range(0, height, step):
            cv2.rectangle(img, (0, y), (width, y + step // 5), steel[0], -1)
        _truss(img, rng, int(0.9 * tpm), int(0.35 * tpm), steel[1], horizontal=False)
        for _ in range(area // 40000 + 6):
            x = int(rng.integers(0, width))
            cv2.line(img, (x, 0), (x + int(rng.integers(-40, 41)), height), _colour(rng, 60, 230),
                     int(rng.integers(2, 6)))
        _rects(img, rng, area // 50000 + 4, max(12, min(width, height) // 10), [(250, 250, 245)], filled=1.0)
        img = _grain(img, rng, 3.0)
    elif kind == "hall":  # the hall beyond the office, as in TUM fr3: steel frame with trusses and bracing,
        # windows with mullions, racks of boxes, pipes and cable trays, lamps and signs (texels_per_m: scale)
        tpm = texels_per_m or 220.0
        base = _colour(rng, 175, 220)
        img[:] = base
        steel = [_colour(rng, 50, 120) for _ in range(3)]
        col_step = int(rng.uniform(1.0, 1.5) * tpm)
        _cladding(img, rng, base, tpm)
        # a band of windows high up: bright panes divided by mullions
        y0, y1 = int(0.08 * height), int(rng.uniform(0.3, 0.4) * height)
        cv2.rectangle(img, (0, y0), (width, y1), (235, 238, 240), -1)
        pane = int(rng.uniform(0.25, 0.4) * tpm)
        for x in range(0, width, pane):
            cv2.line(img, (x, y0), (x, y1), steel[2], max(2, int(0.02 * tpm)))
        for y in range(y0, y1, pane):
            cv2.line(img, (0, y), (width, y), steel[2], max(2, int(0.02 * tpm)))
        # racks of boxes in the lower part, between the columns
        for x in range(0, width, col_step):
            if rng.random() < 0.6:
                top = int(rng.uniform(0.5, 0.65) * height)
                shelf = int(0.3 * tpm)
                for y in range(top, height, shelf):
                    cv2.rectangle(img, (x + 8, y), (x + col_step - 8, y + 4), steel[1], -1)
                    bx = x + 10
                    while bx < x + col_step - 20:
                        bw = int(rng.uniform(0.12, 0.35) * tpm)
                        bh = int(rng.uniform(0.4, 0.9) * shelf)
                        cv2.rectangle(img, (bx, y - bh), (min(bx + bw, x + col_step - 10), y - 1),
                                      _colour(rng, 60, 230), -1)
                        bx += bw + int(rng.integers(2, 12))
        # the steel frame: columns, beams and cross bracing in some bays, a truss under the roof
        beams = [int(f * height) for f in (0.05, rng.uniform(0.42, 0.5))]
        for x in range(0, width + col_step, col_step):
            cv2.rectangle(img, (x - 5, 0), (x + 5, height), steel[0], -1)
        for y in beams:
            cv2.rectangle(img, (0, y - 4), (width, y + 4), steel[0], -1)
        for x in range(0, width, col_step):
            if rng.random() < 0.5:
                cv2.line(img, (x, beams[0]), (x + col_step, beams[1]), steel[0], 3)
                cv2.line(img, (x + col_step, beams[0]), (x, beams[1]), steel[0], 3)
        _truss(img, rng, col_step // 3, max(beams[0], 12), steel[1], horizontal=True)
        # pipes and cable trays along the wall, lamps, signs
        for _ in range(int(rng.integers(3, 7))):
            y = int(rng.uniform(0.0, 0.6) * height)
            cv2.line(img, (0, y), (width, y + int(rng.integers(-4, 5))), _colour(rng, 40, 230),
                     int(rng.integers(3, 9)))
        _rects(img, rng, area // 60000 + 3, max(10, int(0.08 * tpm)), [(252, 252, 245)], filled=1.0)
        _rects(img, rng, area // 40000 + 3, max(10, int(0.12 * tpm)), [_colour(rng, 20, 230) for _ in range(4)],
               filled=0.8)
        _text(img, rng, area // 40000 + 2, (0.5, 1.4), [(30, 30, 30), (200, 40, 30), (30, 60, 160)])
        img = _grain(img, rng, 3.0)
    elif kind == "cork":  # office partition board with pinned notes, a calendar, a timetable
        img[:] = (int(rng.integers(170, 200)), int(rng.integers(125, 150)), int(rng.integers(75, 100)))
        _rects(img, rng, area // 12000 + 3, max(8, min(width, height) // 6), [(240, 240, 235), (250, 240, 120)],
               filled=1.0)
        _text(img, rng, area // 20000 + 2, (0.4, 0.8), [(30, 30, 30), (30, 40, 140)])
        img = _grain(img, rng, 7.0)
    elif kind == "paper":  # a printed sheet: lines of text
        img[:] = _jitter((242, 242, 238), rng, 6)
        for y in range(int(0.1 * height), int(0.9 * height), max(height // 12, 4)):
            x1 = int(rng.uniform(0.4, 0.9) * width)
            cv2.line(img, (int(0.1 * width), y), (x1, y), (60, 60, 60), max(1, height // 60))
    elif kind == "panels":  # white boards in dark frames, with a few notes and writing
        img[:] = (235, 236, 234)
        n = int(rng.integers(2, 4))
        for k in range(n + 1):
            x = int(k * (width - 1) / n)
            cv2.line(img, (x, 0), (x, height), (70, 70, 75), max(3, width // 120))
        cv2.rectangle(img, (0, 0), (width - 1, height - 1), (70, 70, 75), max(3, width // 120))
        _rects(img, rng, int(rng.integers(3, 8)), max(8, min(width, height) // 6), [(250, 240, 120), (240, 240, 235)],
               filled=1.0)
        _text(img, rng, int(rng.integers(3, 8)), (0.6, 1.4), [(40, 40, 140), (30, 30, 30), (160, 30, 30)], (1, 2))
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
        return _clothes(rng, kind, width, height, cfg or SynthConfig(), texels_per_m, base, face)
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


def _clothes(rng, kind, width, height, cfg: SynthConfig, texels_per_m: float | None, base=None,
             face=None) -> np.ndarray:
    """Clothes, skin and hair (see the module docstring and ``make_texture``); sizes in metres times
    ``texels_per_m``."""
    tpm = float(texels_per_m or cfg.body_texels_per_m)
    img = np.empty((height, width, 3), np.uint8)
    contrast = cfg.cloth.cloth_contrast
    given = None if base is None else tuple(int(c) for c in base)
    if kind == "cloth":
        base = given or _colour(rng, 25, 225)
        img[:] = base
        other = _shifted(base, rng, contrast)
        u = rng.random()
        step = max(4, int(rng.uniform(*cfg.cloth.cloth_pattern_m) * tpm))
        if u >= cfg.cloth.cloth_plain_prob:
            if rng.random() >= cfg.cloth.cloth_check_prob:  # stripes, horizontal or vertical
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
        n_marks = int(rng.poisson(cfg.cloth.cloth_marks_per_m2 * width * height / tpm ** 2))
        if n_marks:
            pal = [_shifted(base, rng, cfg.cloth.cloth_print_contrast) for _ in range(2)]
            size = max(4, int(rng.uniform(*cfg.cloth.cloth_mark_m) * tpm))
            kinds = rng.integers(0, 3, size=n_marks)
            _rects(img, rng, int((kinds == 0).sum()), size, pal, filled=0.8)
            _blobs(img, rng, int((kinds == 1).sum()), size // 2, pal)
            _text(img, rng, int((kinds == 2).sum()), (size / 40, size / 25), pal, (1, 2))
        if rng.random() < cfg.cloth.cloth_print_prob:  # one printed logo: a patch and a short word on it
            size = rng.uniform(0.08, 0.16) * tpm
            x, y = int(rng.uniform(0.2, 0.6) * width), int(rng.uniform(0.15, 0.5) * height)
            col = _shifted(base, rng, cfg.cloth.cloth_print_contrast)
            if rng.random() < 0.5:
                cv2.rectangle(img, (x, y), (x + int(size), y + int(0.6 * size)), col, -1)
            else:
                cv2.ellipse(img, (x, y), (int(size / 2), int(size / 3)), 0.0, 0, 360, col, -1, cv2.LINE_AA)
            _text(img, rng, 1, (0.3 * size / 20, 0.5 * size / 20), [_shifted(col, rng, cfg.cloth.cloth_print_contrast)],
                  (1, 2))
    elif kind == "trousers":
        base = given or _colour(rng, 20, 130)
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
        base = given or (int(rng.integers(120, 235)), int(rng.integers(85, 185)), int(rng.integers(60, 150)))
        img[:] = base
        _blobs(img, rng, 2 + width * height // 20000, max(4, min(width, height) // 8), [_jitter(base, rng, 20)])
        # a face: eyebrows, eyes, nose, mouth (the front face of a box head gets the whole texture)
        if face is None:
            cx, cy, sx, sy = width // 2, height // 2 - height // 8, width / 0.16, height / 0.22
        else:
            cx, cy, sx, sy = int(face[0]), int(face[1]), float(face[2]), tpm
        dark, lips = _jitter((60, 45, 40), rng, 15), _jitter((140, 70, 60), rng, 15)
        for side in (-1, 1):
            ex = int(cx + side * 0.032 * sx)
            cv2.ellipse(img, (ex, cy), (max(2, int(0.012 * sx)), max(1, int(0.006 * sy))), 0, 0, 360, dark, -1)
            cv2.line(img, (int(ex - 0.015 * sx), int(cy - 0.018 * sy)), (int(ex + 0.015 * sx), int(cy - 0.02 * sy)),
                     dark, max(1, int(0.004 * sy)))
        cv2.line(img, (cx, int(cy + 0.01 * sy)), (cx, int(cy + 0.04 * sy)), _shifted(base, rng, 40),
                 max(1, int(0.004 * sx)))
        cv2.line(img, (int(cx - 0.025 * sx), int(cy + 0.065 * sy)), (int(cx + 0.025 * sx), int(cy + 0.065 * sy)), lips,
                 max(2, int(0.006 * sy)))
    else:  # hair
        base = given or _colour(rng, 10, 110)
        img[:] = base
        _lines(img, rng, 8 + width * height // 4000, [_jitter(base, rng, contrast // 2) for _ in range(3)], (1, 2))
    img = _grain(img, rng, 2.0)
    sigma = max(cfg.cloth.cloth_blur_m * tpm, 0.6)
    return cv2.GaussianBlur(img, (0, 0), sigma)
