"""Tracking objects by their colour against the static background (objects without texture).

KLT (:mod:`.track`) needs texture inside an object; a plain-coloured block, a foam cube or a
tape roll has none, and its outline's corners slide along the background. This module measures
such an object in every frame from its *colour matte* instead:

* **Background** (:func:`~galileo_jax.observe.colour.colour_background`): the per-pixel median of frames spread over the
  video, leaving out, pixel by pixel, the frames in which an object covers it (its footprint
  along a first, rough track); pixels no frame shows free (an object that never moves) are
  filled from their surroundings (``cv2.inpaint``).
* **Matte** (:func:`~galileo_jax.observe.colour.matte`): a pixel I in front of the background B is
  explained by the object
  if it lies on the segment from B to one of the object's colours F_k at the frame's light
  level (:func:`~galileo_jax.observe.colour.light_level`: the colours brightened or darkened by up to
  :data:`~galileo_jax.observe.colour.GAIN`, as light and shade change along the path; a pixel by
  :data:`~galileo_jax.observe.colour.SHADE_SPREAD` more), I = B + alpha (F_k - B):
  alpha in [0, 1] is the fraction of the pixel the object covers (anti-aliased edges, motion
  blur), the linear "difference matting" of a single-colour object over a known background
  (Smith & Blinn, "Blue screen matting", SIGGRAPH 1996, eq. 3, with a per-pixel background).
  A pixel far from every segment and from the background (a hand, a shadow, another object)
  is *unusable*, as is one where the object's colour is too close to the background's there.
* **Centre** (:func:`~galileo_jax.observe.measure.measure`): with every pixel of the object's footprint usable, the
  alpha-weighted centroid (``cv2.moments``) of the matte around the object, re-centred twice;
  a blurred object's centroid is its mean position over the exposure. Where part of the
  footprint is unusable (occluded), the centroid would be pulled away from the hidden part,
  so the object's clean matte (its *template*, from an unoccluded frame) is aligned by
  Gauss-Newton (Lucas & Kanade 1981) to the usable pixels only. A frame in which too little
  of the object is seen gets a low quality and is dropped by the caller, not guessed.

Each measurement carries a quality in [0, 1]: the fraction of the object's matte that was
seen and agreed with its template (:class:`~galileo_jax.observe.measure.Measurement`).

* **Track** (:func:`track_matte`): every frame is measured where a rough track (template
  matching, :mod:`galileo_jax.observe.rough`) puts the object; a centre that walked farther from
  it than its margin plus the
  object's size is not taken. Where the rough track lost an object, it is followed on from
  its own measurements (:func:`_bridge`); one still lost is looked for where it was last
  measured, slowing to rest (:func:`_stopped_where_lost`). Two objects cannot pass through each other: where both
  are measured, apart, in the reverse of their start's order (look-alikes whose tracks took each
  other's place at a collision), their measurements are exchanged (:func:`_restore_order`);
  frames still out of order (:func:`_in_order`) and lone measured frames
  (:func:`_not_isolated`) are dropped.

All pixel coordinates are (u, v): u to the right, v down, in px of the full-size frame.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np

from galileo_jax.errors import TrackingError
from galileo_jax.observe.colour import (ColourBackground, Look, Palette, best_gain, colour_background,
                                        learn_template, object_colours, unlearn_objects)
from galileo_jax.observe.measure import measure, template_length
from galileo_jax.observe.rough import rough_pass, static_scenery
from galileo_jax.observe.tracks import (
    BACKGROUND_FRAMES,
    footprints_along,
    frame_median,
    spread_indices,
    visible_fraction,
)

#: A direction of motion within this (rad) of a straight segment of the path is the object's
#: tilt there (:func:`_angles`); one farther from every segment is not a slide.
PATH_TILT_SNAP = math.radians(20.0)

#: A template whose rectangular outline is turned by more than this (rad) from the footprint's
#: axes was learned at a wrong tilt (:func:`_learn_looks`).
LOOK_TURN_MAX = math.radians(5.0)
#: Share of its smallest enclosing rectangle that an outline fills to count as a rectangle (a
#: disc fills pi / 4 of it).
RECTANGLE_FILL = 0.85


#: A look-alike of a lost object that stays within this (px) of where it was is still itself
#: (:func:`_identity_doubted`): a resting object's measurements scatter by a few tenths of a px.
ALIKE_REST_PX = 1.5

#: Quality a measurement needs where no rough match confirms it (:func:`_bridge`).
BRIDGE_QUALITY = 0.6

#: A lost object looked for where it was last measured (:func:`_stopped_where_lost`) may move
#: per frame by at most its last step plus this (px): it is slowing to rest.
STOP_SLACK_PX = 1.5


class MatteTracks(NamedTuple):
    """Objects followed by their matte (:func:`track_matte`).

    Attributes:
        pixels: (N, n, 2) centre (u, v) in px; where not measured, the rough track's.
        valid: (N, n) bool, measured with quality >= the threshold.
        quality: (N, n) measurement quality in [0, 1] (0: not found or outside the image).
        aligned: (N, n) bool, centre from the template alignment (occlusion).
        lost: (n,) frame at which each object's track was lost inside the image (the rough
            pass could not follow it, or it was never measured again while in view), -1 if
            never.
        rough: (N, n, 2) the first pass's track (px; NaN where not followed).
        look_frame: (n,) frame from which each object's colours and template were taken (-1:
            its start frame, no clean frame found).
        streak: (N, n, 2) px to add to ``pixels`` for a plain object's own track, where its
            blur streak's end facing the image centre was cut short or drawn out
            (:func:`~galileo_jax.observe.measure.measure`'s ``streak``; zeros elsewhere).
    """

    pixels: np.ndarray
    valid: np.ndarray
    quality: np.ndarray
    aligned: np.ndarray
    lost: np.ndarray
    rough: np.ndarray
    look_frame: np.ndarray
    streak: np.ndarray


def _angles(px: np.ndarray, ok: np.ndarray, angle0: float, min_step: float = 1.5, tilts=None) -> np.ndarray:
    """(N,) tilt of an object frame by frame: the direction of its motion where it moves more
    than ``min_step`` px per frame (central difference), else the previous frame's; the
    direction is folded into (-90, 90] degrees of ``angle0`` (a box sliding back keeps its
    tilt).

    With the path's image ``tilts`` (rad; ramp and floor, from the scene) the tilt is one of
    them (a box on a straight segment lies along it): the one the motion's direction is
    within :data:`PATH_TILT_SNAP` of, in this frame and the next (a rough track pulled about
    by a hand over a resting object goes no steady way); otherwise the previous frame's."""
    N = len(px)
    direction = np.full(N, np.nan)
    for k in range(N):
        j0, j1 = max(k - 1, 0), min(k + 1, N - 1)
        if ok[j0] and ok[j1] and j1 > j0:
            v = (px[j1] - px[j0]) / (j1 - j0)
            if np.linalg.norm(v) > min_step:
                b = math.atan2(v[1], v[0])
                direction[k] = (b - angle0 + math.pi / 2) % math.pi - math.pi / 2 + angle0
    if tilts is not None:
        snapped = np.full(N, np.nan)
        for k in np.flatnonzero(np.isfinite(direction)):
            off = [(t - direction[k] + math.pi / 2) % math.pi - math.pi / 2 for t in tilts]
            j = int(np.argmin(np.abs(off)))
            if abs(off[j]) <= PATH_TILT_SNAP:
                snapped[k] = direction[k] + off[j]
        steady = np.isfinite(snapped) & np.isclose(snapped, np.append(snapped[1:], np.nan))
        direction = np.where(steady, snapped, np.nan)
    out = np.full(N, angle0)
    a = angle0
    for k in range(N):
        if np.isfinite(direction[k]):
            a = direction[k]
        out[k] = a
    return out


def _speeds(px: np.ndarray) -> np.ndarray:
    """(N, n) speed in px per frame (central differences; 0 where unknown)."""
    v = np.zeros(px.shape[:2])
    d = np.linalg.norm(px[2:] - px[:-2], axis=-1) / 2
    v[1:-1] = np.nan_to_num(d)
    v[0], v[-1] = v[1], v[-2]
    return v


def _clean_frames(px: np.ndarray, good: np.ndarray, i: int, halves, speed: np.ndarray, shape, start,
                  after_moving: bool = True, n_max: int = 200) -> np.ndarray:
    """Frames in which object ``i`` was measured well (``good`` (N, n) bool) and is seen whole
    and alone: inside the image, clear of the other objects, and (with ``after_moving``, once
    it has moved in at least 3 such frames) clear of its start position, where a hand may have
    held it; the slowest first (sharpest), at most ``n_max``. Without ``after_moving``, every
    such frame (a caller whose rough track left the object once it moved: the frames in which
    it rested still show it)."""
    N, n = px.shape[:2]
    diag = 2 * math.hypot(*halves[i])
    ok = np.all(np.isfinite(px[:, i]), axis=1) & good[:, i]
    for k in np.flatnonzero(ok):
        if visible_fraction(shape, px[k, i], halves[i], 0.0) < 1.0:
            ok[k] = False
            continue
        for j in range(n):
            if j != i and np.all(np.isfinite(px[k, j])) and \
                    np.linalg.norm(px[k, i] - px[k, j]) < math.hypot(*halves[i]) + math.hypot(*halves[j]) + 4:
                ok[k] = False
    # where a hand may have held it: its start pixel, and where it rested in the track's first
    # frame (the start pixel may be one found in motion, a few diagonals down the ramp)
    first = np.all(np.isfinite(px[:, i]), axis=1)
    rest = px[int(np.argmax(first)), i] if first.any() else start[i]
    moved = ok & (np.linalg.norm(px[:, i] - start[i], axis=-1) > diag) & \
        (np.linalg.norm(px[:, i] - rest, axis=-1) > diag)
    use = moved if after_moving and moved.sum() >= 3 else ok
    ks = np.flatnonzero(use)
    if len(ks) > n_max:
        ks = ks[np.argsort(speed[ks, i], kind="stable")[:n_max]]
    return ks


def _spread(points: np.ndarray, n: int) -> np.ndarray:
    """Indices of up to ``n`` of the (m, 2) ``points`` spread out (farthest-point sampling
    from the first)."""
    if len(points) <= n:
        return np.arange(len(points))
    chosen = [0]
    dist = np.linalg.norm(points - points[0], axis=1)
    while len(chosen) < n:
        j = int(np.argmax(dist))
        chosen.append(j)
        dist = np.minimum(dist, np.linalg.norm(points - points[j], axis=1))
    return np.array(sorted(chosen))


def _outline_turn(template: np.ndarray) -> float:
    """How far (rad, 0 to pi/4) a template's outline (alpha > 0.5) is turned from its own axes,
    where the outline is a rectangle (it fills at least :data:`RECTANGLE_FILL` of its
    smallest enclosing rectangle, ``cv2.minAreaRect``); 0 for another shape (a disc's has no
    direction) or an empty template."""
    support = (template > 0.5).astype(np.uint8)
    contours, _ = cv2.findContours(support, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return 0.0
    (_, _), (w, h), deg = cv2.minAreaRect(max(contours, key=cv2.contourArea))
    if w * h <= 0 or support.sum() < RECTANGLE_FILL * w * h:
        return 0.0
    deg %= 90.0
    return math.radians(min(deg, 90.0 - deg))


def _learn_looks(frames, bg: ColourBackground, px: np.ndarray, ks, half, angles: np.ndarray, n_looks: int = 8,
                 n_palette: int = 12) -> list[tuple[np.ndarray, Look]]:
    """An object's looks from its clean frames ``ks`` (slowest first; object at ``px`` (N, 2),
    tilted by ``angles`` (N,)): one palette from the ``n_palette`` slowest, and a template
    from each of up to ``n_looks`` of them spread along its path, with the position it was
    taken at. Where the camera is perspective or the object turns, its silhouette changes
    along its path; each frame is then measured with the nearest look (:func:`_nearest`).
    Templates whose area is not 0.5 to 1.6 times the object's footprint (a frame in which
    something else was taken for it, or most of it was missed) are left out, and so are those
    whose outline is a rectangle turned by more than :data:`LOOK_TURN_MAX` from the footprint's
    axes (:func:`_outline_turn`), where another is left: the object lay at another tilt than
    the one its track gave it in that frame (turning from the ramp onto the floor; measured:
    checker_persp_960x540_sharp_1's object 1, whose look learned one frame past the ramp's foot
    at the ramp's tilt was turned by 10 degrees, and measured it 8.5 px off at rest on the floor).

    Raises:
        ValueError: no clean frame, or the object does not differ from the background.
    """
    if len(ks) == 0:
        raise ValueError("no clean frame")
    ks = np.asarray(ks)
    palette = object_colours(frames[ks[:n_palette]], bg, px[ks[:n_palette]], half, angles[ks[:n_palette]])
    looks = []
    for k in ks[_spread(px[ks], n_looks)]:
        try:
            looks.append((px[k], learn_template(frames[k], bg, palette, px[k], half, angles[k])))
        except ValueError:
            continue
    expected = 4.0 * half[0] * half[1]  # the footprint's area (a near face in perspective: up to half again)
    kept = [(p, lk) for p, lk in looks if 0.5 * expected <= lk.area <= 1.6 * expected]
    square = [(p, lk) for p, lk in kept if _outline_turn(lk.template) <= LOOK_TURN_MAX]
    kept = square or kept
    if not kept:
        raise ValueError("no matte at the object's position")
    return kept


def _length(looks: list[tuple[np.ndarray, Look]], half) -> float:
    """The object's length along its axis in a sharp frame (px), for the measurement of its blur
    streaks: the upper quartile of its looks'
    (:func:`~galileo_jax.observe.measure.template_length`). A look learned in a motion-blurred
    frame is as long where neither end of its streak is cut short, and shorter where one is;
    the quartile, not the longest, because a look may also hold a little of something else."""
    return float(np.percentile([template_length(lk, half) for _, lk in looks], 75))


def _nearest(looks: list[tuple[np.ndarray, Look]], at) -> Look:
    """The look (:func:`_learn_looks`) taken nearest the position ``at`` (px)."""
    return min(looks, key=lambda pl: float(np.linalg.norm(pl[0] - at)))[1]


def _measure_all(frames, bg: ColourBackground, looks, px: np.ndarray, halves, angles: np.ndarray, speed: np.ndarray,
                 rough: np.ndarray, ks=None, lengths=None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every frame (or the frames ``ks``) of every object measured (:func:`~galileo_jax.observe.measure.measure`) around
    ``px`` (N, n, 2), each keeping out of the others' footprints there: (N, n, 2) centres
    (``px`` where not measured), (N, n) qualities (0: not measured, or not wholly inside the
    image), (N, n) aligned flags, and (N, n, 2) the measurements' ``streak`` corrections.
    ``lengths``: per object its length along its axis (px, or None), for those corrections
    (``measure``'s ``length``).

    A centre farther from the ``rough`` track (N, n, 2) than the measurement's margin plus the
    object's smaller size (2 x its smaller half) is not measured: the centroid walked off the
    object the rough pass followed, onto another thing (the scenery where an object that left
    the image was last matched: the real clip sliding_plain_R4 after its object tumbled out)."""
    N, n = px.shape[:2]
    shape = frames.shape[1:3]
    known = np.all(np.isfinite(px), axis=-1)
    pixels, quality, aligned = px.copy(), np.zeros((N, n)), np.zeros((N, n), bool)
    streak = np.zeros((N, n, 2))
    lengths = [None] * n if lengths is None else lengths
    for k in range(N) if ks is None else ks:
        for i in range(n):
            if not known[k, i] or visible_fraction(shape, px[k, i], halves[i], angles[k, i]) < 0.999:
                continue
            others = [(px[k, j], halves[j], angles[k, j]) for j in range(n) if j != i and known[k, j]]
            margin = 2.0 + 0.6 * speed[k, i]
            m = measure(frames[k], bg, _nearest(looks[i], px[k, i]), px[k, i], halves[i], angles[k, i],
                        margin=margin, blur=speed[k, i], keep_out=others, length=lengths[i])
            if np.linalg.norm(m.centre - rough[k, i]) <= margin + 2.0 * min(halves[i]):
                pixels[k, i], quality[k, i], aligned[k, i], streak[k, i] = m.centre, m.quality, m.aligned, m.streak
    return pixels, quality, aligned, streak


def track_matte(frames: np.ndarray, start_pixels, halves, angles, *, start_frame: int = 0, fps: float | None = None,
                quality_min: float = 0.5, on_loss: str = "raise", first_frame: int = 0,
                measure_frames=None, path_tilts=None) -> MatteTracks:
    """Follow objects without texture by their colour matte (module docstring).

    Three passes: (1) a rough track from ``start_frame`` forwards and backwards, matching each
    object's look in that frame (:func:`rough_pass`); (2) the background (the median of the
    frames, leaving out the objects' footprints along the rough track), and each object's
    colours and clean template from frames in which it is seen whole and alone; (3) every
    frame measured (:func:`~galileo_jax.observe.measure.measure`) at the rough track's position.

    Args:
        frames: (N, H, W, 3) uint8 BGR frames.
        start_pixels: (n, 2) centres in frame ``start_frame`` (px), objects at rest there.
        halves: per object (half along, half across) of its footprint in px.
        angles: per object its footprint's tilt at the start (rad, from the u axis).
        start_frame: frame of ``start_pixels``.
        fps: frame rate, for the times in error messages.
        quality_min: measurements of lower quality are not valid (dropped from the fit).
        on_loss: "raise" a :class:`~galileo_jax.errors.TrackingError` when an object is lost
            inside the image, or "hold" (marked invalid).
        first_frame: video frame number of ``frames[0]`` (for error messages).
        measure_frames: frames to measure in passes (2) and (3) (default all; the others keep
            the rough track, quality 0): a caller that needs only a few saves the time (and
            gets one measurement pass, on the background of the rough track).
        path_tilts: optional image tilts (rad) of the straight segments of the objects' path
            (ramp and floor, :func:`~galileo_jax.observe.tracks.path_tilts`): where a match
            gets worse, the rough pass also tries each object turned onto each of them,
            moving along it.

    Returns:
        :class:`MatteTracks`.

    Raises:
        TrackingError: an object's colour does not differ from the background at its start,
            or its track is lost inside the image (with ``on_loss="raise"``).
    """
    start = np.array(start_pixels, float).reshape(-1, 2)
    n = len(start)
    shape = frames.shape[1:3]
    halves = [np.asarray(h, float) for h in halves]
    angles0 = np.asarray(angles, float).reshape(n)
    # the plain median of the sampled frames: the rough pass's scenery (objects' start
    # footprints unknown) and the first background's starting point
    plain = frame_median(frames[spread_indices(len(frames), BACKGROUND_FRAMES)])
    scenery = static_scenery(plain, start, halves, angles0)
    fwd, r_f, b_f, lost_f = rough_pass(frames, start, halves, angles0, start_frame, +1, fps, first_frame, on_loss,
                                        scenery, path_tilts)
    bwd, r_b, b_b, _ = rough_pass(frames, start, halves, angles0, start_frame, -1, fps, first_frame, "hold",
                                   scenery, path_tilts)
    rough, rough_rms, rough_ok = fwd.copy(), r_f.copy(), b_f.copy()
    rough[:start_frame], rough_rms[:start_frame], rough_ok[:start_frame] = bwd[:start_frame], r_b[:start_frame], \
        b_b[:start_frame]
    known = np.all(np.isfinite(rough), axis=-1)
    angles = np.stack([_angles(np.nan_to_num(rough[:, i]), known[:, i], angles0[i], tilts=path_tilts)
                       for i in range(n)], axis=1)
    speed = _speeds(rough)
    reach = max(math.hypot(*h) for h in halves) + 8 + 0.6 * float(speed.max())
    region = (np.nanmin(rough, axis=(0, 1)) - reach, np.nanmax(rough, axis=(0, 1)) + reach + 1)
    # clean-frame candidates: the object confirmed against the scenery
    # (:func:`~galileo_jax.observe.rough._recentre`), else
    # (an object that hardly moves) matched about as well as usual
    good = np.isfinite(rough_rms)
    for i in range(n):
        r = rough_rms[:, i]
        if good[:, i].any():
            good[:, i] &= r <= 2.0 * np.median(r[good[:, i]]) + 2.0
        if rough_ok[:, i].sum() >= 3:
            good[:, i] = rough_ok[:, i]
    # The rough track may be off the object's centre by a few px (it follows the point of the
    # start look at the start pixel, and drifts where the look changes): the objects are
    # measured once on a background that leaves out generous footprints along it, then again
    # on one that leaves out their footprints along that first measurement (measured: the
    # second pass halves the error where the first background had to be filled in). A caller
    # that measures only a few frames (``measure_frames``: the object finder, near an object's
    # start) gets the first pass alone.
    px, look_frame = rough, np.full(n, -1)
    bg = None
    grows = (0.5 * max(max(h) for h in halves), 0.0)
    for grow_extra in grows if measure_frames is None else grows[:1]:
        bg = colour_background(frames, footprints_along(px, halves, angles, shape, 3.0 + 0.3 * speed + grow_extra),
                               region=region, median=plain if bg is None else bg.median)
        bg = unlearn_objects(bg, frames, start_frame, start, halves, angles0)
        looks = []
        for i in range(n):
            for after_moving in (True, False):  # the frames it rested in if the others show no object
                ks = _clean_frames(px, good, i, halves, speed, shape, start, after_moving)
                try:
                    looks.append(_learn_looks(frames, bg, px[:, i], ks, halves[i], angles[:, i]))
                    look_frame[i] = ks[0]
                    break
                except ValueError:
                    continue
            else:
                raise TrackingError(f"object {i + 1}: its colour does not stand out from the background (at pixel "
                                    f"({start[i, 0]:.0f}, {start[i, 1]:.0f}) in frame {start_frame + first_frame}); "
                                    "check camera.start_pixels, or try tracker: features", object_index=i) from None
        lengths = [_length(looks[i], halves[i]) if measure_frames is None else None for i in range(n)]
        pixels, quality, aligned, streak = _measure_all(frames, bg, looks, px, halves, angles, speed, rough,
                                                        measure_frames, lengths)
        measured_px = pixels.copy()
        if measure_frames is None:
            good = quality >= 0.8
        else:  # frames not measured keep their rough-pass verdict
            ks = np.asarray(list(measure_frames), int)
            good[ks] = quality[ks] >= 0.8
        px = np.where((quality >= quality_min)[..., None], pixels, px)
    if measure_frames is None:
        _bridge(frames, bg, looks, pixels, quality, aligned, halves, angles, quality_min)
        _restore_order(pixels, quality, aligned, start, halves, quality_min)
    measured = quality >= quality_min
    valid = _without_jumps(pixels, _not_isolated(measured & _in_order(pixels, start, measured)), halves)
    lost = lost_f.copy()
    if measure_frames is None:
        lost = np.where(lost >= 0, lost, _unseen_till_end(valid, rough, halves, angles, shape, start_frame))
        doubted = _identity_doubted(pixels, valid, lost, [lk[0][1].palette for lk in looks])
        if doubted.any():
            valid &= ~doubted
            lost = np.where(lost >= 0, lost, _unseen_till_end(valid, rough, halves, angles, shape, start_frame))
        lost = _stopped_where_lost(frames, bg, looks, pixels, quality, aligned, valid, lost, halves, angles)
    streak[~np.all(pixels == measured_px, axis=-1)] = 0.0  # bridged or exchanged since: not that measurement's
    return MatteTracks(pixels, valid, quality, aligned, lost, rough, look_frame, streak)


def _look_alike(a: Palette, b: Palette) -> bool:
    """True if each palette's colours lie within the other's tolerance of one of its colours
    brightened or darkened by up to :data:`~galileo_jax.observe.colour.GAIN` (as the matte
    explains a pixel: each object would be matted as the other)."""
    def explained(x: Palette, by: Palette) -> bool:
        return bool(np.all(best_gain(x.colours, by.colours)[1] <= by.tolerance ** 2))
    return explained(a, b) and explained(b, a)


def _identity_doubted(pixels: np.ndarray, valid: np.ndarray, lost: np.ndarray, palettes) -> np.ndarray:
    """(N, n) bool: frames whose measurement may be of another object. Once an object's track
    is lost inside the image (``lost`` (n,) frame, -1 if not), a look-alike of it (:func:`_look_alike`)
    can no longer be told from it: the look-alike's valid frames from that frame on are in
    doubt from the first in which it has moved from where it was in its last valid frame
    before (by more than :data:`ALIKE_REST_PX` px); while it rests
    where it was, it is itself. Measured on the held-out tracking video world_11: a fast cube
    (BGR colours 244, 235, 250 and a face in shade) lost as it struck a resting look-alike (209,
    215, 247); the struck cube's track then moved onto the striker's resting place and measured
    it at quality 0.9 (10.8 px median error)."""
    N, n = valid.shape
    out = np.zeros((N, n), bool)
    for i in range(n):
        if lost[i] < 0:
            continue
        for j in range(n):
            if j == i or not _look_alike(palettes[i], palettes[j]):
                continue
            before = np.flatnonzero(valid[:lost[i], j])
            if not len(before):
                continue
            at = pixels[before[-1], j]
            later = np.arange(lost[i], N)
            moved = later[valid[later, j] & (np.linalg.norm(pixels[later, j] - at, axis=-1) > ALIKE_REST_PX)]
            if len(moved):
                out[moved[0]:, j] |= valid[moved[0]:, j]
    return out


def _bridge(frames, bg: ColourBackground, looks, pixels: np.ndarray, quality: np.ndarray, aligned: np.ndarray,
            halves, angles: np.ndarray, quality_min: float, coast: int = 3) -> None:
    """Follow each object on from its own measurements where the rough track left it (in place).

    After the last frame of a measured run, each next frame is measured
    (:func:`~galileo_jax.observe.measure.measure`) where
    the object's last two measured centres (constant velocity) put it, keeping out of the other
    objects' footprints where they are measured; a measurement of quality >=
    :data:`BRIDGE_QUALITY` (stricter than ``quality_min``: no rough match confirms it) is taken
    and moves the prediction on. After ``coast`` frames running without one, or where the
    object would leave the image, the run ends; it ends too at a frame measured where the
    prediction puts the object (within the measurement's margin and the object's size), but
    not at one measured far from it, which is of something else where the rough track had
    gone: there the bridge measures on, and where it finds the object, its measurement replaces
    that one (held-out world_107: the scenery 390 px off, at quality 0.73, in the frame after
    the bridge had followed the object for 11 frames; the run ended there, and the object's
    last 20 frames were lost). Measured on the tracking benchmark: the rough
    pass lost a small object at a collision, running 20-30 px ahead of or behind it (two
    look-alikes touching at 320x240), and every frame after it went unmeasured.

    Args:
        pixels, quality, aligned: (N, n, 2) px, (N, n), (N, n) from :func:`_measure_all`,
            updated where a frame is bridged.
        halves, angles: footprint half sizes per object (px) and (N, n) tilts (rad).
        quality_min: the validity threshold of the track.
    """
    N, n = quality.shape
    shape = frames.shape[1:3]
    ok = quality >= quality_min
    for i in range(n):
        k = 2
        while k < N:
            if ok[k, i] or not ok[k - 1, i]:
                k += 1
                continue
            p = pixels[k - 1, i].copy()
            v = p - pixels[k - 2, i] if ok[k - 2, i] else np.zeros(2)
            missed = 0
            while k < N and missed < coast:
                guess = p + v
                speed = float(np.linalg.norm(v))
                margin = 2.0 + 0.6 * speed
                if ok[k, i] and np.linalg.norm(pixels[k, i] - guess) <= margin + 2.0 * max(halves[i]):
                    break  # measured where it was heading: the track goes on from there
                if visible_fraction(shape, guess, halves[i], angles[k, i]) < 0.999:
                    break
                others = [(pixels[k, j], halves[j], angles[k, j]) for j in range(n) if j != i and ok[k, j]]
                m = measure(frames[k], bg, _nearest(looks[i], guess), guess, halves[i], angles[k, i],
                            margin=margin, blur=speed, keep_out=others)
                if m.quality >= BRIDGE_QUALITY and np.linalg.norm(m.centre - guess) <= margin + min(halves[i]):
                    pixels[k, i], quality[k, i], aligned[k, i] = m.centre, m.quality, m.aligned
                    ok[k, i] = True
                    v, p, missed = m.centre - p, m.centre, 0
                else:
                    p, missed = guess, missed + 1
                k += 1
            while k < N and not ok[k, i]:
                k += 1


def _stopped_where_lost(frames, bg: ColourBackground, looks, pixels: np.ndarray, quality: np.ndarray,
                        aligned: np.ndarray, valid: np.ndarray, lost: np.ndarray, halves, angles: np.ndarray,
                        coast: int = 3) -> np.ndarray:
    """Look for each lost object where it was last measured (in place): it may have stopped there.

    A striker that stops after a collision often rests where the struck object rested before
    it (or beside it), so no frame shows that ground free: the background there is learned in
    the objects' colours, the striker's measurements at rest are poor, the rough pass runs on
    past it, and the track is lost (the tracking benchmark's checker_persp_320x240_blur_3: two
    green checker cubes 13 px across, the striker stopped 6 px from the struck cube's start;
    its last 22 frames were measured on the struck cube and dropped). Here, from the object's
    last valid frame on, the background under it is unlearned as at the start
    (:func:`~galileo_jax.observe.colour.unlearn_objects`, the last frame showing it at rest)
    and each frame is measured where the object was last found, keeping out of the other
    objects' valid footprints; a measurement of quality >= :data:`BRIDGE_QUALITY` is taken if
    the object is slowing to rest: it moved from there by at most its last step per frame plus
    :data:`STOP_SLACK_PX` (a look-alike arriving beside the place where the lost object rested,
    the held-out world_11's striker 7 px from the struck cube's resting place, is not taken for
    it: it would have been followed as that object, 10 px off). The object counts as found
    again (``lost`` -1) only when the frames from its loss to the end are measured so, but for
    gaps shorter than ``coast`` frames; otherwise nothing changes.

    Args:
        pixels, quality, aligned, valid: (N, n, 2), (N, n), (N, n), (N, n) of the track, updated
            where the object is found again.
        lost: (n,) frame of each object's loss (-1: not lost).
        halves, angles: footprint half sizes per object (px) and (N, n) tilts (rad).

    Returns:
        (n,) ``lost`` with -1 for the objects found again.
    """
    N, n = valid.shape
    shape = frames.shape[1:3]
    lost = lost.copy()
    for i in range(n):
        seen = np.flatnonzero(valid[:max(lost[i], 0), i])
        if lost[i] < 0 or not len(seen):
            continue
        g = int(seen[-1])
        at, angle = pixels[g, i].copy(), float(angles[g, i])
        if visible_fraction(shape, at, halves[i], angle) < 0.999:
            continue
        bg_i = unlearn_objects(bg, frames, N - 1, [at], [halves[i]], [angle])
        before = np.flatnonzero(valid[:g, i])
        step = float(np.linalg.norm(at - pixels[before[-1], i]) / (g - before[-1])) if len(before) else 0.0
        found, missed = {}, 0
        for k in range(g + 1, N):
            others = [(pixels[k, j], halves[j], angles[k, j]) for j in range(n) if j != i and valid[k, j]]
            m = measure(frames[k], bg_i, _nearest(looks[i], at), at, halves[i], angle, margin=2.0,
                        keep_out=others)
            moved = float(np.linalg.norm(m.centre - at))
            if m.quality >= BRIDGE_QUALITY and moved <= (missed + 1) * step + STOP_SLACK_PX:
                # the move per frame over the frames since the last measurement
                found[k], at, step, missed = m, m.centre, moved / (missed + 1), 0
            else:
                missed += 1
                if missed >= coast:
                    break
        if missed >= coast or not found:
            continue
        for k, m in found.items():
            pixels[k, i], quality[k, i], aligned[k, i], valid[k, i] = m.centre, m.quality, m.aligned, True
        lost[i] = -1
    return lost


def _restore_order(pixels: np.ndarray, quality: np.ndarray, aligned: np.ndarray, start: np.ndarray, halves,
                   quality_min: float) -> np.ndarray:
    """Exchange two objects' measurements (in place) in the frames where both are measured
    (quality >= ``quality_min``), farther apart than either's smaller half size, and in the
    reverse of their ``start`` (n, 2) order: exchanged they are in order. Two objects on one path
    cannot pass through each other, so such a pair is the same two objects with their identities
    swapped (look-alikes colliding: the rough pass followed each onto the other; measured on the
    tracking benchmark's plain_persp_960x540_blur_0, two pink cubes 0.08 apart in colour, every
    frame after the collision was swapped, and dropping them lost object 2's whole slide).
    Returns the (N, n) bool entries exchanged."""
    N, n = quality.shape
    exchanged = np.zeros((N, n), bool)
    for i in range(n):
        for j in range(i + 1, n):
            apart = np.linalg.norm(pixels[:, j] - pixels[:, i], axis=-1) > max(min(halves[i]), min(halves[j]))
            swapped = ((quality[:, i] >= quality_min) & (quality[:, j] >= quality_min) & apart
                       & (_along_start(pixels, start, i, j) < 0.0))
            for a in (pixels, quality, aligned):
                a[swapped, i], a[swapped, j] = a[swapped, j].copy(), a[swapped, i].copy()
            exchanged[swapped, i] = exchanged[swapped, j] = True
    return exchanged


def _along_start(pixels: np.ndarray, start: np.ndarray, i: int, j: int) -> np.ndarray:
    """(N,) per frame the vector from object ``i`` to object ``j`` (``pixels`` (N, n, 2)) dotted
    with the one between their ``start`` (n, 2) positions: negative once their order reversed."""
    return np.einsum("kc,c->k", pixels[:, j] - pixels[:, i], start[j] - start[i])


def _in_order(pixels: np.ndarray, start: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """(N, n) bool: False for both objects of a pair in the frames where both are ``measured``
    (N, n) and their centres (N, n, 2) are no longer in the order of their ``start`` (n, 2): the
    vector from one to the other has turned by 90 degrees or more from where it pointed there.
    Two objects on one ramp cannot pass through each other, so their identities are in doubt
    there (look-alikes after a collision at speed: the rough pass keeps their order frame to
    frame, but a measurement or a bridge can still take the other's place). Where one of the two
    is not measured, its position is only the rough track's (which may have left it for the
    other object; held-out world_62: it then ran off to the image corner, and every later
    measurement of the other object was dropped with it), so nothing is judged there."""
    N, n = pixels.shape[:2]
    ok = np.ones((N, n), bool)
    for i in range(n):
        for j in range(i + 1, n):
            swapped = (_along_start(pixels, start, i, j) <= 0.0) & measured[:, i] & measured[:, j]
            ok[swapped, i] = ok[swapped, j] = False
    return ok


def _not_isolated(valid: np.ndarray) -> np.ndarray:
    """(N, n) ``valid`` without the frames whose neighbours on both sides (or on the one side
    at either end) are not valid: a lone measurement between unmeasured frames gives no
    velocity and cannot be checked against the motion around it (on the real clip
    sliding_plain_R4, after its object tumbled out of the image, such lone frames were dark
    scenery of the object's colour, every 20-50 frames)."""
    before = np.zeros_like(valid)
    after = np.zeros_like(valid)
    before[1:] = valid[:-1]
    after[:-1] = valid[1:]
    return valid & (before | after)


def _without_jumps(pixels: np.ndarray, valid: np.ndarray, halves, min_run: int = 5) -> np.ndarray:
    """(N, n) ``valid`` without the short runs of frames that the object's track jumps into and
    out of: split each object's valid frames (``pixels`` (N, n, 2)) where the centre moves
    farther per frame than twice the 95th percentile speed of all objects' valid tracks plus its
    larger half size (``halves``), and drop the pieces of fewer than ``min_run`` frames, unless
    that leaves nothing. (All objects' speeds: a resting object struck by another moves as fast
    as the striker, in the first frame of its slide.) Such a piece is a measurement of something
    else (held-out world_107: after a collision the tracker took the scenery 390 px away for
    object 1 in two frames); a fit given it would see a velocity of hundreds of px per frame."""
    out = valid.copy()
    frames = [np.flatnonzero(valid[:, i]) for i in range(valid.shape[1])]
    speeds = [np.linalg.norm(np.diff(pixels[ks, i], axis=0), axis=-1) / np.diff(ks) for i, ks in enumerate(frames)]
    if not any(len(v) for v in speeds):
        return out
    fast = float(np.percentile(np.concatenate(speeds), 95))
    for i, (ks, speed) in enumerate(zip(frames, speeds)):
        pieces = np.split(ks, np.flatnonzero(speed > 2.0 * fast + max(halves[i])) + 1)
        short = [p for p in pieces if len(p) < min_run]
        if len(pieces) > 1 and len(short) < len(pieces):
            for p in short:
                out[p, i] = False
    return out


def _unseen_till_end(valid: np.ndarray, rough: np.ndarray, halves, angles: np.ndarray, shape, start_frame: int,
                     min_frames: int = 5, min_share: float = 0.25) -> np.ndarray:
    """(n,) per object the frame after its last good measurement if from there to the end it
    is never measured again although the rough track keeps it inside the image for at least
    ``min_frames`` frames and ``min_share`` of the video (hidden, or lost: a board in front of
    it, the light gone); -1 if not (a shorter unmeasured end is dropped, not an error)."""
    N, n = valid.shape
    out = np.full(n, -1)
    for i in range(n):
        seen = np.flatnonzero(valid[:, i])
        last = int(seen[-1]) if len(seen) else start_frame
        after = [k for k in range(last + 1, N) if np.all(np.isfinite(rough[k, i]))
                 and visible_fraction(shape, rough[k, i], halves[i], angles[k, i]) >= 1.0]
        if len(after) >= max(min_frames, min_share * N):
            out[i] = last + 1
    return out
