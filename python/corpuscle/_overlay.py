"""Text and colour-bar overlays drawn over rendered frames (Pillow for glyphs, NumPy to blend)."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from . import _colors


@lru_cache(maxsize=8)
def font(size: int):
    """Pillow's built-in scalable font at ``size`` pixels (bitmap fallback without FreeType)."""
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1
        return ImageFont.load_default()


def plain(text: str) -> str:
    """Text with superscripts spelled out (the built-in font lacks them)."""
    return text.replace("²", "^2").replace("³", "^3")


def text_mask(text: str, size: int) -> np.ndarray:
    """Coverage (h, w) in [0, 1] of ``text`` set in the overlay font."""
    from PIL import Image, ImageDraw

    f = font(size)
    x0, y0, x1, y1 = f.getbbox(text)
    img = Image.new("L", (max(1, x1 - min(x0, 0) + 2), max(1, y1 - min(y0, 0) + 2)), 0)
    ImageDraw.Draw(img).text((1 - min(x0, 0), 1 - min(y0, 0)), text, font=f, fill=255)
    return np.asarray(img, dtype=np.float32) / 255.0


def blend_mask(img: np.ndarray, mask: np.ndarray, x: int, y: int, color, opacity: float = 1.0) -> None:
    """Blend ``color`` into ``img`` through coverage ``mask`` with its top-left corner at (x, y)."""
    h, w = mask.shape
    x0, y0, x1, y1 = max(x, 0), max(y, 0), min(x + w, img.shape[1]), min(y + h, img.shape[0])
    if x0 >= x1 or y0 >= y1:
        return
    a = (mask[y0 - y:y1 - y, x0 - x:x1 - x] * opacity)[..., None]
    region = img[y0:y1, x0:x1].astype(np.float32)
    img[y0:y1, x0:x1] = (region + a * (np.asarray(color, np.float32) - region) + 0.5).astype(np.uint8)


def shade_box(img: np.ndarray, x0: int, y0: int, x1: int, y1: int, opacity: float = 0.55) -> None:
    """Darken a rectangle so overlay text stays readable over bright particles."""
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, img.shape[1]), min(y1, img.shape[0])
    if x0 < x1 and y0 < y1:
        img[y0:y1, x0:x1] = (img[y0:y1, x0:x1].astype(np.float32) * (1 - opacity)).astype(np.uint8)


def draw_text(img: np.ndarray, text: str, x: int, y: int, size: int, color=(240, 240, 240), box: bool = True) -> tuple[int, int]:
    """Draw ``text`` at (x, y) over a darkened box; returns its (width, height)."""
    m = text_mask(plain(text), size)
    if box:
        shade_box(img, x - 4, y - 3, x + m.shape[1] + 4, y + m.shape[0] + 3)
    blend_mask(img, m, x, y, color)
    return m.shape[1], m.shape[0]


def format_tick(v: float) -> str:
    """A compact tick label (at most 8 characters for a positive value: 73,868.9 is
    "7.39e+04", not "7.387e+04", which the colour-bar panel cuts off)."""
    if v == 0 or 1e-3 <= abs(v) < 1e4:
        return f"{v:.4g}"
    return f"{v:.2e}"


# width in pixels reserved on the right for the colour bar and its labels
def colorbar_width(height: int) -> int:
    """Width of the colour-bar panel for a frame of this height."""
    return max(70, int(round(0.13 * height)))


def draw_colorbar(img: np.ndarray, lut: np.ndarray, lo: float, hi: float, log: bool, label: str) -> None:
    """A vertical colour bar at the right edge: ramp, its field range in field units, the label."""
    h, w = img.shape[:2]
    pw = colorbar_width(h)
    size = max(10, int(round(h / 50)))
    bar_w = max(10, pw // 6)
    top, bottom = int(0.12 * h), int(0.88 * h)
    x0 = w - pw + max(6, pw // 10)
    # the ramp, high values at the top
    rows = bottom - top
    k = np.minimum(((1.0 - (np.arange(rows) + 0.5) / rows) * len(lut)).astype(int), len(lut) - 1)
    img[top:bottom, x0:x0 + bar_w] = lut[k][:, None, :]
    img[top - 1:bottom + 1, [x0 - 1, x0 + bar_w]] = 200
    img[[top - 1, bottom], x0 - 1:x0 + bar_w + 1] = 200
    # ticks at both ends and the middle of the transformed range, labelled in field units
    for frac in (0.0, 0.5, 1.0):
        t = lo + frac * (hi - lo)
        v = float(_colors.inverse_transform(t, log))
        y = int(round(bottom - frac * rows))
        img[y, x0 + bar_w:x0 + bar_w + 4] = 220
        m = text_mask(format_tick(v), size)
        blend_mask(img, m, x0 + bar_w + 6, y - m.shape[0] // 2, (230, 230, 230))
    # the field name and units above the bar
    m = text_mask(plain(label), size)
    blend_mask(img, m, min(x0, w - m.shape[1] - 2), top - m.shape[0] - size // 2, (235, 235, 235))
