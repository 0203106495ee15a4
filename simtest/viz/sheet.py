"""Laying out pictures: titled panels, rows, contact-sheet grids, legends, and writing PNG files.

Pictures are RGB uint8 (H, W, 3); sizes are canvas pixels. Text is OpenCV's Hershey simplex font at
:data:`FONT_SCALE` (about 12 px high), legible on a 640 px wide panel.
"""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from simtest.io.files import atomic_write_bytes

__all__ = ["FONT_SCALE", "BG", "upscale_factor", "upscale", "text_strip", "titled", "hstack", "vstack", "grid",
           "legend_strip", "save_png", "fit_width"]

#: Font scale of every caption and label (Hershey simplex, thickness 1).
FONT_SCALE = 0.5
#: Page background (RGB).
BG = (24, 24, 28)
_LINE_H = 18
_GAP = 6


def upscale_factor(width: int, height: int, min_height: int = 480) -> int:
    """The integer factor that brings a ``width`` x ``height`` image to at least ``min_height`` rows
    (1 for images that already have them): small images are enlarged so labels stay legible."""
    return max(1, int(np.ceil(min_height / max(1, int(height)))))


def upscale(img: np.ndarray, factor: int, nearest: bool = False) -> np.ndarray:
    """``img`` enlarged ``factor`` times (linear, or nearest neighbour for label-like pictures)."""
    if int(factor) == 1:
        return np.ascontiguousarray(img).copy()
    return cv2.resize(img, None, fx=int(factor), fy=int(factor),
                      interpolation=cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR)


def _char_width() -> float:
    (w, _), _ = cv2.getTextSize("abcdefghijklmnopqrstuvwxyz", cv2.FONT_HERSHEY_SIMPLEX, FONT_SCALE, 1)
    return w / 26.0


def text_strip(lines: Sequence[str | tuple[str, tuple[int, int, int]]], width: int,
               colour=(235, 235, 235)) -> np.ndarray:
    """A strip ``width`` wide holding ``lines`` (each a string or ``(string, rgb)``), wrapped to the width."""
    chars = max(8, int((width - 8) / _char_width()))
    rows: list[tuple[str, tuple[int, int, int]]] = []
    for item in lines:
        text, col = (item, colour) if isinstance(item, str) else item
        rows += [(r, col) for r in (textwrap.wrap(text, chars) or [""])]
    out = np.full((len(rows) * _LINE_H + 4, width, 3), BG, dtype=np.uint8)
    for i, (text, col) in enumerate(rows):
        cv2.putText(out, text, (4, 14 + i * _LINE_H), cv2.FONT_HERSHEY_SIMPLEX, FONT_SCALE, col, 1, cv2.LINE_AA)
    return out


def titled(img: np.ndarray, title: str | None = None, lines: Sequence = ()) -> np.ndarray:
    """``img`` with ``title`` above it and ``lines`` (wrapped) below it."""
    parts = []
    if title:
        parts.append(text_strip([title], img.shape[1]))
    parts.append(img)
    if lines:
        parts.append(text_strip(lines, img.shape[1]))
    return np.vstack(parts)


def _pad(img: np.ndarray, h: int, w: int) -> np.ndarray:
    out = np.full((h, w, 3), BG, dtype=np.uint8)
    out[:img.shape[0], :img.shape[1]] = img
    return out


def hstack(images: Sequence[np.ndarray], gap: int = _GAP) -> np.ndarray:
    """Pictures side by side, tops aligned, ``gap`` pixels apart."""
    h = max(i.shape[0] for i in images)
    parts = []
    for k, img in enumerate(images):
        if k:
            parts.append(np.full((h, gap, 3), BG, dtype=np.uint8))
        parts.append(_pad(img, h, img.shape[1]))
    return np.hstack(parts)


def vstack(images: Sequence[np.ndarray], gap: int = _GAP) -> np.ndarray:
    """Pictures one above the other, left edges aligned, ``gap`` pixels apart."""
    w = max(i.shape[1] for i in images)
    parts = []
    for k, img in enumerate(images):
        if k:
            parts.append(np.full((gap, w, 3), BG, dtype=np.uint8))
        parts.append(_pad(img, img.shape[0], w))
    return np.vstack(parts)


def fit_width(img: np.ndarray, width: int) -> np.ndarray:
    """``img`` shrunk (area interpolation) to ``width`` pixels when wider, else unchanged."""
    if img.shape[1] <= width:
        return img
    h = int(round(img.shape[0] * width / img.shape[1]))
    return cv2.resize(img, (int(width), h), interpolation=cv2.INTER_AREA)


def grid(cards: Sequence[np.ndarray], cols: int, gap: int = 2 * _GAP) -> np.ndarray:
    """A contact sheet: ``cards`` in rows of ``cols``, each cell as large as the largest card."""
    cols = max(1, min(int(cols), len(cards)))
    h = max(c.shape[0] for c in cards)
    w = max(c.shape[1] for c in cards)
    rows = [hstack([_pad(c, h, w) for c in cards[i:i + cols]], gap) for i in range(0, len(cards), cols)]
    return vstack(rows, gap)


def legend_strip(items: Sequence[tuple[tuple[int, int, int], str, str]], width: int) -> np.ndarray:
    """One line of legend entries ``(rgb, label, style)``, style ``"solid"``, ``"dashed"`` or ``"box"``."""
    out = np.full((26, width, 3), BG, dtype=np.uint8)
    x = 6
    for col, label, style in items:
        if style == "dashed":
            for k in range(0, 24, 8):
                cv2.line(out, (x + k, 13), (x + k + 4, 13), col, 2)
        elif style == "box":
            cv2.rectangle(out, (x, 6), (x + 22, 20), col, 1)
        else:
            cv2.line(out, (x, 13), (x + 22, 13), col, 2)
        cv2.putText(out, label, (x + 30, 18), cv2.FONT_HERSHEY_SIMPLEX, FONT_SCALE, (235, 235, 235), 1, cv2.LINE_AA)
        (tw, _), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, FONT_SCALE, 1)
        x += 30 + tw + 18
        if x > width - 40:
            break
    return out


def save_png(path: str | Path, img: np.ndarray, palette: bool = False) -> Path:
    """Write ``img`` (RGB) as a PNG at ``path`` (atomically; parent folders created); ``palette``: as a
    256-colour PNG (Pillow's fast octree quantizer), a fraction of the size, for documents."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if palette:
        import io

        from PIL import Image

        buf = io.BytesIO()
        Image.fromarray(np.ascontiguousarray(img)).quantize(256, method=Image.Quantize.FASTOCTREE).save(
            buf, format="PNG", optimize=True)
        atomic_write_bytes(path, buf.getvalue())
        return path
    ok, enc = cv2.imencode(".png", np.ascontiguousarray(img[..., ::-1]), [cv2.IMWRITE_PNG_COMPRESSION, 6])
    if not ok:
        raise OSError(f"cannot encode a PNG of shape {img.shape}")
    atomic_write_bytes(path, enc.tobytes())
    return path
