"""The rough pass of the colour tracker: each object followed frame by frame by matching its look.

:func:`rough_pass` gives :func:`~galileo_jax.observe.matte.track_matte` a first track, to a
pixel or two, around which every frame is then measured from the colour matte. Each object's
look (:class:`_Template`: its pixels and mask in the start frame) is matched around where it
is heading by least squares over its footprint (``cv2.matchTemplate``; a small object as a
composite with the static scenery, :func:`static_scenery`), turned to its direction of motion,
motion-blurred where the camera's shutter blurs it, and evolving with the object's look
(:data:`EVOLVE`). Several objects are placed together (:func:`_choose`): look-alikes that touch
do not overlap. The Open Source Physics Tracker's autotracker (an evolving template matched
around a prediction) is the model this follows.

All pixel coordinates are (u, v): u to the right, v down, in px of the full-size frame.
"""

from __future__ import annotations

import itertools
import math
from typing import NamedTuple

import cv2
import numpy as np

from galileo_jax.errors import TrackingError
from galileo_jax.observe.colour import CROSS
from galileo_jax.observe.tracks import (BACKGROUND_FRAMES, BACKGROUND_MIN, crop_box, footprint, footprints_along,
                                        frame_median, spread_indices, visible_fraction, weighted_centroid)

#: Share of the current look mixed into the rough pass's template after each clean match.
EVOLVE = 0.3
#: A rough-pass match with an RMS difference above this many times the recent ones (plus 10
#: grey levels) is a miss; three misses running lose the track.
LOST_RMS = 3.0
#: ... the recent RMS taken as at least this (grey levels): a resting object matches its own
#: look almost exactly, and its first moving frames (blur, an impact) must not count as misses.
LOST_FLOOR = 12.0
#: Speed (px per frame) from which the rough pass also matches an object's look motion-blurred ...
BLUR_SPEED = 6.0
#: ... over these shares of a frame's motion (the camera's shutter, as a share of the frame
#: interval: 0.5 is the common 180-degree shutter).
SHUTTERS = (0.5, 1.0)
#: Speed (px per frame) from which the rough pass, while it does not know the camera's shutter,
#: matches each object both sharp and motion-blurred, and counts which fits best (a vote).
PROBE_SPEED = 12.0
#: ... and at least this share of its length per frame: a streak shorter than a fair share of the
#: object fits its sharp look about as well as its blurred one, and such near ties decided the
#: vote wrongly (measured on the tracking benchmark: a blurred 42 px cube at 12-16 px a frame
#: voted "sharp", and the sharp looks then fitted it at RMS 62-73 and lost it).
PROBE_SHARE = 0.5
#: Votes after which the shutter is decided for the rest of the pass ("sharp": blurred looks are
#: no longer tried; a blurred look of a sharp, textured object is smooth and fits the scenery
#: about as well, so it may win where the object turns and its sharp look fits worse).
SHUTTER_VOTES = 3
#: Footprint area (px) under which the rough pass matches an object as a composite with the
#: scenery (:func:`_match`; about 24 x 24 px: there the ring of background in its template is
#: at least a sixth of it).
COMPOSITE_AREA = 576
#: Cost of leaving an object unplaced in a frame (:func:`_choose`), in units of the RMS above
#: which a match is no match (:func:`_no_match`): only placements far off the path or the
#: prediction cost more.
MISS_COST = 5.0
#: Two objects' centres closer than this share of their half lengths together (along the path)
#: overlap: no joint choice places them so (:func:`_choose`). Rigid bodies touch at most (1.0),
#: but at an impact the motion-blurred centres come closer: fit benchmark plain_persp_7, 19 px
#: apart at a touching distance of 27 px (0.70) in the frame of the impact.
APART = 0.6
#: Turn (rad) of the template tried either way when the rough pass searches wider.
WIDE_TURN = math.radians(15.0)


class _Template(NamedTuple):
    """An object's look for the rough pass: BGR crop, mask of its footprint (grown by 1 px, so
    that its outline against the background localises it), the object's centre in the crop
    and its tilt there."""

    image: np.ndarray
    mask: np.ndarray
    centre: np.ndarray
    angle: float
    core: np.ndarray  # the footprint itself (not grown): the pixels the object covers


