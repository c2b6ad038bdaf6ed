"""Finding the objects when the scene does not say where they start.

:func:`locate_objects` / :func:`find_objects`: object 1 from the first steady motion down the
ramp's image direction (dense optical flow), refined by its silhouette against the background;
object 2 where the scene puts it, from the first change of its footprint. See
:func:`locate_objects` for the whole procedure.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np

from galileo_jax.calibration import Calibration
from galileo_jax.errors import TrackingError
from galileo_jax.observe.klt import track_objects
from galileo_jax.observe.matte import track_matte
from galileo_jax.observe.motion import MAX_ANGLE_DEG, Small, dense_flow, downscale, first_motion, roi_box
from galileo_jax.observe.outline import track_circles
from galileo_jax.observe.track import track_scene, tracker_of
from galileo_jax.observe.tracks import (Window, background_model, expected_start_pixels, frame_median,
                                       inside_fraction, object_windows, path_direction, polygon_mask, spread_indices,
                                       window_corners)
from galileo_jax.scene import Scene


def _diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Largest per-channel absolute difference of two images (int)."""
    d = np.abs(a.astype(np.int16) - b.astype(np.int16))
    return d.max(axis=-1) if d.ndim == 3 else d


def _crop_radius(window: Window) -> int:
    """Half size (px) of the square searched for an object's silhouette."""
    return int(2 * max(window.half) + 10)


