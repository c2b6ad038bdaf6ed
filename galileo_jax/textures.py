"""Textures for rendered videos (:mod:`galileo_jax.render`): the checkered look of the objects
(:func:`checker_texture`), the skin of the hand (:func:`speckle_texture`) and the cluttered
backdrop wall of a lab (:func:`clutter_texture`). Each is an (h, w, 3) uint8 RGB image, the
same for the same seed.
"""

from __future__ import annotations

import cv2
import numpy as np


def checker_texture(rgb, n: int = 64, checks: int = 4, seed: int = 0) -> np.ndarray:
    """A checker texture with a random shade per square (breaks the periodicity for KLT).

    Args:
        rgb: (3,) base colour, 0..1.
        n: texture size in texels.
        checks: squares per side.
        seed: seed of the shade pattern.

    Returns:
        (n, n, 3) uint8 image.
    """
    rng = np.random.default_rng(seed)
    base = np.asarray(rgb, dtype=float)
    dark = 0.1 + 0.3 * base
    idx = np.arange(n) * checks // n
    parity = (idx[:, None] + idx[None, :]) % 2
    shade = rng.uniform(0.8, 1.15, size=(checks, checks))[idx[:, None], idx[None, :]]
    img = np.where(parity[..., None] == 0, base, dark) * shade[..., None]
    return np.clip(255 * img, 0, 255).astype(np.uint8)


def speckle_texture(rgb, n: int = 32, spot: float = 0.7, frac: float = 0.25, seed: int = 0) -> np.ndarray:
    """A skin/cloth texture: base colour with random darker texels ((n, n, 3) uint8)."""
    rng = np.random.default_rng(seed)
    base = np.asarray(rgb, dtype=float)
    img = np.broadcast_to(base, (n, n, 3)).copy()
    mask = rng.random((n, n)) < frac
    img[mask] *= spot
    img *= rng.uniform(0.95, 1.05, size=(n, n, 1))
    return np.clip(255 * img, 0, 255).astype(np.uint8)


#: Drawn items (posters, shelves, cables, blobs) per square metre of a cluttered backdrop.
CLUTTER_DENSITY = 40.0


#: Largest side of the cluttered backdrop's texture in texels.
MAX_TEXELS = 2048


def clutter_texture(width: int, height: int, texels_per_metre: float, seed: int = 0) -> np.ndarray:
    """A cluttered wall: posters, shelves with boxes, cables and blobs of varied size, colour and
    contrast on a light wall tone that darkens downwards.

    Args:
        width, height: texture size in texels.
        texels_per_metre: texels per metre of wall; items are sized in metres (1 cm to 1.2 m).
        seed: seed of the layout.

    Returns:
        (height, width, 3) uint8 RGB image.
    """
    rng = np.random.default_rng(seed)
    tone = rng.uniform(0.6, 0.9) * rng.uniform(0.85, 1.0, size=3)
    shade = np.linspace(1.05, 0.9, height)[:, None, None]
    wall = np.clip(255 * tone * shade, 0, 255).astype(np.uint8)
    img = np.ascontiguousarray(np.broadcast_to(wall, (height, width, 3)))
    count = int(np.clip(round(CLUTTER_DENSITY * width * height / texels_per_metre**2), 6, 400))
    painters = (_draw_poster, _draw_shelf, _draw_cable, _draw_blob)
    for kind in rng.choice(len(painters), size=count, p=(0.35, 0.1, 0.25, 0.3)):
        painters[kind](img, rng, texels_per_metre)
    return img


def _random_colour(rng: np.random.Generator, value=(20, 256), hue=(0, 180)) -> tuple[int, int, int]:
    """An RGB colour (0..255) of random hue, moderate saturation and brightness in ``value`` (OpenCV HSV ranges)."""
    hsv = np.uint8([[[rng.integers(*hue), rng.integers(0, 200), rng.integers(*value)]]])
    return tuple(int(c) for c in cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0])


def _random_point(img: np.ndarray, rng: np.random.Generator) -> tuple[int, int]:
    return int(rng.integers(0, img.shape[1])), int(rng.integers(0, img.shape[0]))


def _draw_poster(img: np.ndarray, rng: np.random.Generator, tpm: float) -> None:
    """A rectangle 4-45 cm with an inner picture and a few lines of 'text'."""
    w, h = (rng.uniform(0.04, 0.45, size=2) * tpm).astype(int) + 2
    x, y = _random_point(img, rng)
    cv2.rectangle(img, (x, y), (x + w, y + h), _random_colour(rng), -1)
    m = max(1, min(w, h) // 10)
    cv2.rectangle(img, (x + m, y + m), (x + w - m, y + h // 2), _random_colour(rng), -1)
    ink = _random_colour(rng, value=(0, 120))
    for k in range(int(rng.integers(0, 5))):
        yy = y + h // 2 + m + k * max(2, h // 10)
        cv2.line(img, (x + m, yy), (x + m + int(rng.uniform(0.3, 1.0) * (w - 2 * m)), yy), ink, max(1, h // 40))


def _draw_shelf(img: np.ndarray, rng: np.random.Generator, tpm: float) -> None:
    """A wooden board 0.3-1.2 m long with 1-5 boxes standing on it."""
    length, thick = int(rng.uniform(0.3, 1.2) * tpm), max(2, int(rng.uniform(0.012, 0.03) * tpm))
    x, y = _random_point(img, rng)
    cv2.rectangle(img, (x, y), (x + length, y + thick), _random_colour(rng, value=(60, 200), hue=(8, 22)), -1)
    for _ in range(int(rng.integers(1, 6))):
        bw, bh = (rng.uniform([0.03, 0.03], [0.15, 0.25]) * tpm).astype(int) + 1
        bx = x + int(rng.integers(0, max(1, length - bw)))
        cv2.rectangle(img, (bx, y - bh), (bx + bw, y), _random_colour(rng), -1)


def _draw_cable(img: np.ndarray, rng: np.random.Generator, tpm: float) -> None:
    """A dark cable 3-12 mm thick, hanging in a smooth wavy curve."""
    x, y = _random_point(img, rng)
    t = np.linspace(0.0, 1.0, 24)
    drop, sway = rng.uniform(0.1, 0.8) * tpm, rng.uniform(-0.3, 0.3) * tpm
    wave = rng.uniform(0.01, 0.08) * tpm * np.sin(2 * np.pi * rng.uniform(0.5, 2.5) * t + rng.uniform(0, 6.3))
    pts = np.stack([x + sway * t + wave, y + drop * t], axis=-1).round().astype(np.int32)
    cv2.polylines(img, [pts], False, _random_colour(rng, value=(0, 90)), max(1, int(rng.uniform(0.003, 0.012) * tpm)),
                  cv2.LINE_AA)


def _draw_blob(img: np.ndarray, rng: np.random.Generator, tpm: float) -> None:
    """A filled ellipse 1-12 cm across at a random angle."""
    axes = tuple(int(a) + 1 for a in rng.uniform(0.005, 0.06, size=2) * tpm)
    cv2.ellipse(img, _random_point(img, rng), axes, float(rng.uniform(0, 180)), 0, 360, _random_colour(rng), -1,
                cv2.LINE_AA)
