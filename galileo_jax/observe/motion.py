"""Steady motion along the ramp in dense optical flow: how the object finder
(:mod:`galileo_jax.observe.find`) sees object 1 start to slide.

Frames are downscaled to :data:`WORK_SIZE` px (:func:`downscale`); between consecutive frames,
the regions whose Farneback flow points along the ramp's image direction (:func:`moving_blobs`)
are chained from frame to frame, and :func:`first_motion` returns the first chain that lasts a
few frames, keeps to the direction and did not enter at the image border (a hand or arm).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np

from galileo_jax.observe.tracks import as_gray

#: Longest side (px) of the downscaled frames used for motion detection.
WORK_SIZE = 640


#: A moving pixel's flow must be within this angle (deg) of the expected direction.
MAX_ANGLE_DEG = 40.0


class Small(NamedTuple):
    """Downscaled grey frames for motion detection; ``f`` = small px per full px."""

    gray: np.ndarray
    f: float

    def to_full(self, uv) -> np.ndarray:
        return (np.asarray(uv, float) + 0.5) / self.f - 0.5

    def to_small(self, uv) -> np.ndarray:
        return (np.asarray(uv, float) + 0.5) * self.f - 0.5


def downscale(frames: np.ndarray) -> Small:
    h, w = frames.shape[1:3]
    f = min(1.0, WORK_SIZE / max(h, w))
    size = (max(1, round(w * f)), max(1, round(h * f)))
    gray = np.stack([cv2.resize(as_gray(fr), size, interpolation=cv2.INTER_AREA) if f < 1 else as_gray(fr)
                     for fr in frames])
    return Small(gray, size[0] / w)


class Blob(NamedTuple):
    centroid: np.ndarray  # (2,) small px
    area: float
    flow: np.ndarray  # (2,) mean flow, small px / frame
    border: bool
    front: np.ndarray  # (2,) centroid of its leading part (one object deep), small px


def _changed(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(h, w) bool: pixels near a real change between two grey frames (above the noise),
    grown by a few pixels so that flat patches inside a moving object count too."""
    d = cv2.absdiff(a, b)
    noise = 1.4826 * float(np.median(d)) + 1.0
    changed = (d > max(6.0, 4.0 * noise)).astype(np.uint8)
    return cv2.dilate(changed, np.ones((7, 7), np.uint8)) > 0


def moving_blobs(flow: np.ndarray, direction: np.ndarray, allowed: np.ndarray, min_speed: float,
                  min_area: float, offset: np.ndarray, depth: float = np.inf) -> list[Blob]:
    """Connected regions (of ``allowed`` pixels) whose optical flow points along ``direction``
    (within :data:`MAX_ANGLE_DEG`) faster than ``min_speed`` px/frame, at least ``min_area`` px;
    ``front`` is the centroid of a region's pixels within ``depth`` px of its leading point
    along ``direction`` (the object itself, where a hand that lifts off trails it)."""
    along = flow @ direction
    speed = np.linalg.norm(flow, axis=-1)
    mask = ((along > min_speed) & (along >= math.cos(math.radians(MAX_ANGLE_DEG)) * speed) & allowed).astype(np.uint8)
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, labels, stats, cents = cv2.connectedComponentsWithStats(mask, connectivity=8)
    h, w = mask.shape
    blobs = []
    for j in range(1, n):
        x, y, bw, bh, area = stats[j]
        if area < min_area:
            continue
        sel = labels == j
        border = x == 0 or y == 0 or x + bw >= w or y + bh >= h
        ys, xs = np.nonzero(sel)
        proj = xs * direction[0] + ys * direction[1]
        lead = proj >= proj.max() - depth
        front = np.array([xs[lead].mean(), ys[lead].mean()])
        blobs.append(Blob(cents[j] + offset, float(area), flow[sel].mean(0), bool(border), front + offset))
    return blobs


def roi_box(shape, centre, radius) -> tuple[np.ndarray, np.ndarray]:
    h, w = shape
    if centre is None:
        return np.array([0, 0]), np.array([w, h])
    lo = np.maximum(np.floor(np.asarray(centre) - radius).astype(int), 0)
    hi = np.minimum(np.ceil(np.asarray(centre) + radius).astype(int) + 1, [w, h])
    return lo, hi