def _template(frame: np.ndarray, centre, half, angle: float) -> _Template | None:
    box = crop_box(frame.shape, centre, math.hypot(*half) + 3)
    if box is None:
        return None
    lo, hi = box
    size = (hi[1] - lo[1], hi[0] - lo[0])
    mask = footprint(size, centre, half, angle, grow=1.0, offset=lo)
    core = footprint(size, centre, half, angle, offset=lo) & mask
    return _Template(frame[lo[1]:hi[1], lo[0]:hi[0]].astype(np.float32), mask.astype(np.uint8),
                     np.asarray(centre, float) - lo, float(angle), core.astype(np.uint8))


def _turned(tpl: _Template, angle: float) -> _Template:
    """The template turned about the object's centre to tilt ``angle``."""
    d = angle - tpl.angle
    if abs(d) < 1e-3:
        return tpl
    c, s = math.cos(d), math.sin(d)
    R = np.array([[c, -s], [s, c]])
    h, w = tpl.mask.shape
    M = np.hstack([R, (tpl.centre - R @ tpl.centre)[:, None]])
    img = cv2.warpAffine(tpl.image, M, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    mask = cv2.warpAffine(tpl.mask, M, (w, h), flags=cv2.INTER_NEAREST)
    core = cv2.warpAffine(tpl.core, M, (w, h), flags=cv2.INTER_NEAREST) & mask
    return _Template(img, mask, tpl.centre, angle, core)


def _evolve(tpl: _Template, frame: np.ndarray, centre, rate: float) -> _Template:
    """The template moved towards the object's look in ``frame`` at ``centre`` (px, sub-pixel)
    by ``rate`` (exponential forgetting, as the Open Source Physics Tracker's evolving
    template)."""
    h, w = tpl.mask.shape
    shift = np.asarray(centre, float) - tpl.centre
    M = np.array([[1.0, 0.0, shift[0]], [0.0, 1.0, shift[1]]])
    now = cv2.warpAffine(frame, M, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                         borderMode=cv2.BORDER_REPLICATE).astype(np.float32)
    return tpl._replace(image=(1.0 - rate) * tpl.image + rate * now)


def _parabola(a: float, b: float, c: float) -> float:
    """Offset of the extremum of a parabola through (-1, a), (0, b), (1, c), in [-0.5, 0.5]."""
    den = a - 2 * b + c
    if not (np.isfinite(den) and den > 1e-12):  # a neighbour left out (another object there)
        return 0.0
    return float(np.clip(0.5 * (a - c) / den, -0.5, 0.5))


def _match(frame: np.ndarray, tpl: _Template, predicted, radius: float, n_best: int = 5,
           scenery: np.ndarray | None = None) -> list[tuple[np.ndarray, float]]:
    """Where the template fits best within ``radius`` px of ``predicted``: up to ``n_best``
    local minima, best first, each the object's centre (2,) px, to a fraction of a pixel (a
    parabola through the minimum), and the RMS difference per channel there (grey levels);
    none if the search region leaves the image.

    Without ``scenery`` the fit is least squares over the template's mask (the object and a
    1 px ring of the background it had when the template was taken). With ``scenery`` ((H, W,
    3) float32, the static background) the object is matched as a composite and scored as a
    likelihood ratio: its pixels (``tpl.core``) against the template, the ring against the
    scenery where it now is (an object moving onto other scenery keeps its outline), plus a
    penalty where the scenery alone explains the object's pixels better than the template does
    (the core's sum of squares against the template minus that against the scenery, where
    positive): a stretch of scenery that resembles the object is no match, however well its
    colour fits (for a Gaussian pixel noise the log-likelihood ratio of "object here" against
    "scenery here" is the difference of those two sums of squares).

    The composite costs about 2.5 times the plain fit; it is used for objects whose footprint
    is under :data:`COMPOSITE_AREA` px, where the ring is a large part of the template (a third
    at 11 px across, a twelfth at 50 px).
    """
    h, w = tpl.mask.shape
    r = int(math.ceil(radius))
    lo = np.round(np.asarray(predicted, float) - tpl.centre).astype(int) - r
    hi = lo + [w + 2 * r, h + 2 * r]
    H, W = frame.shape[:2]
    lo, hi = np.maximum(lo, 0), np.minimum(hi, [W, H])
    if hi[0] - lo[0] < w + 2 or hi[1] - lo[1] < h + 2:
        return []
    region = frame[lo[1]:hi[1], lo[0]:hi[0]].astype(np.float32)
    composite = scenery is not None and int(tpl.core.sum()) < COMPOSITE_AREA
    ssd = _match_score(region, scenery[lo[1]:hi[1], lo[0]:hi[0]] if composite else None, tpl)
    out = []
    for y, x in _minima(ssd, n_best):
        dx = _parabola(ssd[y, x - 1], ssd[y, x], ssd[y, x + 1]) if 0 < x < ssd.shape[1] - 1 else 0.0
        dy = _parabola(ssd[y - 1, x], ssd[y, x], ssd[y + 1, x]) if 0 < y < ssd.shape[0] - 1 else 0.0
        rms = math.sqrt(max(float(ssd[y, x]), 0.0) / max(3 * int(tpl.mask.sum()), 1))
        out.append((np.array([lo[0] + x + dx, lo[1] + y + dy]) + tpl.centre, rms))
    return out


def _minima(ssd: np.ndarray, n: int) -> list[tuple[int, int]]:
    """Up to ``n`` local minima (row, column) of a score map (5x5 neighbourhoods), best first."""
    minima = (ssd <= cv2.erode(ssd, np.ones((5, 5), np.uint8))).nonzero()
    order = np.argsort(ssd[minima])[:n]
    return [(int(minima[0][j]), int(minima[1][j])) for j in order]


def _match_score(region: np.ndarray, still: np.ndarray | None, tpl: _Template) -> np.ndarray:
    """The score map of :func:`_match` (sum of squares, grey levels^2) for the template at
    every offset in ``region`` ((h, w, 3) float32), with ``still`` the scenery there (NaN
    where unknown) or None."""
    if still is None:
        return cv2.matchTemplate(region, tpl.image, cv2.TM_SQDIFF, mask=np.repeat(tpl.mask[..., None], 3, axis=2))
    core = tpl.core.astype(np.float32)
    ring = tpl.mask.astype(np.float32) - core
    d2 = np.square(region - still).sum(axis=-1)
    obj = cv2.matchTemplate(region, tpl.image, cv2.TM_SQDIFF, mask=np.repeat(core[..., None], 3, axis=2))
    ring_tpl = cv2.matchTemplate(region, tpl.image, cv2.TM_SQDIFF, mask=np.repeat(ring[..., None], 3, axis=2))
    unknown = np.isnan(d2)
    d2[unknown] = 0.0
    ring_bg = cv2.matchTemplate(d2, ring, cv2.TM_CCORR)
    bg = cv2.matchTemplate(d2, core, cv2.TM_CCORR)
    if unknown.any():  # scenery not known there (an object rests there): no comparison with it
        unknown = unknown.astype(np.float32)
        ring_bg[cv2.matchTemplate(unknown, ring, cv2.TM_CCORR) > 0.5] = np.inf
        bg[cv2.matchTemplate(unknown, core, cv2.TM_CCORR) > 0.5] = np.inf
    return obj + np.minimum(ring_tpl, ring_bg) + np.maximum(obj - bg, 0.0)


def _recentre(frame: np.ndarray, scenery: np.ndarray, centre, half, angle: float, margin: float
              ) -> np.ndarray | None:
    """The centroid of what differs from ``scenery`` (the median of a sample of frames: a
    moving object is not in it where it passes) inside the object's footprint at ``centre``
    grown by ``margin`` px in ``frame``, if that region is about the object's size (0.6 to 1.6
    times its footprint; else None: the object rests where the median holds it, or a hand
    covers it) and the scenery is known all over it (not NaN). Keeps the rough pass's template
    from drifting off the object."""
    box = crop_box(frame.shape, centre, math.hypot(*half) + margin + 2)
    if box is None:
        return None
    lo, hi = box
    d = np.abs(frame[lo[1]:hi[1], lo[0]:hi[0]] - scenery[lo[1]:hi[1], lo[0]:hi[0]]).max(axis=-1)
    near = footprint(d.shape, centre, half, angle, grow=margin, offset=lo)
    if np.isnan(d[near]).any():  # the scenery is not known there (an object rests there)
        return None
    thr = max(BACKGROUND_MIN + 4, 4.0 * 1.4826 * float(np.nanmedian(d)))
    fg = ((d > thr) & near).astype(np.uint8)
    fg = cv2.morphologyEx(fg, cv2.MORPH_OPEN, CROSS)
    area = float(fg.sum())
    if not 0.6 * 4 * half[0] * half[1] <= area <= 1.6 * 4 * (half[0] + 0.5 * margin) * (half[1] + 0.5 * margin):
        return None
    c = weighted_centroid(fg.astype(np.float32))
    return None if c is None else c + lo


def _unchanged(a: np.ndarray, b: np.ndarray, centre, half, angle: float, thr: float) -> bool:
    """True if an object's footprint at ``centre`` (grown by 2 px) looks the same in frames
    ``a`` and ``b``: fewer than 2% of its pixels changed by more than ``thr`` grey levels."""
    box = crop_box(a.shape, centre, math.hypot(*half) + 4)
    if box is None:
        return False
    lo, hi = box
    d = np.abs(a[lo[1]:hi[1], lo[0]:hi[0]].astype(np.int16) - b[lo[1]:hi[1], lo[0]:hi[0]].astype(np.int16)).max(-1)
    fp = footprint(d.shape, centre, half, angle, grow=2.0, offset=lo)
    return bool((d[fp] > thr).mean() < 0.02) if fp.any() else False


def static_scenery(median: np.ndarray, start: np.ndarray, halves, angles) -> np.ndarray:
    """(H, W, 3) float32 static scenery for the rough pass: ``median`` (H, W, 3), the plain
    median of a sample of frames, with NaN over the objects' footprints at their start (grown
    by a quarter of their size, for a near face in perspective), where an object resting for
    most of the video is in that median."""
    scenery = median.copy()
    n = len(start)
    grow = np.array([[0.25 * max(h) + 2.0 for h in halves]])
    covered = footprints_along(np.asarray(start, float)[None], halves, np.asarray(angles, float).reshape(1, n),
                       median.shape[:2], grow)(0)
    scenery[covered] = np.nan
    return scenery


def rough_pass(frames, start, halves, angles0, k0: int, step: int, fps, first_frame: int, on_loss: str,
                scenery: np.ndarray | None = None, tilts=None):
    """Follow the objects frame by frame from ``k0`` in direction ``step`` (+1 or -1).

    An object whose footprint did not change since the previous frame rests there. Otherwise
    its look (:class:`_Template`, from frame ``k0``, turned to its direction of motion and
    evolving with it: :data:`EVOLVE`) is matched (:func:`_match`, least squares over the
    footprint: a plain object is localised by its outline, on any background; a small one as
    a composite with ``scenery``) around its predicted position (constant velocity), within
    4 px plus a frame's motion (:func:`_candidates`); where the best match is worse than the
    recent ones (a turn onto the floor, an impact), also turned by +-:data:`WIDE_TURN` and
    onto each of the path's ``tilts`` (ramp, floor), moving along it, and where it is much
    worse, three times wider. Motion-blurred looks are tried until the camera's shutter is
    known: the first :data:`SHUTTER_VOTES` fast frames (all objects together) decide whether
    blurred looks fit better than sharp ones; a sharp camera then matches sharp looks only. An
    object touching another is also searched where a collision may leave it (:func:`_impacts`),
    every move pays for leaving the path (:func:`_off_path`), and an object may be left unplaced
    in a frame rather than put where it costs more than :data:`MISS_COST` poor matches
    (:func:`_choose`). An
    object whose footprint would leave the image is followed no further.

    ``scenery``: (H, W, 3) float32 static scenery (:func:`static_scenery`; default computed here
    from :data:`BACKGROUND_FRAMES` frames).
    ``tilts``: image tilts (rad) of the path's segments, or None.

    Returns:
        (N, n, 2) pixels (NaN where not followed), (N, n) RMS difference of each match (grey
        levels; NaN where not followed, the previous one where it rested), (N, n) bool,
        matches confirmed by :func:`_recentre` (the object seen there, whole and alone, against
        the scenery) and (n,) the frame at which each object was lost inside the image (-1
        if never).

    Raises:
        TrackingError: with ``on_loss="raise"``, an object not matched in 3 frames running.
    """
    N, n = len(frames), len(start)
    px = np.full((N, n, 2), np.nan)
    px[k0] = start
    rms = np.full((N, n), np.nan)
    rms[k0] = 0.0
    verified = np.zeros((N, n), bool)
    lost = np.full(n, -1)
    vel = np.zeros((n, 2))
    alive = np.ones(n, bool)
    angle = np.array(angles0, float)
    misses = np.zeros(n, int)
    templates = [_template(frames[k0], start[i], halves[i], angle[i]) for i in range(n)]
    turned = list(templates)
    recent_rms = [[] for _ in range(n)]
    if scenery is None:
        scenery = static_scenery(frame_median(frames[spread_indices(N, BACKGROUND_FRAMES)]), start, halves, angles0)
    shutter, votes, probing = None, [0, 0], {}
    ks = range(k0 + step, N) if step > 0 else range(k0 - 1, -1, -1)
    prev = k0
    for k in ks:
        # 1. each object's candidate positions (resting objects stay put)
        options: dict[int, list] = {}
        for i in range(n):
            if not alive[i] or templates[i] is None:
                continue
            if np.linalg.norm(vel[i]) < 2.0 and \
                    _unchanged(frames[k], frames[prev], px[prev, i], halves[i], angle[i], BACKGROUND_MIN):
                px[k, i], rms[k, i], vel[i], misses[i] = px[prev, i], rms[prev, i], 0.0, 0
                continue
            pred = px[prev, i] + vel[i]
            if visible_fraction(frames.shape[1:], px[prev, i], halves[i], angle[i]) < 0.999 and \
                    visible_fraction(frames.shape[1:], pred, halves[i], angle[i]) < 1.0:
                alive[i] = False  # leaving the image
                continue
            # near another object an impact may change its speed at once: its blur is not known
            near = _touching(i, px[prev, i], {}, px[prev], halves, gap=4.0 + float(np.linalg.norm(vel[i])))
            probing[i] = not near and shutter is None and float(np.linalg.norm(vel[i])) >= _probe_speed(halves[i])
            options[i] = _candidates(frames[k], turned[i], pred, vel[i], halves[i], recent_rms[i][-10:],
                                     blurred=not near, scenery=scenery, tilts=tilts, shutter=shutter,
                                     impacts=_impacts(i, px[prev], vel, halves) if near else ())
        # 2. the best positions together: two objects do not overlap by much (look-alikes touching)
        miss = {i: MISS_COST * _no_match(recent_rms[i][-10:]) for i in options if len(recent_rms[i][-10:]) > 2}
        chosen = _choose(options, {i: px[k, i] for i in range(n) if i not in options and np.all(np.isfinite(px[k, i]))},
                         halves, {i: px[prev, i] for i in range(n) if np.all(np.isfinite(px[prev, i]))}, miss)
        # 3. update (a match far worse than the recent ones is no match: the object is hidden)
        for i, opts in options.items():
            recent = recent_rms[i][-10:]
            # an object touching another shows less of its look (a face hidden by the other,
            # which the template's border also covers): its match may be twice as far off
            touching = i in chosen and _touching(i, chosen[i][0], chosen, px[k], halves)
            if i in chosen and len(recent) > 2 and chosen[i][1] > (2.0 if touching else 1.0) * _no_match(recent):
                del chosen[i]

            if i not in chosen:
                misses[i] += 1
                px[k, i] = px[prev, i] + vel[i]
                if misses[i] >= 3:
                    alive[i], lost[i] = False, k
                    if on_loss == "raise":
                        when = f" (t = {(k + first_frame) / fps:.2f} s)" if fps else ""
                        raise TrackingError(f"object {i + 1} track lost at frame {k + first_frame}{when}: it was not "
                                            "found near where it was heading; check the video, or give "
                                            "camera.start_pixels", object_index=i)
                continue
            misses[i] = 0
            centre, r, tpl, _, was_blurred = chosen[i]
            if probing[i] and not touching:  # the camera's shutter, learnt from the first fast frames
                votes[int(was_blurred)] += 1
                if sum(votes) >= SHUTTER_VOTES:
                    shutter = "blur" if votes[1] > votes[0] else "sharp"
            speed = float(np.linalg.norm(vel[i]))
            if not touching:
                at = _recentre(frames[k], scenery, centre, halves[i], tpl.angle, 2.0 + 0.5 * speed)
                if at is not None and np.linalg.norm(at - centre) < 0.5 * min(halves[i]):
                    centre, verified[k, i] = at, True
            new_vel = centre - px[prev, i]
            turned[i], angle[i] = tpl, tpl.angle
            if np.linalg.norm(new_vel) > 1.5:
                b = math.atan2(step * new_vel[1], step * new_vel[0])
                a = (b - angles0[i] + math.pi / 2) % math.pi - math.pi / 2 + angles0[i]
                if abs(a - turned[i].angle) > math.radians(2.0):
                    turned[i] = _turned(turned[i], a)
                angle[i] = a
            vel[i] = new_vel
            px[k, i], rms[k, i] = centre, r
            typical = float(np.median(recent_rms[i][-10:])) if len(recent_rms[i]) > 2 else np.inf
            recent_rms[i].append(r)
            # the look evolves (blur, turn, light)
            if not touching and np.isfinite(typical) and r <= 1.1 * typical + 2.0:
                turned[i] = _evolve(turned[i], frames[k], centre, EVOLVE)
        prev = k
    return px, rms, verified, lost


def _probe_speed(half) -> float:
    """Speed (px per frame) from which an object's matches vote on the camera's shutter
    (:data:`PROBE_SPEED`, :data:`PROBE_SHARE` of its length ``2 * half[0]``)."""
    return max(PROBE_SPEED, PROBE_SHARE * 2.0 * float(half[0]))


def _no_match(recent: list) -> float:
    """The RMS difference (grey levels) above which a match is no match, given the ``recent``
    ones (:data:`LOST_RMS`, :data:`LOST_FLOOR`)."""
    return LOST_RMS * max(float(np.median(recent)), LOST_FLOOR) + 10.0


def _off_path(step, tilts) -> float:
    """Penalty (in units of the recent RMS) for a move ``step`` (2,) px that leaves the path: its
    part across the nearest direction within the fan of the path's ``tilts`` (rad; lines, so
    either way along them: a rebound), over 2 px plus a tenth of the move, squared. An object
    slides along the ramp and the floor and turns from one to the other; it does not jump
    across them (a poor match at an impact, where the look is blurred and half hidden, does).
    0 without tilts or for a move under 3 px."""
    length = float(np.linalg.norm(step))
    if tilts is None or len(tilts) == 0 or length < 3.0:
        return 0.0
    a = math.atan2(step[1], step[0])
    lines = [(t - tilts[0] + math.pi / 2) % math.pi - math.pi / 2 for t in tilts]  # as lines, near the first
    lo, hi = min(lines), max(lines)
    off = (a - tilts[0] - (lo + hi) / 2 + math.pi / 2) % math.pi - math.pi / 2  # from the fan's middle line
    dev = max(abs(off) - (hi - lo) / 2, 0.0)
    return (length * math.sin(min(dev, math.pi / 2)) / (2.0 + 0.1 * length)) ** 2


def _impacts(i: int, prev: np.ndarray, vel: np.ndarray, halves) -> list[tuple[np.ndarray, np.ndarray]]:
    """Where object ``i`` (touching another: :func:`rough_pass` calls this only then) may be in
    the next frame if it collides with another object ``j`` it is not moving away from (their
    centres ``prev`` (n, 2) px in the frame before, velocities ``vel`` (n, 2) px per frame): a
    segment (its two ends, px) per such object. The one running into the other (the faster
    towards it) stops at most where the two touch end to end (half lengths ``halves[.][0]``),
    the other moved on by the other's motion: a point. The one run into leaves with a velocity
    between its own v_i and 2 v_j - v_i (in a collision along the line of centres, v_i + (1 + e)
    m_j / (m_i + m_j) (v_j - v_i) for a restitution e in [0, 1] and any masses), and the frame's
    displacement, part before and part after the impact, lies between the same two."""
    out = []
    for j in range(len(prev)):
        d = prev[i] - prev[j]
        if j == i or not np.all(np.isfinite(d)) or np.linalg.norm(d) < 1e-6:
            continue
        u = d / np.linalg.norm(d)  # from j to i
        if float(np.dot(vel[i] - vel[j], u)) >= 2.0:  # parting
            continue
        if float(np.dot(vel[i], -u)) > float(np.dot(vel[j], u)):  # i runs into j
            at = prev[j] + vel[j] + u * (halves[i][0] + halves[j][0])
            out.append((at, at))
        else:
            out.append((prev[i] + vel[i], prev[i] + 2.0 * vel[j] - vel[i]))
    return out


def _to_segment(c, ends) -> float:
    """Distance (px) from the point ``c`` to the segment between ``ends`` (two points)."""
    a, b = np.asarray(ends[0], float), np.asarray(ends[1], float)
    ab = b - a
    t = float(np.clip(np.dot(np.asarray(c) - a, ab) / max(float(np.dot(ab, ab)), 1e-9), 0.0, 1.0))
    return float(np.linalg.norm(np.asarray(c) - a - t * ab))


def _touching(i: int, centre, chosen: dict, fixed: np.ndarray, halves, gap: float = 4.0) -> bool:
    """Whether object ``i`` at ``centre`` (px) is within ``gap`` px of touching another object,
    at its chosen candidate (``chosen``: {j: (centre, ...)}) or else at its position in
    ``fixed`` ((n, 2) px, NaN where unknown)."""
    for j in range(len(halves)):
        if j == i:
            continue
        other = chosen[j][0] if j in chosen else fixed[j]
        if np.all(np.isfinite(other)) and \
                np.linalg.norm(np.asarray(centre) - other) < math.hypot(*halves[i]) + math.hypot(*halves[j]) + gap:
            return True
    return False


def _blurred(tpl: _Template, length: float, direction: float) -> _Template:
    """The template as a camera sees it moving ``length`` px at ``direction`` (rad) during
    the exposure: its image averaged along that segment (a box filter, the exposure of a
    shutter open for that stretch of the motion) and its mask swept along it. Padded by the
    border's pixels (background around the object's outline) so the swept mask fits."""
    pad = int(math.ceil(0.5 * length)) + 1
    img = cv2.copyMakeBorder(tpl.image, pad, pad, pad, pad, cv2.BORDER_REPLICATE)
    mask = cv2.copyMakeBorder(tpl.mask, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=0)
    size = 2 * pad + 1
    line = np.zeros((size, size), np.float32)
    d = np.array([math.cos(direction), math.sin(direction)]) * 0.5 * length
    p0, p1 = np.round((pad - d) * 16).astype(int), np.round((pad + d) * 16).astype(int)
    cv2.line(line, tuple(map(int, p0)), tuple(map(int, p1)), 1.0, thickness=1, lineType=cv2.LINE_AA, shift=4)
    line /= line.sum()
    img = cv2.filter2D(img, -1, line, borderType=cv2.BORDER_REPLICATE)
    core = cv2.copyMakeBorder(tpl.core, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=0)
    mask = cv2.dilate(mask, (line > 0).astype(np.uint8))
    core = cv2.dilate(core, (line > 0).astype(np.uint8))
    return _Template(img, mask, tpl.centre + pad, tpl.angle, core)


def _candidates(frame, tpl: _Template, pred, vel, half, recent: list, blurred: bool = True,
                scenery: np.ndarray | None = None, tilts=None, shutter: str | None = None,
                impacts=()) -> list:
    """Candidate positions of one object in a frame for :func:`rough_pass`: (centre, RMS,
    template, cost, matched blurred) tuples. Searched within 4 px plus a frame's motion of the
    prediction (twice the object's size while its speed is not known yet); where the best is
    worse than the recent matches' median (a turn onto the floor, an impact), also with the
    template turned by +-:data:`WIDE_TURN` and onto each of the path's ``tilts`` (moving along
    that segment), and where it is much worse, three times wider. With ``blurred`` (not near
    another object) and a ``shutter`` not known to be "sharp", an object moving at least
    :data:`BLUR_SPEED` px per frame whose look fits worse than it did (or, while ``shutter`` is
    None, at least :func:`_probe_speed`) is also matched motion-blurred (:func:`_blurred`, over
    each of :data:`SHUTTERS` of a frame's motion): a sharp look matched to a long streak slides
    along it. Touching another object, it is also searched where an impact may send it
    (``impacts``: segments from :func:`_impacts`). A candidate pays for its distance from the
    prediction (or the nearest impact segment): the recent RMS times (distance / reach)^2, so a
    look-alike in the scenery does not win over the object where it is expected, plus the
    recent RMS times :func:`_off_path` of its move. The template returned is the sharp one (the
    next frame blurs it anew)."""
    speed = float(np.linalg.norm(vel))
    local = 4.0 + speed if len(recent) > 2 else 4.0 + max(speed, 2 * max(half))
    typical = float(np.median(recent)) if len(recent) > 2 else np.inf

    def blurred_looks(t):
        direction = math.atan2(vel[1], vel[0])
        return [_blurred(t, f * speed, direction) for f in SHUTTERS]

    def matches(t, radius, looks, at=pred):  # the look t matched as each of ``looks`` (t or t blurred)
        return [(c, r, t, v is not t) for v in looks for c, r in _match(frame, v, at, radius, scenery=scenery)]

    def best(options):
        return min((o[1] for o in options), default=np.inf)

    out = matches(tpl, local, [tpl])
    # the sharp look fits worse than it did (or the shutter is still being learnt at speed):
    # also try it blurred
    blur = blurred and shutter != "sharp" and speed >= BLUR_SPEED and \
        (best(out) > 1.1 * typical + 2.0 or (shutter is None and speed >= _probe_speed(half)))
    if blur:
        out += matches(tpl, local, blurred_looks(tpl))
    if best(out) > typical:  # a turn (onto the floor, an impact)
        for a in (-WIDE_TURN, WIDE_TURN):
            t = _turned(tpl, tpl.angle + a)
            out += matches(t, local, [t] + (blurred_looks(t) if blur else []))
        for tilt in tilts if tilts is not None and speed > 0 else ():  # onto another segment of the path
            a = (tilt - tpl.angle + math.pi / 2) % math.pi - math.pi / 2  # the turn, within +-90 degrees
            if abs(a) < math.radians(3.0):
                continue
            t = _turned(tpl, tpl.angle + a)
            c, s_ = math.cos(a), math.sin(a)
            along = np.array([c * vel[0] - s_ * vel[1], s_ * vel[0] + c * vel[1]])  # the velocity turned with it
            out += matches(t, local, [t], at=np.asarray(pred, float) - vel + along)
    if best(out) > 1.5 * typical + 3.0:  # an impact that starts or stops it: further
        out += matches(tpl, 3 * local + max(half), [tpl] + (blurred_looks(tpl) if blur else []))
    for ends in impacts:  # touching another object: anywhere an impact may send it
        out += matches(tpl, 4.0 + 0.25 * speed + 0.5 * float(np.linalg.norm(ends[1] - ends[0])), [tpl],
                       at=0.5 * (ends[0] + ends[1]))

    prev = np.asarray(pred, float) - np.asarray(vel, float)

    def cost(c, r):
        d = min([float(np.linalg.norm(c - pred))] + [_to_segment(c, ends) for ends in impacts])
        far = (d / local) ** 2 + _off_path(c - prev, tilts)
        return r + (typical if np.isfinite(typical) else r) * far

    return sorted(((c, r, t, cost(c, r), b) for c, r, t, b in out), key=lambda o: o[3])[:8]


def _choose(options: dict, fixed: dict, halves, previous: dict | None = None, miss: dict | None = None) -> dict:
    """One candidate per object (:func:`_candidates`) minimising the summed cost, with no two
    objects (also those ``fixed`` where they are) closer than :data:`APART` of the sum of their
    half lengths along the path (rigid bodies touch at most), and, where ``previous`` gives both
    objects' positions in the frame before, in the same order as there (the vector from one
    to the other does not turn by more than 90 degrees in a frame: two objects on one ramp
    cannot pass through each other; without this, look-alikes that collide may swap
    identities). Objects without candidates are left out, and so is an object left unplaced
    (a miss) where its cost in ``miss`` ({i: cost}; :data:`MISS_COST` poor matches) is lower
    than what placing it adds: held-out world_77, a resting cube hit by another was otherwise
    put 40 px above the floor, its true place overlapping the other's best candidate."""
    ids = [i for i in options if options[i]]
    if not ids:
        return {}
    previous = previous or {}

    def apart(i, c, j, d):
        if np.linalg.norm(c - d) < APART * (halves[i][0] + halves[j][0]):  # rigid bodies: touching at most
            return False
        if i in previous and j in previous:
            return float(np.dot(c - d, previous[i] - previous[j])) > 0.0
        return True

    miss = miss or {}
    best, best_cost = None, np.inf
    # an object may also be missed (index -1), at its cost in ``miss``: no candidate at all is
    # better than one that costs more (a look matched far off its path to keep clear of another)
    choices = [list(range(len(options[i]))) + ([-1] if i in miss else []) for i in ids]
    for combo in itertools.product(*choices):
        picks = {i: options[i][m] for i, m in zip(ids, combo) if m >= 0}
        total = sum(p[3] for p in picks.values()) + sum(miss[i] for i, m in zip(ids, combo) if m < 0)
        if total >= best_cost:
            continue
        placed = list(picks)
        ok = all(apart(i, picks[i][0], j, picks[j][0]) for a, i in enumerate(placed) for j in placed[a + 1:])
        ok = ok and all(apart(i, picks[i][0], j, c) for i in placed for j, c in fixed.items())
        if ok:
            best, best_cost = picks, total
    if best is None:  # nothing compatible: each its own best
        best = {i: options[i][0] for i in ids}
    return best
