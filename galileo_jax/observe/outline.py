"""Tracking round objects by their outline (rolling spheres, a pipe seen end-on), whose
texture turns with them so that KLT features would turn away.

:func:`track_circles`: in each frame the strongest circle of the object's radius near its
predicted position (``cv2.HoughCircles``), refined to sub-pixel by a least-squares circle
through edge points found along rays from its centre.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from galileo_jax.errors import TrackingError
from galileo_jax.observe.tracks import Tracks, as_gray, inside_fraction, lost_message

# ---------------------------------------------------------------------------- rolling discs


def _circle_fit(pts: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Least-squares (Kasa) circle through (m, 2) points: centre (2,) and radius, or None."""
    if len(pts) < 8:
        return None
    A = np.column_stack([2 * pts, np.ones(len(pts))])
    b = (pts ** 2).sum(1)
    (cx, cy, c), *_ = np.linalg.lstsq(A, b, rcond=None)
    r2 = c + cx * cx + cy * cy
    return (np.array([cx, cy]), math.sqrt(r2)) if r2 > 0 else None


def _radial_edges(gray: np.ndarray, centre: np.ndarray, radius: float, n_rays: int = 72) -> np.ndarray:
    """(m, 2) sub-pixel points of the object's outline: on each of ``n_rays`` rays from
    ``centre``, the grey-level step between 0.7 and 1.3 radii (at least a third of the
    ray's strongest) nearest ``radius``, placed by a parabola through the peak. (A pipe's
    face and rim give two concentric steps; taking the one nearest the object's radius on
    every ray keeps to its outline.)"""
    angles = np.linspace(0, 2 * np.pi, n_rays, endpoint=False)
    radii = np.arange(0.7 * radius, 1.3 * radius, 0.25)
    dirs = np.column_stack([np.cos(angles), np.sin(angles)])
    xy = centre[None, None] + radii[None, :, None] * dirs[:, None]
    prof = cv2.remap(gray, xy[..., 0].astype(np.float32), xy[..., 1].astype(np.float32), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)
    grad = np.abs(np.gradient(prof, axis=1))
    h, w = gray.shape
    inside = ((xy[..., 0] >= 0) & (xy[..., 0] <= w - 1) & (xy[..., 1] >= 0) & (xy[..., 1] <= h - 1)).all(axis=1)
    pts = []
    for j in np.flatnonzero(inside):  # rays that leave the image would see a fake edge
        g = grad[j]
        strong = np.flatnonzero((g[1:-1] >= g.max() / 3) & (g[1:-1] >= g[:-2]) & (g[1:-1] >= g[2:])) + 1
        if g.max() <= 2.0 or not len(strong):
            continue
        i = strong[np.argmin(np.abs(radii[strong] - radius))]
        den = g[i - 1] - 2 * g[i] + g[i + 1]
        off = 0.5 * (g[i - 1] - g[i + 1]) / den if den < 0 else 0.0
        pts.append(centre + (radii[i] + 0.25 * off) * dirs[j])
    return np.array(pts).reshape(-1, 2)


def _refine_circle(gray: np.ndarray, centre: np.ndarray, radius: float, first_radius: float) -> np.ndarray:
    """Sub-pixel centre: least-squares circle through the outline points, refitted without
    the points that miss it by more than 1.5 px or 3 robust SDs. The first round takes on
    each ray the step nearest ``first_radius`` (the Hough circle's, which may be a pipe's
    inner face: concentric, so its centre is as good), the next two the step nearest the
    object's ``radius``, with the rays cast again from the new centre."""
    c = np.asarray(centre, float)
    for r_pick in (first_radius, radius, radius):
        pts = _radial_edges(gray, c, r_pick)
        keep = np.ones(len(pts), bool)
        for _ in range(2):
            fit = _circle_fit(pts[keep])
            if fit is None or np.linalg.norm(fit[0] - centre) > 0.3 * radius or abs(fit[1] - r_pick) > 0.3 * radius:
                return c
            res = np.abs(np.linalg.norm(pts - fit[0], axis=1) - fit[1])
            keep = res <= max(1.5, 3 * 1.4826 * float(np.median(res[keep])))
        c = fit[0]
    return c


