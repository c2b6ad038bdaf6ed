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


#: Motion per frame (px) from which a measurement checks the two ends of the object's blur
#: streak (:func:`_streak_end_shift`).
STREAK_SPEED = 6.0


#: A blur streak whose length differs from its object's by more than this (px) is taken as cut
#: short or drawn out at one end (:func:`_streak_end_shift`).
STREAK_SHORT = 2.0


#: The end a blur streak is measured from must rise over at least this many px (alpha 0.1 to 0.9
#: of the plateau): a streak, not a sharp edge (a frame from a fast shutter).
STREAK_RAMP = 3.0


#: Objects shorter than this (px) are not measured from one end of their streak: a side face
#: beside them is a pixel or two wide, and their ends' half-maximum points are as uncertain.
STREAK_MIN_LENGTH = 20.0


class Measurement(NamedTuple):
    """One object in one frame.

    Attributes:
        centre: (2,) centre (u, v) in px (NaN when not found).
        quality: in [0, 1]; 0 when not found.
        seen: matte area seen over the object's area (about 1 for a clean frame).
        unusable: fraction of the footprint that was occluded or without contrast.
        aligned: True if the centre came from aligning the template (occlusion), False if
            from the centroid.
        streak: (2,) px to add to ``centre`` where the object's blur streak is cut short or
            drawn out at the end facing the image centre (:func:`_streak_end_shift`; zeros
            elsewhere): kept apart, since only a plain object's own track takes it.
    """

    centre: np.ndarray
    quality: float
    seen: float
    unusable: float
    aligned: bool
    streak: np.ndarray = np.zeros(2)


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


def _crossings(profile: np.ndarray, level: float) -> tuple[float, float]:
    """First and last positions (bins, interpolated) where a 1-D ``profile`` reaches ``level``
    from outside."""
    above = np.flatnonzero(profile >= level)
    i, j = int(above[0]), int(above[-1])
    lo = i - (profile[i] - level) / max(profile[i] - profile[i - 1], 1e-9) if i > 0 else float(i)
    hi = j + (profile[j] - level) / max(profile[j] - profile[j + 1], 1e-9) if j < len(profile) - 1 else float(j)
    return float(lo), float(hi)


def _binned_profile(coord: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, int]:
    """Mean of ``weights`` in 1 px bins of ``coord`` (both (m,)): the profile, bin b holding
    ``coord`` in [lo + b, lo + b + 1), and lo."""
    lo = math.floor(float(coord.min()))
    idx = (np.floor(coord) - lo).astype(int)
    return np.bincount(idx, weights) / np.maximum(np.bincount(idx), 1), lo