def silhouette_centre(pre: np.ndarray, background: np.ndarray, rough, window: Window, reach: float | None = None
                      ) -> np.ndarray | None:
    """Centre (px) of a resting object's silhouette, by background subtraction.

    Args:
        pre: (m, H, W, 3) frames in which the object rests at ``rough``.
        background: (H, W, 3) the same view without the object.
        rough: (2,) approximate centre (px), inside the object.
        window: its expected footprint (for the search region and a size check).
        reach: how far (px) outside a region ``rough`` may lie (default half the footprint's
            smaller half size); of several regions the nearest is taken.

    Returns:
        The centroid of the filled region that differs from the background in every frame
        of ``pre`` and does not change between them (so a hand moving over it is left
        out), or None if no region of plausible size contains ``rough`` (or lies within
        ``reach`` of it).
    """
    if not np.all(np.isfinite(rough)):  # a track that lost the object there
        return None
    radius = _crop_radius(window) + (0 if reach is None else int(math.ceil(reach)))  # the object well inside
    lo, hi = roi_box(background.shape[:2], rough, radius)
    if np.any(hi - lo < 3):  # ``rough`` outside the image: nothing to see (and OpenCV asserts on empty arrays)
        return None
    crop = (slice(lo[1], hi[1]), slice(lo[0], hi[0]))
    last = pre[-1][crop]
    d_bg = np.stack([_diff(p[crop], background[crop]) for p in pre])
    thr = max(15.0, 5.0 * float(np.median(d_bg[-1])))
    fg = (d_bg > thr).all(0)
    for p in pre[:-1]:
        fg &= _diff(p[crop], last) < thr
    mask = cv2.morphologyEx(fg.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    expected = 4 * window.half[0] * window.half[1]
    here = np.asarray(rough, float) - lo
    limit = 0.5 * min(window.half) if reach is None else reach  # how far outside a region ``rough`` may be
    best, best_key = None, None
    for c in contours:
        area = cv2.contourArea(c)
        dist = cv2.pointPolygonTest(c, (float(here[0]), float(here[1])), True)
        if 0.4 * expected <= area <= 2.5 * expected and dist > -limit:
            # the largest; with a ``reach``, the nearest (of those containing ``rough``, the largest)
            key = (0.0 if reach is None else min(dist, 0.0), area)
            if best is None or key > best_key:
                best, best_key = c, key
    if best is None:
        return None
    filled = np.zeros(mask.shape, np.uint8)
    cv2.drawContours(filled, [best], -1, 1, -1)
    m = cv2.moments(filled, binaryImage=True)
    return np.array([m["m10"] / m["m00"], m["m01"] / m["m00"]]) + lo


def _centre_in_motion(frames, k: int, rough, window: Window, k_start: int, k1: int, n: int = 25
                      ) -> np.ndarray | None:
    """Object 1's centre in frame ``k``, where the motion detector saw it a couple of
    diagonals down its path (``rough``, often half an object off: flow inside a plain object
    is vague): the centroid of its silhouette (:func:`silhouette_centre`) against the median
    of frames in which it was elsewhere: at rest before ``k_start`` (up the ramp), and
    after it has gone as far again (it took ``k - k1`` frames to come here from where it
    started, and accelerates). None if no silhouette of its size is found there."""
    later = k + 2 * (k - k1) + 2
    idx = list(range(0, k_start)) + list(range(later, len(frames)))
    if len(idx) < 3:
        return None
    idx = np.asarray(idx)[spread_indices(len(idx), n)]
    background = frame_median(frames[idx]).astype(np.uint8)
    found = silhouette_centre(frames[k:k + 1], background, rough, window)
    if found is None:  # the flow can be more than half an object off (a small plain object)
        found = silhouette_centre(frames[k:k + 1], background, rough, window, reach=2.0 * math.hypot(*window.half))
    return found


def _off_path(disp: np.ndarray, k_from: int, direction: np.ndarray, n: int = 15) -> float:
    """How badly a displacement track (N, 2) px leaves the object's path over the ``n``
    frames after ``k_from``: the largest distance across ``direction`` plus the largest
    distance backwards along it, over the largest distance forwards (0 for a track straight
    down its path; a hand lifting off gives 1 or more)."""
    d = disp[k_from: k_from + n]
    along = d @ direction
    across = np.abs(d @ np.array([-direction[1], direction[0]]))
    return float((across.max() + max(-along.min(), 0.0)) / max(along.max(), 1.0))


def _displacements(frames, k_from: int, start, window: Window, background=None, method: str = "auto",
                   k_at: int | None = None, direction=None, k_check: int | None = None, start_at=None
                   ) -> tuple[np.ndarray | None, np.ndarray]:
    """Follow one object from frame ``k_from`` to the end.

    By its outline (``method`` "outline", a rolling sphere), by KLT ("features") or by its
    colour ("colour"; "auto": both, KLT from where the colour tracker saw the object rest,
    keeping the track that leaves the object's path in ``direction`` least
    (:func:`_off_path`): one of them may follow a hand lifting off). The
    colour tracker starts at ``start_at`` (default ``start``) in frame ``k_at`` (default
    ``k_from``; e.g. where a motion detector saw the object clear of a hand, frames after it
    started) and follows it backward to ``k_from`` too; the others start at ``start`` in frame
    ``k_from``. ``k_check``: the frame
    around which the object starts to move (default ``k_at``), where "auto" compares the tracks.

    Returns:
        ``(rest, disp)``: the object's pixel in frame ``k_from`` as the colour tracker measured
        it (None for the other methods, which take ``start`` as given), and (N, 2) its
        displacement from there in every frame (zeros before ``k_from``), px.
    """
    tail = frames[k_from:]
    k_at = k_from if k_at is None else k_at
    k_check = k_at if k_check is None else k_check
    found = []  # (rest, disp)
    if method == "outline":
        found.append((None, track_circles(tail, [start], [window.half[0]]).pixels[:, 0]))
    if method in ("colour", "auto"):
        try:
            mt = track_matte(tail, [start if start_at is None else start_at], [window.half], [window.angle],
                             start_frame=k_at - k_from, on_loss="hold",
                             measure_frames=range(0, min(len(tail), k_check - k_from + 16)))
            px = np.where(np.isfinite(mt.pixels[:, 0]), mt.pixels[:, 0], mt.rough[:, 0])  # measured near the start
            found.append((px[0] if np.all(np.isfinite(px[0])) else None, px))
        except TrackingError:
            if method == "colour":
                raise
    if method in ("features", "auto"):
        at = found[0][0] if found and found[0][0] is not None else start  # where the colour tracker saw it rest
        try:
            found.append((None if at is start else at, track_objects(tail, [at], [window], background=background,
                                                                     min_features=3).pixels[:, 0]))
        except TrackingError:
            if method == "features" or not found:
                raise
    out = []
    for rest, px in found:
        px = px.copy()
        for k in range(1, len(px)):  # after a loss: the last position
            if not np.all(np.isfinite(px[k])):
                px[k] = px[k - 1]
        disp = np.zeros((len(frames), 2))
        disp[k_from:] = px - px[0]
        out.append((rest, disp))
    if len(out) > 1 and direction is not None:  # "auto": the one that follows the object down its path
        return min(out, key=lambda o: _off_path(o[1], max(k_check - 3, k_from), direction))
    return out[0]


def _refine(frames, k_on: int, rough, window: Window, disp: np.ndarray, clear=None) -> np.ndarray | None:
    """Start pixel from the silhouette at the start: background taken from frames where the
    object has moved off its start (and ``clear(k)``, no other object there, holds). None
    if that is not possible."""
    far = 2 * math.hypot(*window.half) + 4
    ks = [k for k in range(k_on, len(frames)) if np.linalg.norm(disp[k]) > far and (clear is None or clear(k))]
    if not ks:
        return None
    background = frame_median(frames[ks[:5]]).astype(np.uint8)
    pre = frames[max(0, k_on - 4): max(1, k_on)]
    return _checked(silhouette_centre(pre, background, rough, window), rough, window)


def _refine_in_motion(frames, k_on: int, rough, window: Window, disp: np.ndarray, clear=None,
                      n_use: int = 3) -> np.ndarray | None:
    """Start pixel from the object's silhouette in the first frames after it has moved off
    its start by two diagonals (clear of a hand that held it there), against the background
    of the last frames in which it still rested (tracked displacement < 0.5 px), minus its
    tracked displacement; the mean over up to ``n_use`` frames. ``clear(k, at)`` says no
    other object is near pixel ``at`` in frame k. None if no frame qualifies."""
    far = 2 * math.hypot(*window.half) + 4
    resting = np.flatnonzero(np.linalg.norm(disp[:max(k_on, 1)], axis=1) < 0.5)
    ks_bg = resting[-5:].tolist()
    if not ks_bg:
        return None
    background = None
    found = []
    for k in range(k_on, len(frames)):
        at = np.asarray(rough, float) + disp[k]
        if np.linalg.norm(disp[k]) <= far or inside_fraction(window_corners(at, window), frames.shape[1:]) < 1:
            continue
        if clear is not None and not all(clear(j, at) for j in ks_bg + [k]):
            continue
        if background is None:
            background = frame_median(frames[ks_bg]).astype(np.uint8)
        centre = _checked(silhouette_centre(frames[k:k + 1], background, at, window), at, window)
        if centre is not None:
            found.append(centre - disp[k])
        if len(found) >= n_use or k > k_on + 30:
            break
    return np.mean(found, axis=0) if found else None


def _checked(centre, rough, window: Window):
    """``centre`` if it is within 1.2 half-lengths of ``rough`` (the silhouette also had to
    contain ``rough``), else None."""
    if centre is None or np.linalg.norm(centre - np.asarray(rough, float)) > 1.2 * max(window.half):
        return None
    return centre


class Located(NamedTuple):
    """Where the objects are found (:func:`locate_objects`).

    Attributes:
        pixels: (n, 2) centres (u, v) in px in frame ``frame``, where object 1 rests for the
            last time before it slides (a hand that held it may still be there).
        frame: that frame.
        clean_pixels: (n, 2) centres in frame ``clean_frame``, a few frames later, where object
            1 was seen whole, clear of the hand, and the other objects still rest; or None.
        clean_frame: that frame, or None.
    """

    pixels: np.ndarray
    frame: int
    clean_pixels: np.ndarray | None
    clean_frame: int | None


def never_moves_error(scene: Scene) -> TrackingError:
    """The error for a video in which object 1 does not slide."""
    tan = math.tan(scene.ramp.angle)
    return TrackingError(f"object 1 never moves in the video: nothing to fit (the video only says friction "
                         f"k1 >= tan(theta) = {tan:.3f}); if it does move, give camera.start_pixels")


def find_objects(frames: np.ndarray, scene: Scene, calib: Calibration,
                 background: np.ndarray | None = None) -> np.ndarray:
    """Each object's centre in frame 0 (see :func:`locate_objects`), (n_objects, 2) px.

    Raises:
        TrackingError: as :func:`locate_objects`.
    """
    start, k = locate_objects(frames, scene, calib, background)[:2]
    if k == 0:
        return start
    return track_scene(frames[: k + 1], start, scene, calib, start_frame=k, background=background).tracks.pixels[0]


def locate_objects(frames: np.ndarray, scene: Scene, calib: Calibration,
                   background: np.ndarray | None = None) -> Located:
    """Find the objects from the motion in the video and the scene's geometry.

    Object 1 is the first region that starts a steady motion down the ramp's image
    direction (dense optical flow on downscaled frames, chained over 3 frames); regions that
    move against that direction (a hand lifting off, moving up or out), wander off the ramp
    line, or start at the image border are rejected. With ``camera.foot_pixel`` it is first
    searched near the pixel the calibrated scene predicts (and that prediction is kept when
    the motion confirms it). Its centre is then refined by background subtraction: the
    centroid of its silhouette in the first frames after it has slid two diagonals away
    from the start (clear of a hand that held it), minus its tracked displacement; failing
    that, the silhouette in the last frames before it moves, keeping only pixels that stay
    unchanged (a hand moving over it is cut out). Object 2 is searched where the scene puts
    it (object 1's pixel plus the scene's start offset, or the calibrated prediction): the
    first frame in which its footprint changes, away from object 1's tracked footprint,
    then the same silhouette refinement while object 1 is clear of it; if it never moves,
    the scene's prediction is used.

    Args:
        frames: (N, H, W, 3) uint8 BGR frames.
        scene: the scene (ramp direction, object sizes and start positions).
        calib: its calibration (scale, direction, roll; anchored at ``foot_pixel`` if any).
        background: grey background (:func:`background_model`), computed if not given.

    Returns:
        :class:`Located`: the centres in the last frame in which object 1 rests before it
        starts to slide (a hand that let go may still be there); track from there
        (:func:`track_scene`); and, where object 1 was seen clear of the hand a few frames
        later, the centres there (the colour tracker starts from them).

    Raises:
        TrackingError: nothing moves down the ramp (object 1 never moves, or is not seen
            to), or object 1 cannot be tracked.
    """
    small = downscale(frames)
    wins = object_windows(scene, calib)
    bg = background_model(frames) if background is None else background
    prior = expected_start_pixels(scene, calib) if scene.camera.foot_pixel is not None else None
    p1, k1, p_far, k_far = _find_first(small, scene, calib, wins[0], prior)
    k_start = _rest_frame(small, k1, p1, wins[0], path_direction(scene, calib, 0))  # tracked from here
    seen_far = _centre_in_motion(frames, k_far, p_far, wins[0], k_start, k1)
    p_far = p_far if seen_far is None else seen_far
    method = tracker_of(scene, 0)
    rest, disp1 = _displacements(frames, k_start, p1, wins[0], bg, method, k_at=k_far, start_at=p_far,
                                 k_check=k1, direction=path_direction(scene, calib, 0))
    if rest is not None:  # followed by colour back to where it rested: its pixel there
        p1, method = rest, "colour"
    for it in range(0 if method == "colour" else 2):  # again from the refined centre if far off (a smooth object)
        if it > 0:
            _, disp1 = _displacements(frames, k_start, p1, wins[0], bg, method)
        refined = _refine_in_motion(frames, k1, p1, wins[0], disp1)
        if refined is None:
            refined = _refine(frames, k1, p1, wins[0], disp1)
        if refined is None or np.linalg.norm(refined - p1) < 0.25 * max(wins[0].half):
            p1 = p1 if refined is None else refined
            break
        p1 = refined
    out, clean = [p1], [p_far]
    if scene.n_objects == 2:
        p2, k2 = _find_second(frames, small, scene, calib, wins, p1, p1 + disp1, k1, prior, bg)
        out.append(p2)
        clean.append(p2)
        if k2 is not None and k2 <= k_far:  # object 2 already moving there: no clean start
            seen_far = None
    if seen_far is None:
        return Located(np.array(out), k_start, None, None)
    return Located(np.array(out), k_start, np.array(clean), k_far)


def _rest_frame(small: Small, k: int, centre, window: Window, direction: np.ndarray) -> int:
    """The last frame, going back from ``k``, in which the object at ``centre`` (px) is still
    at rest: fewer than 15% of its footprint's pixels flow down its path (> 0.3 px/frame
    at the working scale) into the next frame. A smooth or low-contrast object (an air-track
    cart) is seen moving steadily only frames after it started."""
    region = polygon_mask(small.gray.shape[1:], small.to_small(window_corners(centre, window))) > 0
    ys, xs = np.nonzero(region)
    if not len(ys):
        return max(0, k - 2)
    lo, hi = np.array([xs.min(), ys.min()]) - 8, np.array([xs.max(), ys.max()]) + 9
    lo, hi = np.maximum(lo, 0), np.minimum(hi, small.gray.shape[:0:-1])
    inside = region[lo[1]:hi[1], lo[0]:hi[0]]
    cos = math.cos(math.radians(MAX_ANGLE_DEG))
    for j in range(k - 1, -1, -1):
        flow = dense_flow(small.gray[j, lo[1]:hi[1], lo[0]:hi[0]], small.gray[j + 1, lo[1]:hi[1], lo[0]:hi[0]])
        along = flow @ direction
        moving = (along > 0.3) & (along >= cos * np.linalg.norm(flow, axis=-1))
        if moving[inside].mean() < 0.15:
            return j
    return 0


def _min_area(small: Small, window: Window) -> float:
    return max(6.0, 0.25 * 4 * window.half[0] * window.half[1] * small.f ** 2)


def _find_first(small: Small, scene, calib, window: Window, prior) -> tuple[np.ndarray, int, np.ndarray, int]:
    """Object 1's rough centre (px) and the frame its steady motion starts; and its rough
    centre in a frame a diagonal further on (clear of a hand that held it), and that frame."""
    direction = path_direction(scene, calib, 0)
    area = _min_area(small, window)
    kw = dict(away=2 * math.hypot(*window.half) * small.f, depth=2 * window.half[0] * small.f)
    found = None
    if prior is not None:
        radius = max(3 * max(window.half), 0.1 * calib.scale) * small.f
        found = first_motion(small, direction, small.to_small(prior[0]), radius, area, **kw)
    if found is None:
        found = first_motion(small, direction, None, None, area, **kw)
    if found is None:
        raise never_moves_error(scene)
    rough = small.to_full(found.centroid)
    if prior is not None and np.linalg.norm(rough - prior[0]) < max(window.half):
        rough = prior[0]  # the calibrated scene's prediction, when the motion confirms it
    return rough, found.k, small.to_full(found.centroid_far), found.k_far


def _footprints(track: np.ndarray, window: Window, small: Small):
    """``mask(k)``: (h, w) bool, the downscaled pixels covered by an object whose centre
    follows ``track`` (N, 2) px, its rectangle turned to its direction of motion, plus a
    margin for the spread of dense flow."""
    shape = small.gray.shape[1:]
    angle = window.angle
    masks = {}

    def mask(k):
        nonlocal angle
        k = min(k, len(track) - 1)
        if k not in masks:
            v = track[min(k + 1, len(track) - 1)] - track[max(k - 1, 0)]
            if np.linalg.norm(v) > 2.0:
                angle = math.atan2(v[1], v[0])
            margin = 4.0 / small.f
            w = Window((window.half[0] + margin, window.half[1] + margin), angle)
            masks[k] = polygon_mask(shape, small.to_small(window_corners(track[k], w))) > 0
        return masks[k]

    return mask


def _change_onset(small: Small, centre, window: Window, k_start: int, exclude) -> int | None:
    """First frame k > ``k_start`` at which at least a fifth of the object's footprint
    around ``centre`` (px) changes from frame k-1, and again from k to k+1 (pixels that
    ``exclude(k)`` marks are ignored). Changes, not flow: object 2 is set moving by an impact
    and may jump tens of pixels in a frame, which dense flow does not follow."""
    grown = Window((window.half[0] * 1.3, window.half[1] * 1.3), window.angle)
    region = polygon_mask(small.gray.shape[1:], small.to_small(window_corners(centre, grown))) > 0
    if region.sum() < 4:
        return None

    def changed(k):
        d = cv2.absdiff(small.gray[k], small.gray[k - 1])
        noise = 1.4826 * float(np.median(d)) + 1.0
        sel = region & ~exclude(k - 1) & ~exclude(k)
        return sel.sum() >= 0.3 * region.sum() and ((d > max(6.0, 4.0 * noise)) & sel).sum() >= 0.2 * sel.sum()

    for k in range(max(k_start, 0) + 1, len(small.gray) - 1):
        if changed(k) and changed(k + 1):
            return k
    return None


def _find_second(frames, small: Small, scene, calib, wins, p1, track1, k1, prior, bg) -> tuple[np.ndarray, int | None]:
    """Object 2's start pixel (see :func:`find_objects`) and the frame it starts to change
    (None if it never does); ``track1`` (N, 2) object 1's pixels."""
    expected = prior[1] if prior is not None else expected_start_pixels(scene, calib, p1)[1]
    w1, w2 = wins
    footprints = _footprints(track1, w1, small)
    k2 = _change_onset(small, expected, w2, k1, lambda k: footprints(k))
    if k2 is None:
        return expected, None
    try:
        rest, disp2 = _displacements(frames, 0, expected, w2, bg, tracker_of(scene, 1),
                                     direction=path_direction(scene, calib, 1), k_check=k2)
    except TrackingError:
        return expected, k2
    if rest is not None:  # followed by colour: measured where it rests
        return rest, k2
    clear_r = math.hypot(*w1.half) + _crop_radius(w2) + 2  # object 1 outside the silhouette's crop
    refined = _refine_in_motion(frames, k2, expected, w2, disp2,
                                clear=lambda k, at: np.linalg.norm(track1[k] - at) > clear_r)
    if refined is None:
        refined = _refine(frames, k2, expected, w2, disp2,
                          clear=lambda k: np.linalg.norm(track1[k] - expected) > clear_r)
    return (expected if refined is None else refined), k2

