"""One object's centre in one frame from its colour matte (:func:`measure`): the matte's
centroid in the object's footprint, and where part of it is hidden or contradicted, the clean
template aligned to the usable pixels (:func:`align`, Lucas & Kanade 1981, translation only)
standing in for the hidden part.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np

from galileo_jax.observe.colour import CROSS, ColourBackground, Look, matte, place_template
from galileo_jax.observe.tracks import crop_box, footprint, weighted_centroid

#: Unusable pixels (occluded or without contrast) in the footprint above which the centre comes
#: from aligning the template instead of the centroid.
OCCLUSION_MAX = 0.03


#: A frame whose matte around the object holds no unusable pixel and this close to the
#: object's clean area (relative) is measured by the plain centroid, without the template.
CLEAN_SEEN = 0.03


#: Share of the object's clean area that must be wholly its colour (at some gain) for the
#: matte to take the frame's light level from it (:func:`~galileo_jax.observe.colour.light_level`);
#: a motion-blurred object with less is matted with any gain within
#: :data:`~galileo_jax.observe.colour.GAIN`.
LIGHT_SHARE = 0.4


class Measurement(NamedTuple):
    """One object in one frame.

    Attributes:
        centre: (2,) centre (u, v) in px (NaN when not found).
        quality: in [0, 1]; 0 when not found.
        seen: matte area seen over the object's area (about 1 for a clean frame).
        unusable: fraction of the footprint that was occluded or without contrast.
        aligned: True if the centre came from aligning the template (occlusion), False if
            from the centroid.
    """

    centre: np.ndarray
    quality: float
    seen: float
    unusable: float
    aligned: bool


NOT_FOUND = Measurement(np.full(2, np.nan), 0.0, 0.0, 1.0, False)


def _gradient(image: np.ndarray) -> np.ndarray:
    """(2, h, w) derivatives (d/du, d/dv) of an (h, w) image, as ``np.gradient`` takes them
    (central differences inside, one-sided at the border), without its overhead."""
    g = np.empty((2,) + image.shape, image.dtype)
    gu, gv = g
    gu[:, 1:-1] = (image[:, 2:] - image[:, :-2]) * 0.5
    gu[:, 0], gu[:, -1] = image[:, 1] - image[:, 0], image[:, -1] - image[:, -2]
    gv[1:-1] = (image[2:] - image[:-2]) * 0.5
    gv[0], gv[-1] = image[1] - image[0], image[-1] - image[-2]
    return g


def align(alpha: np.ndarray, usable: np.ndarray, look: Look, angle: float, start, iters: int = 12
          ) -> tuple[np.ndarray, np.ndarray]:
    """Translate the object's template over a matte, using only the usable pixels.

    Gauss-Newton on sum_x usable(x) (alpha(x) - T(x - c))^2 over the centre c (Lucas &
    Kanade 1981, translation only; the template is turned to ``angle``).

    Args:
        alpha: (h, w) matte (crop coordinates).
        usable: (h, w) bool, pixels that may be compared.
        look: the object's :class:`~galileo_jax.observe.colour.Look`.
        angle: the object's tilt in the image (rad).
        start: (2,) first guess of the centre (crop px).
        iters: Gauss-Newton steps at most.

    Returns:
        ``(centre, placed)``: the centre (2,) in crop px and the template placed there
        (alpha's shape).
    """
    c = np.asarray(start, float).copy()
    w = usable.astype(np.float32).ravel()
    a = alpha.ravel()
    for _ in range(iters):
        T = place_template(look.template, look.centre, angle, c, alpha.shape)
        G = _gradient(T).reshape(2, -1)  # (gx, gy) per pixel
        Gw = G * w
        (sxx, sxy), (_, syy) = (Gw @ G.T).tolist()
        bx, by = (-(Gw @ (a - T.ravel()))).tolist()
        # the 2x2 normal equations in closed form (their condition number from the eigenvalues)
        mean, dev = 0.5 * (sxx + syy), math.hypot(0.5 * (sxx - syy), sxy)
        if mean - dev <= 0.0 or (mean + dev) / (mean - dev) > 1e6:
            break
        det = sxx * syy - sxy * sxy
        step = np.clip([(syy * bx - sxy * by) / det, (sxx * by - sxy * bx) / det], -3.0, 3.0)
        c += step
        if np.abs(step).max() < 0.005:
            break
    return c, place_template(look.template, look.centre, angle, c, alpha.shape)


def _streak(radius: float, length: float, angle: float) -> np.ndarray:
    """Structuring element: a disc of ``radius`` px swept along a segment of ``length`` px at
    ``angle`` rad (how far a motion-blurred edge reaches), centred."""
    r = max(int(round(radius)), 1)
    half = 0.5 * length
    ext = int(math.ceil(half)) + r
    size = 2 * ext + 1
    k = np.zeros((size, size), np.uint8)
    d = np.array([math.cos(angle), math.sin(angle)]) * half
    p0 = np.round((ext - d) * 4).astype(int)
    p1 = np.round((ext + d) * 4).astype(int)
    cv2.line(k, tuple(map(int, p0)), tuple(map(int, p1)), 1, thickness=2 * r + 1, lineType=cv2.LINE_8, shift=2)
    cv2.circle(k, (ext, ext), r, 1, -1)
    return k


def measure(frame: np.ndarray, background: ColourBackground, look: Look, guess, half, angle: float,
            margin: float = 3.0, blur: float = 0.0, keep_out=(), refine: int = 10) -> Measurement:
    """Measure one object's centre in one frame (:mod:`galileo_jax.observe.matte`).

    First the alpha-weighted centroid of the matte in the object's footprint (grown by
    ``margin``), re-centred until it settles. Then the object's clean template is aligned to
    the usable pixels (:func:`align`) and pixels that contradict it are marked *bad*: matte
    well outside the template's outline (a hand's fingers, a shadow of the object's colour),
    matte missing well inside it (an occluder explained as background), and unusable pixels
    (occluders, no contrast); the alignment is repeated without them. The centre is the
    centroid of the matte with the bad pixels replaced by the aligned template: in a clean
    frame exactly the first centroid, and where part of the object is hidden, the centroid
    the object would have if it were seen whole.

    Args:
        frame: (H, W, 3) uint8 BGR frame.
        background: the video's :class:`~galileo_jax.observe.colour.ColourBackground`.
        look: the object's :class:`~galileo_jax.observe.colour.Look` (colours, clean template).
        guess: (2,) its approximate centre (px).
        half: (2,) half sizes (along, across) of its footprint (px).
        angle: its tilt in the image (rad, the footprint's along axis from the u axis).
        margin: px added around the footprint for the measurement (motion blur, the guess's
            error).
        blur: the longest motion blur expected (px, the object's speed per frame): matte
            within half of it along the footprint's axis (and 1.5 px across) of the
            template's outline is never bad.
        keep_out: (centre, half, angle) of each other object near it: its footprint counts
            as occluding this one (the part of this object there is the template's).
        refine: centroids at most, each in the region re-centred on the last (until it
            moves by less than 0.01 px).

    Returns:
        :class:`Measurement` (:data:`NOT_FOUND` when the region holds no matte). Its quality
        is the share of the template's mass seen on good pixels times 1 - |1 - seen| (seen:
        the matte's mass on good pixels over the template's there).
    """
    reach = math.hypot(*half) + margin + 2 + 0.5 * blur
    box = crop_box(frame.shape, guess, reach + 3)
    if box is None:
        return NOT_FOUND
    lo, hi = box
    img = frame[lo[1]:hi[1], lo[0]:hi[0]].astype(np.float32)
    alpha, unusable = matte(img, background.image[lo[1]:hi[1], lo[0]:hi[0]], look.palette, background.noise_sd,
                            min_lit=LIGHT_SHARE * look.area)
    hidden = np.zeros(alpha.shape, bool)  # under another object's footprint: not this one's
    for other_centre, other_half, other_angle in keep_out:
        hidden |= footprint(alpha.shape, other_centre, other_half, other_angle, offset=lo)
    alpha[hidden] = 0.0
    unusable |= hidden
    centre = np.asarray(guess, float) - lo
    region = None
    for _ in range(refine):
        region = footprint(alpha.shape, centre + lo, half, angle, grow=margin, offset=lo)
        found = weighted_centroid(np.where(region, alpha, 0.0))
        if found is None:
            return NOT_FOUND
        shift = float(np.abs(found - centre).max())
        centre = found
        if shift < 0.01:
            break
    if region is None:
        return NOT_FOUND
    seen = float(np.where(region, alpha, 0.0).sum()) / look.area
    if abs(1.0 - seen) <= CLEAN_SEEN and not (unusable & region).any():  # a clean frame: the centroid as it is
        return Measurement(centre + lo, 1.0 - abs(1.0 - seen), seen, 0.0, False)
    near_k = _streak(1.5, blur, angle)  # blur runs along the motion (about the footprint's axis)
    bad = unusable.copy()
    c = centre
    for _ in range(3):
        c, T = align(alpha, ~bad, look, angle, c)
        support = (T > 0.5).astype(np.uint8)
        near = cv2.dilate(support, near_k) > 0
        core = cv2.erode(support, near_k) > 0
        wrong = ((alpha > 0.35) & ~near) | ((alpha < T - 0.35) & core)
        wrong = cv2.morphologyEx(wrong.astype(np.uint8), cv2.MORPH_OPEN, CROSS) > 0
        new_bad = unusable | wrong
        if np.array_equal(new_bad, bad):
            break
        bad = new_bad
    T = place_template(look.template, look.centre, angle, c, alpha.shape)
    near = cv2.dilate((T > 0.01).astype(np.uint8), near_k) > 0
    filled = np.where(near, np.where(bad, T, alpha), 0.0)
    found = weighted_centroid(filled)
    if found is None:
        return NOT_FOUND
    mass = float(T.sum())
    good_mass = float(T[~bad].sum())
    observed = good_mass / mass if mass > 0 else 0.0
    seen = float(alpha[near & ~bad].sum()) / max(good_mass, 1e-6)
    bad_share = float(T[bad].sum()) / mass if mass > 0 else 1.0
    quality = float(np.clip(observed * (1.0 - abs(1.0 - seen)), 0.0, 1.0))
    return Measurement(found + lo, quality, seen, bad_share, bad_share > OCCLUSION_MAX)