def _streak_end_shift(weights: np.ndarray, centre, half, angle: float, length: float, image_centre,
                      bad: np.ndarray | None = None) -> float:
    """Shift (px, along the object's axis at ``angle``) that moves ``centre`` (the centroid of a
    motion-blurred matte ``weights``, crop px) to where the streak's intact end puts it, where
    one end of the streak is cut short or drawn out; 0 where neither is.

    A rigid object moving along its axis during the exposure leaves a streak whose profile along
    the axis rises over the blur's length at both ends, and each end's half-maximum point is
    where that edge of the object was at mid-exposure, however long the blur: the two lie the
    object's ``length`` apart. Through a perspective camera a cube also shows the side face that
    looks towards the image centre, at the leading end before the cube passes the centre and at
    the trailing end after. Where that face is darker than the background, the pixels that
    blend it with the front face unmix to less alpha than the front face's share of the exposure
    (the side face's own alpha is below zero before the matte clips it), so that end's ramp is
    cut short and the centroid moves away from it (measured: -3 to +3 px at 30-40 px per frame,
    ``docs/tracking.md``); where the face is paler, the matte takes it in at some gain and that
    end is drawn out instead. Where the half-maximum points lie more than :data:`STREAK_SHORT`
    closer or farther apart than ``length``, the centre is taken half the length from the point
    of the end that faces away from the image centre (``image_centre``, crop px; a camera shows
    no side face beside it), if that end is a streak's (it rises over :data:`STREAK_RAMP` px or
    more), an edge across the motion is sharp (rises within that; a cube turned from its axis,
    tumbling at the ramp's foot, has sloped ends without any blur) and nothing hides it.

    Args:
        weights: (h, w) matte (crop coordinates).
        centre: (2,) its centroid (crop px).
        half: (2,) half sizes (along, across), px.
        angle: the footprint's axis (rad).
        length: the object's length along its axis in a sharp frame (px; its template's).
        image_centre: (2,) the image's centre (crop px).
        bad: (h, w) bool, pixels not to be trusted (occluded, contradicting the template), or
            None: where any lies on the end measured from, nothing is moved.
    """
    u = np.array([math.cos(angle), math.sin(angle)])
    ys, xs = np.indices(weights.shape)
    dx, dy = xs - centre[0], ys - centre[1]
    band = np.abs(-dx * u[1] + dy * u[0]) < 0.5 * half[1]  # away from the top and bottom faces
    if not band.any():
        return 0.0
    along = dx * u[0] + dy * u[1]
    # the end facing the image centre is the one a side face shows beside: measure from the other,
    # where nothing hides it
    towards = float((np.asarray(image_centre, float) - centre) @ u)
    if abs(towards) < length:  # near the image centre a side face hardly shows
        return 0.0
    facing_high = towards > 0.0
    if bad is not None and (bad & band & ((along < 0) if facing_high else (along > 0))).any():
        return 0.0
    profile, lo = _binned_profile(along[band], weights[band])
    plateau = float(profile.max())
    if plateau < 0.5:
        return 0.0
    lo50, hi50 = _crossings(profile, 0.5 * plateau)
    deficit = hi50 - lo50 - length
    if abs(deficit) <= STREAK_SHORT:  # as long as the object: both ends are its edges
        return 0.0
    if facing_high:  # measured from the low end
        ramp = _crossings(profile, 0.9 * plateau)[0] - _crossings(profile, 0.1 * plateau)[0]
    else:
        ramp = _crossings(profile, 0.1 * plateau)[1] - _crossings(profile, 0.9 * plateau)[1]
    if ramp < STREAK_RAMP:
        return 0.0
    # motion blur leaves the edges across the motion sharp; an object turned from its axis (a
    # cube tumbling at the ramp's foot) slopes at all four
    middle = np.abs(along) < 0.25 * length
    if (middle & (weights > 0)).any():
        across, _ = _binned_profile((-dx * u[1] + dy * u[0])[middle], weights[middle])
        a10, b10 = _crossings(across, 0.1 * float(across.max()))
        a90, b90 = _crossings(across, 0.9 * float(across.max()))
        if min(a90 - a10, b10 - b90) > STREAK_RAMP:
            return 0.0
    mid = lo50 + 0.5 * length if facing_high else hi50 - 0.5 * length  # bins
    # bin b holds s in [lo + b, lo + b + 1); a side face moves the centroid by about half the
    # streak's error in length, never by more than three quarters of it
    return float(np.clip(mid + lo + 0.5, -0.75 * abs(deficit), 0.75 * abs(deficit)))


def template_length(look: Look, half) -> float:
    """The object's length along its axis in ``look``'s template (px): the distance between the
    half-maximum points of its profile along the axis, over the middle half across it."""
    T = look.template
    rows = np.abs(np.arange(T.shape[0]) - look.centre[1]) < 0.5 * half[1]
    profile = T[rows].mean(axis=0)
    a, b = _crossings(profile, 0.5 * float(profile.max()))
    return b - a


def measure(frame: np.ndarray, background: ColourBackground, look: Look, guess, half, angle: float,
            margin: float = 3.0, blur: float = 0.0, keep_out=(), refine: int = 10,
            length: float | None = None) -> Measurement:
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
        length: the object's length along its axis in a sharp frame (px,
            :func:`template_length`): where given and the object moves at least
            :data:`STREAK_SPEED` px per frame, the correction for a blur streak whose end
            facing the image centre is cut short or drawn out (:func:`_streak_end_shift`) is
            returned as the measurement's ``streak``.

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
    image_centre = 0.5 * (np.array(frame.shape[1::-1], float) - 1.0) - lo
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
        streak = _streak_end(np.where(region, alpha, 0.0), centre, half, angle, blur, length, image_centre)
        return Measurement(centre + lo, 1.0 - abs(1.0 - seen), seen, 0.0, False, streak)
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
    streak = _streak_end(np.where(near & ~bad, alpha, 0.0), found, half, angle, blur, length, image_centre, bad)
    return Measurement(found + lo, quality, seen, bad_share, bad_share > OCCLUSION_MAX, streak)


def _streak_end(weights: np.ndarray, centre: np.ndarray, half, angle: float, blur: float, length: float | None,
                image_centre, bad: np.ndarray | None = None) -> np.ndarray:
    """(2,) px that move ``centre`` (crop px) along the object's axis by :func:`_streak_end_shift`
    where the object's ``length`` is known (at least :data:`STREAK_MIN_LENGTH`) and it moves at
    least :data:`STREAK_SPEED` px per frame; zeros elsewhere."""
    if length is None or blur < STREAK_SPEED or length < STREAK_MIN_LENGTH:
        return np.zeros(2)
    shift = _streak_end_shift(weights, centre, half, angle, length, image_centre, bad)
    return shift * np.array([math.cos(angle), math.sin(angle)])