def dense_flow(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return cv2.calcOpticalFlowFarneback(a, b, None, 0.5, 3, 15, 3, 5, 1.2, 0)


def _extends(chain: list[Blob], blob: Blob, direction: np.ndarray, gate: float) -> bool:
    last = chain[-1]
    predicted = last.centroid + last.flow
    close = np.linalg.norm(blob.centroid - predicted) <= max(gate, 2 * np.linalg.norm(last.flow))
    return bool(close and (blob.centroid - last.centroid) @ direction >= -1.0)


def _on_path(chain: list[Blob], direction: np.ndarray) -> bool:
    """The blob moved along ``direction`` (not off it) over the chain."""
    d = chain[-1].centroid - chain[0].centroid
    along = d @ direction
    across = abs(d @ np.array([-direction[1], direction[0]]))
    return bool(along > -1.0 and across <= 0.5 * max(along, 0.0) + 2.0)


class Start(NamedTuple):
    """A steady motion found (:func:`first_motion`): its first frame and centroid (small
    px), and a later frame and centroid of the same moving region, as far from the first as
    asked (clear of a hand that held it), or the chain's last if it ended sooner."""

    k: int
    centroid: np.ndarray
    k_far: int
    centroid_far: np.ndarray


def blobs_at(small: Small, k: int, lo, hi, direction, min_speed, min_area, exclude, depth=np.inf
              ) -> list[Blob] | None:
    a = small.gray[k, lo[1]:hi[1], lo[0]:hi[0]]
    b = small.gray[k + 1, lo[1]:hi[1], lo[0]:hi[0]]
    if a.size == 0:
        return None
    allowed = _changed(a, b)
    if exclude is not None:
        allowed &= ~exclude(k)[lo[1]:hi[1], lo[0]:hi[0]]
    return moving_blobs(dense_flow(a, b), direction, allowed, min_speed, min_area, lo.astype(float), depth)


def first_motion(small: Small, direction, centre, radius, min_area, k_start: int = 0,
                  exclude=None, min_speed: float = 0.4, run: int = 3, away: float = 0.0, depth: float = np.inf
                  ) -> Start | None:
    """First frame at which a region starts a steady motion along ``direction``.

    Dense (Farneback) flow between consecutive downscaled frames, inside a square of
    ``radius`` (small px) around ``centre`` (or everywhere); moving regions are chained
    from frame to frame. A chain counts once it lasts ``run`` frames, keeps to the
    direction and did not start at the image border (a hand or arm entering or leaving the
    picture). ``exclude(k)`` may return a (h, w) bool mask of small pixels to ignore. The
    chain found is then followed on until its region is ``away`` small px from where it
    started (at most 20 frames more); its position there is the centroid of its leading part,
    ``depth`` small px deep (the object's length).

    Returns:
        :class:`Start`, or None.
    """
    lo, hi = roi_box(small.gray.shape[1:], centre, radius)
    chains: list[list[Blob]] = []
    gate = max(6.0, math.sqrt(min_area))
    for k in range(k_start, len(small.gray) - 1):
        blobs = blobs_at(small, k, lo, hi, direction, min_speed, min_area, exclude, depth)
        if blobs is None:
            return None
        grown, used = [], set()
        for chain in chains:
            match = [j for j, bl in enumerate(blobs) if _extends(chain, bl, direction, gate)]
            if match:
                j = max(match, key=lambda j: blobs[j].area)
                used.add(j)
                grown.append(chain + [blobs[j]])
        grown += [[bl] for j, bl in enumerate(blobs) if j not in used and not bl.border]
        for chain in grown:
            if len(chain) >= run and _on_path(chain, direction):
                return _follow_on(small, chain, k, lo, hi, direction, min_speed, min_area, exclude, gate, away,
                                  depth)
        chains = [c for c in grown if len(c) < run or _on_path(c, direction)]
    return None


def _follow_on(small: Small, chain: list[Blob], k: int, lo, hi, direction, min_speed, min_area, exclude, gate,
               away: float, depth: float) -> Start:
    """:class:`Start` of a confirmed ``chain`` whose last blob is in frame ``k``, extended
    until it is ``away`` small px from its first blob."""
    k_first = k - len(chain) + 1
    while np.linalg.norm(chain[-1].centroid - chain[0].centroid) < away and k + 1 < len(small.gray) - 1 \
            and k < k_first + len(chain) + 20:
        blobs = blobs_at(small, k + 1, lo, hi, direction, min_speed, min_area, exclude, depth)
        match = [bl for bl in blobs or [] if _extends(chain, bl, direction, gate)]
        if not match:
            break
        chain = chain + [max(match, key=lambda bl: bl.area)]
        k += 1
    return Start(k_first, chain[0].centroid, k, chain[-1].front)