def _find_circle(gray: np.ndarray, predicted: np.ndarray, radius: float, gate: float) -> np.ndarray | None:
    """The strongest circle of about ``radius`` px within ``gate`` px of ``predicted``, its
    centre refined to sub-pixel on its outline; None if there is none."""
    reach = int(math.ceil(1.3 * radius + gate))
    lo = np.maximum(np.floor(predicted).astype(int) - reach, 0)
    hi = np.minimum(np.floor(predicted).astype(int) + reach + 1, gray.shape[::-1])
    if np.any(hi - lo < radius):
        return None
    crop = cv2.GaussianBlur(gray[lo[1]:hi[1], lo[0]:hi[0]], (5, 5), 1.5)
    found = cv2.HoughCircles(crop, cv2.HOUGH_GRADIENT, dp=1, minDist=3, param1=60, param2=12,
                             minRadius=max(3, int(0.7 * radius)), maxRadius=int(math.ceil(1.25 * radius)))
    if found is None:
        return None
    cands = found[0][:, :2] + lo  # strongest first
    near = np.flatnonzero(np.linalg.norm(cands - predicted, axis=1) <= gate)
    if not len(near):
        return None
    j = int(near[0])
    smooth = cv2.GaussianBlur(gray[lo[1]:hi[1], lo[0]:hi[0]].astype(np.float32), (0, 0), 1.0)
    return _refine_circle(smooth, cands[j] - lo, radius, float(found[0][j, 2])) + lo


def track_circles(frames: np.ndarray, start_pixels, radii, *, fps: float | None = None,
                  progress: bool = False, on_loss: str = "raise", first_frame: int = 0) -> Tracks:
    """Track rolling round objects (a sphere or a pipe seen end-on) by their outline.

    KLT features on a rolling object turn with it, by tens of degrees per frame once it is
    fast, and are lost; the outline does not turn. In each frame the circle of the
    object's radius nearest the constant-velocity prediction is found by a Hough
    transform in a window around it, and its centre is refined to sub-pixel by a robust
    least-squares circle fit to its outline (the grey-level step nearest the object's
    radius on 72 rays).

    Args:
        frames: (N, H, W, 3) uint8 BGR or (N, H, W) grey frames.
        start_pixels: (n, 2) centre (u, v) of each object in frame 0, px.
        radii: (n,) image radius of each object, px.
        fps: frame rate, for the times in error messages.
        progress: show a progress bar.
        on_loss, first_frame: as for :func:`track_objects`.

    Returns:
        :class:`Tracks` (``n_features`` is 1 where the circle was found, 0 where the
        position was predicted over a one-frame gap).

    Raises:
        TrackingError: the circle is missing in two frames running inside the image.
    """
    start = np.asarray(start_pixels, float).reshape(-1, 2)
    radii = np.broadcast_to(np.asarray(radii, float), (len(start),))
    N, n = len(frames), len(start)
    pixels = np.repeat(start[None], N, axis=0)
    valid = np.zeros((N, n), bool)
    count = np.zeros((N, n), int)
    valid[0], count[0] = True, 1
    # Frame 0 is measured like every other frame, on the outline: the start pixel may come from
    # another estimator (the motion-based locator's silhouette), and a centre a few px off in
    # that one frame alone is a spike in two velocity samples at the release (measured on 5
    # rendered rolling videos: 2-3.4 px, up to 0.06 m/s, in every one of them).
    gray0 = as_gray(frames[0])
    for i in range(n):
        found = _find_circle(gray0, start[i], radii[i], max(0.25 * radii[i], 3.0))
        if found is not None:
            pixels[:, i] = found
    velocity, misses, alive = np.zeros((n, 2)), np.zeros(n, int), np.ones(n, bool)
    steps = range(1, N)
    if progress:
        from tqdm import tqdm
        steps = tqdm(steps, desc="tracking", unit="frame")
    for k in steps:
        gray = as_gray(frames[k])
        for i in np.flatnonzero(alive):
            predicted = pixels[k - 1, i] + velocity[i]
            box = np.array([predicted - radii[i], predicted + radii[i]])
            if inside_fraction(box, gray.shape) < 0.5:
                alive[i] = False
                pixels[k:, i] = pixels[k - 1, i]
                continue
            gate = max(0.5 * radii[i], 0.5 * np.linalg.norm(velocity[i]), 3.0)
            found = _find_circle(gray, predicted, radii[i], gate)
            if found is None:
                misses[i] += 1
                if misses[i] >= 2 and on_loss == "raise":
                    raise TrackingError(lost_message(i, k + first_frame, fps, 0), object_index=i)
                if misses[i] >= 2:
                    alive[i] = False
                    pixels[k:, i] = pixels[k - 1, i]
                    continue
                pixels[k, i] = predicted
                continue
            misses[i] = 0
            velocity[i] = found - pixels[k - 1, i]
            pixels[k, i], valid[k, i], count[k, i] = found, True, 1
    return Tracks(pixels, valid, count, valid.astype(float))


