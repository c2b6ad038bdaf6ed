"""KLT feature tracking of textured objects (dissertation 4.2.2).

:func:`track_objects`: from each object's centre in frame 0, Shi-Tomasi corners from
``cv2.goodFeaturesToTrack`` inside a window the size of the object, moved frame to frame by
``cv2.calcOpticalFlowPyrLK`` with a forward-backward check. The object's motion in each frame
is the rigid transform (rotation + translation) that best maps the features' positions in
frame 0 to their current ones, fitted robustly (median start, then least squares on inliers);
the centre is that transform applied to the start pixel. For pure translation this is the start
pixel plus the median feature displacement; it stays right when the object turns (a box tipping
onto the floor). Features are re-detected when too few remain, only on pixels unlike the
background (:func:`~galileo_jax.observe.tracks.background_model`); a track that is lost inside
the image, or stops dead on the scenery while the object moves on, raises
:class:`~galileo_jax.errors.TrackingError`.

A textured object's track is held to its look in frame 0 (:func:`_tether`,
:mod:`galileo_jax.observe.tether`): each frame's pose is refined against it by ECC, and where
the look no longer matches at the track's pose (a rotation gone wrong in the motion-blurred
frames of a turn) the pose is searched again; the frames since the last pose the look
confirmed are then dropped.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import NamedTuple

import cv2
import numpy as np

from galileo_jax.errors import TrackingError
from galileo_jax.observe.tether import Look, crop_look, key_look, look_ncc, realign, refine
from galileo_jax.observe.tracks import (Tracks, Window, as_gray, has_texture, inside_fraction, lost_message,
                                       polygon_mask, rotation, window_corners)


#: Forward-backward KLT error (px) above which a feature is dropped.
FB_MAX = 1.0
#: Residual (px) to the fitted rigid motion below which a feature is always an inlier.
RESIDUAL_MIN = 1.0
#: Default half size (px) of an object's window when the scene gives no size.
DEFAULT_HALF = 15.0
#: Agreeing features that make a measurement of quality 1 (fewer: proportionally less).
FULL_FEATURES = 8
#: Correlation of the key frame's look with a frame at the track's pose below which the pose
#: is searched again (:func:`_tether`; motion blur alone lowers it to 0.3-0.5 at 20-45 px/frame).
TETHER_CHECK = 0.5
#: Correlation at the track's pose from which a frame's pose counts as confirmed by the look.
TETHER_TRUST = 0.6
#: Correlation the searched pose needs to replace the track's, and by how much it must beat it.
TETHER_MATCH, TETHER_GAIN = 0.85, 0.3
#: Smallest move (px) of the centre for which a searched pose replaces the track's.
TETHER_SHIFT = 1.0


# ---------------------------------------------------------------------------- rigid fit


def _kabsch(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation R and translation t minimising |b - (a R^T + t)| (2-D, least squares)."""
    ca, cb = a.mean(0), b.mean(0)
    p, q = a - ca, b - cb
    phi = math.atan2(np.sum(p[:, 0] * q[:, 1] - p[:, 1] * q[:, 0]), np.sum(p * q))
    R = rotation(phi)
    return R, cb - ca @ R.T


def fit_rigid(ref: np.ndarray, cur: np.ndarray, R_prior: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Robust rigid motion from frame-0 feature positions to current ones.

    Args:
        ref: (m, 2) features' positions in frame-0 coordinates (px).
        cur: (m, 2) their positions now (px).
        R_prior: (2, 2) rotation of the previous frame, used when the features are too
            few or too bunched to fix a rotation.

    Returns:
        ``(R, t, inliers)``: (2, 2), (2,), (m,) bool, with cur ~ ref R^T + t on inliers.
    """
    t = np.median(cur - ref @ R_prior.T, axis=0)
    R = R_prior
    inl = np.ones(len(ref), bool)
    for _ in range(3):
        res = np.linalg.norm(cur - (ref @ R.T + t), axis=1)
        inl = res <= max(RESIDUAL_MIN, 3.0 * 1.4826 * np.median(res[inl]))
        sel_ref, sel_cur = ref[inl], cur[inl]
        if len(sel_ref) >= 3 and np.sqrt(np.var(sel_ref, axis=0).sum()) > 3.0:
            R, t = _kabsch(sel_ref, sel_cur)
        else:
            R = R_prior
            t = np.median(sel_cur - sel_ref @ R.T, axis=0)
    res = np.linalg.norm(cur - (ref @ R.T + t), axis=1)
    inl = res <= max(RESIDUAL_MIN, 3.0 * 1.4826 * np.median(res[inl]))
    return R, t, inl


# ---------------------------------------------------------------------------- KLT state


@dataclass
class _Track:
    """One object's tracking state (frame-0 coordinates -> current frame: x -> R x + t)."""

    centre0: np.ndarray
    window: Window
    ref: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    pts: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    R: np.ndarray = field(default_factory=lambda: np.eye(2))
    t: np.ndarray = field(default_factory=lambda: np.zeros(2))
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(2))
    alive: bool = True
    look: Look | None = None
    key: Look | None = None
    strikes: int = 0
    recent_speed: float = 0.0

    @property
    def centre(self) -> np.ndarray:
        return self.R @ self.centre0 + self.t

    def corners(self, shrink: float = 1.0, R=None, t=None) -> np.ndarray:
        R = self.R if R is None else R
        t = self.t if t is None else t
        return window_corners(R @ self.centre0 + t, self.window, R, shrink)


class _Params(NamedTuple):
    win: int
    max_features: int
    min_features: int
    min_distance: float
    background: np.ndarray | None = None
    redetect: bool = True


def _foreground(crop: np.ndarray, bg_crop: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``mask`` restricted to pixels unlike the background, when they cover at least a
    quarter of it (else the background holds the object itself: ``mask`` unchanged)."""
    d = cv2.absdiff(crop, bg_crop)
    fg = d > max(12.0, 4.0 * 1.4826 * float(np.median(d)))
    inside = mask > 0
    if (fg & inside).sum() >= 0.25 * inside.sum():
        return np.where(fg, mask, 0).astype(np.uint8)
    return mask


def _detect(gray: np.ndarray, tr: _Track, others: list[_Track], prm: _Params, background=None) -> np.ndarray:
    """New Shi-Tomasi corners (k, 2) inside the object's shrunken window, on pixels unlike
    the ``background`` (grey image, optional), away from the features it already has and
    from the other objects' windows."""
    # the whole footprint when the background keeps features off the scenery, else a margin
    corners = tr.corners(shrink=1.0 if background is not None else 0.85)
    lo = np.floor(corners.min(0)).astype(int) - 2
    hi = np.ceil(corners.max(0)).astype(int) + 3
    h, w = gray.shape
    lo, hi = np.maximum(lo, 0), np.minimum(hi, [w, h])
    if np.any(hi - lo < 3):
        return np.zeros((0, 2))
    crop = gray[lo[1]:hi[1], lo[0]:hi[0]]
    mask = polygon_mask(crop.shape, corners, lo)
    if background is not None:
        mask = _foreground(crop, background[lo[1]:hi[1], lo[0]:hi[0]], mask)
    for o in others:
        if o.alive:
            mask[polygon_mask(crop.shape, o.corners(shrink=1.1), lo) > 0] = 0
    for p in tr.pts:
        cv2.circle(mask, (int(round(p[0] - lo[0])), int(round(p[1] - lo[1]))), int(prm.min_distance), 0, -1)
    want = prm.max_features - len(tr.pts)
    if want <= 0 or not mask.any():
        return np.zeros((0, 2))
    found = cv2.goodFeaturesToTrack(crop, maxCorners=want, qualityLevel=0.01, minDistance=prm.min_distance,
                                    mask=mask, blockSize=5)
    if found is None:
        return np.zeros((0, 2))
    return found.reshape(-1, 2).astype(float) + lo


def _keep_resting(tr: _Track, image: np.ndarray, prelude: np.ndarray, prm: _Params) -> None:
    """Drop the features that move (by > 0.5 px) in the ``prelude`` frames before ``image``,
    in which the object rests (a hand lifting off it moves); keep all if too few rest."""
    pts, ok, cur = tr.pts.copy(), np.ones(len(tr.pts), bool), image
    for prev in prelude[::-1]:
        back = _klt(cur, prev, pts, pts, prm)
        ok &= np.isfinite(back[:, 0]) & (np.linalg.norm(back - tr.pts, axis=1) <= 0.5)
        pts, cur = np.where(np.isfinite(back), back, pts), prev
    if ok.sum() >= prm.min_features:
        tr.ref, tr.pts = tr.ref[ok], tr.pts[ok]


def _add_features(gray, tr: _Track, others, prm: _Params, initial: bool = False) -> None:
    if not (prm.redetect or initial):
        return
    new = _detect(gray, tr, others, prm, prm.background)
    if len(new):
        ref_new = (new - tr.t) @ tr.R  # inverse of x -> R x + t
        tr.ref = np.vstack([tr.ref, ref_new])
        tr.pts = np.vstack([tr.pts, new])


def _klt(img0, img1, pts: np.ndarray, guess: np.ndarray, prm: _Params) -> np.ndarray:
    """Track points from ``img0`` to ``img1`` (colour or grey: in colour, two objects of
    equal brightness but different colour are told apart) with a forward-backward check;
    returns (m, 2) positions with NaN rows for failed points."""
    if len(pts) == 0:
        return np.zeros((0, 2))
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)
    levels = 2
    kw = dict(winSize=(prm.win, prm.win), maxLevel=levels, criteria=crit, flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
    # only the part of the frames the points can reach: the pyramids of a crop, not of the
    # whole frame (3-4x faster at 960x540). Its corner is on the coarsest level's grid and its
    # margin is a search window at the coarsest level plus the pyramid filters' reach, so each
    # point sees what it sees on the whole frame up to the pyramid's border handling
    # (tracks moved by hundredths of a px, 0.22 px in one frame of the tracking benchmark).
    step = 1 << levels
    reach = (prm.win // 2 + 4) * step
    both = np.vstack([pts, guess])
    both = both[np.all(np.isfinite(both), axis=1)]
    lo, hi = np.zeros(2, int), np.array(img0.shape[1::-1])
    if len(both):
        lo = np.maximum((np.floor(both.min(axis=0) - reach) // step) * step, lo).astype(int)
        hi = np.minimum(np.ceil(both.max(axis=0) + reach), hi).astype(int)
    img0, img1 = img0[lo[1]:hi[1], lo[0]:hi[0]], img1[lo[1]:hi[1], lo[0]:hi[0]]
    p0 = (pts - lo).astype(np.float32).reshape(-1, 1, 2)
    p1, st, _ = cv2.calcOpticalFlowPyrLK(img0, img1, p0, (guess - lo).astype(np.float32).reshape(-1, 1, 2), **kw)
    pb, stb, _ = cv2.calcOpticalFlowPyrLK(img1, img0, p1, p0.copy(), **kw)
    p1, pb = p1.reshape(-1, 2) + lo, pb.reshape(-1, 2) + lo  # float64 again
    ok = (st.ravel() == 1) & (stb.ravel() == 1) & (np.linalg.norm(pb - pts, axis=1) < FB_MAX)
    p1[~ok] = np.nan
    return p1


def _outside(pts: np.ndarray, polygons: list[np.ndarray]) -> np.ndarray:
    """(m,) bool: points (NaN rows count as outside) in none of the convex polygons."""
    ok = np.ones(len(pts), bool)
    for poly in polygons:
        for j in np.flatnonzero(ok & np.isfinite(pts[:, 0])):
            if cv2.pointPolygonTest(poly.astype(np.float32), (float(pts[j, 0]), float(pts[j, 1])), False) >= 0:
                ok[j] = False
    return ok


def _measure(tr: _Track, f0: "_Frame", f1: "_Frame", prm: _Params,
             keep_out: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """KLT-track the object's features into this frame; (m, 2) positions and (m,) bool good
    (tracked, and not inside the ``keep_out`` polygons: other objects' footprints)."""
    new = _klt(f0.image, f1.image, tr.pts, tr.pts + tr.velocity, prm)
    good = np.isfinite(new[:, 0])
    if keep_out:
        good &= _outside(new, keep_out)
    return new, good


def _step(tr: _Track, f0: "_Frame", f1: "_Frame", others, prm: _Params, keep_out=()) -> int:
    """Move one object's track from the previous frame to this one. Returns the number of
    inlier features (0 if it could not be measured; the state is then left unchanged)."""
    keep_out = list(keep_out)
    if len(tr.pts) < prm.min_features:
        _add_features(f0.gray, tr, others, prm)
    new, good = _measure(tr, f0, f1, prm, keep_out)
    if good.sum() < prm.min_features:  # retry once with fresh corners in the previous frame
        tr.ref, tr.pts = tr.ref[good], tr.pts[good]
        _add_features(f0.gray, tr, others, prm)
        new, good = _measure(tr, f0, f1, prm, keep_out)
    if good.sum() < max(2, prm.min_features // 2):
        return 0
    old_centre = tr.centre
    R, t, inl = fit_rigid(tr.ref[good], new[good], tr.R)
    tr.R, tr.t = R, t
    tr.ref, tr.pts = tr.ref[good][inl], new[good][inl]
    tr.velocity = tr.centre - old_centre
    n = len(tr.pts)
    if n < prm.max_features // 2:
        _add_features(f1.gray, tr, others, prm)
    return n


# ---------------------------------------------------------------------------- stuck tracks


def _fg_fraction(gray: np.ndarray, background: np.ndarray, corners: np.ndarray) -> float:
    """Fraction of the polygon's pixels that differ from the background."""
    lo = np.maximum(np.floor(corners.min(0)).astype(int) - 2, 0)
    hi = np.minimum(np.ceil(corners.max(0)).astype(int) + 3, gray.shape[::-1])
    if np.any(hi - lo < 2):
        return 0.0
    d = cv2.absdiff(gray[lo[1]:hi[1], lo[0]:hi[0]], background[lo[1]:hi[1], lo[0]:hi[0]])
    inside = polygon_mask(d.shape, corners, lo) > 0
    if not inside.any():
        return 0.0
    return float((d[inside] > max(12.0, 4.0 * 1.4826 * float(np.median(d)))).mean())


def _look(gray: np.ndarray, tr: _Track, background) -> Look | None:
    """The object's frame-0 appearance, or None when it cannot serve (no background, or
    the background holds the object itself at its start)."""
    corners = tr.corners(shrink=0.8)
    if background is None or _fg_fraction(gray, background, corners) < 0.3:
        return None
    return crop_look(gray, corners)


def _on_background(gray: np.ndarray, tr: _Track, prm: _Params) -> bool:
    """True if the track sits on scenery: its footprint looks like the background and
    unlike the object's frame-0 appearance (features caught on a static edge while the
    object moved on). Only asked when a fast track suddenly stops."""
    if tr.look is None or _fg_fraction(gray, prm.background, tr.corners(shrink=0.8)) >= 0.15:
        return False
    return look_ncc(gray, tr.look, tr.R, tr.t) < 0.4


def _tether(tr: _Track, gray: np.ndarray, others: list[_Track]) -> tuple[float, bool]:
    """Hold the track to the object's key-frame look (:mod:`galileo_jax.observe.tether`).

    Where the look correlates with the frame at the track's pose by at least
    :data:`TETHER_CHECK`, the pose is refined (:func:`~galileo_jax.observe.tether.refine`) and
    kept if it correlates better and moves the centre by at most 1 px. Where it correlates by
    less, the pose is searched again (:func:`~galileo_jax.observe.tether.realign`,
    shifts up to the object's smaller half size); a pose that correlates by at least
    :data:`TETHER_MATCH`, :data:`TETHER_GAIN` better than the track's, moves the centre by
    at least :data:`TETHER_SHIFT` px and does not overlap another object's footprint by more
    than a quarter replaces it, and the features' frame-0 positions are taken again under it.

    Returns:
        ``(ncc, moved)``: the correlation at the pose now kept, and whether it was replaced.
    """
    gray = np.asarray(gray, np.float32)  # once, for every comparison below
    rho = look_ncc(gray, tr.key, tr.R, tr.t)
    if rho >= TETHER_CHECK:
        near = refine(gray, tr.key, tr.R, tr.t)
        if near is not None and near[0] > rho and np.linalg.norm(near[1] @ tr.centre0 + near[2] - tr.centre) <= 1.0:
            _set_pose(tr, near[1], near[2])
            return near[0], False
        return rho, False
    top, R, t = realign(gray, tr.key, tr.R, tr.t, tr.centre0, min(tr.window.half))
    if top < max(TETHER_MATCH, rho + TETHER_GAIN) or np.linalg.norm(R @ tr.centre0 + t - tr.centre) < TETHER_SHIFT:
        return rho, False
    corners = tr.corners(R=R, t=t)
    if any(o.alive and _overlap(corners, o.corners()) > 0.25 for o in others):
        return rho, False
    _set_pose(tr, R, t)
    return top, True


def _set_pose(tr: _Track, R: np.ndarray, t: np.ndarray) -> None:
    """Give the track the pose x -> R x + t, its features' frame-0 positions taken again under it."""
    tr.R, tr.t = R, t
    tr.ref = (tr.pts - t) @ R  # inverse of x -> R x + t


def _stuck_message(i: int, k: int, fps: float | None) -> str:
    when = f" (t = {k / fps:.2f} s)" if fps else ""
    return (f"object {i + 1} track lost at frame {k}{when}: its features stayed on the scenery while the object "
            "moved on (fast, blurred or rolling?); check the video and the object's size in the scene")


# ---------------------------------------------------------------------------- public



class _Frame(NamedTuple):
    """A frame as the tracker uses it: grey for corners and background, the original
    (colour) image for KLT."""

    gray: np.ndarray
    image: np.ndarray


def _frame(frame: np.ndarray) -> _Frame:
    return _Frame(as_gray(frame), frame)


def _windows(n: int, windows) -> list[Window]:
    if windows is None:
        return [Window((DEFAULT_HALF, DEFAULT_HALF), 0.0)] * n
    out = [w if isinstance(w, Window) else Window(tuple(w[0]), float(w[1])) for w in windows]
    if len(out) != n:
        raise ValueError(f"{len(out)} windows for {n} objects")
    return out


def _params(windows: list[Window], max_features: int, min_features: int, background) -> _Params:
    small = min(min(w.half) for w in windows)
    win = int(np.clip(2 * round(small * 0.6) + 1, 11, 21))
    if background is not None:
        background = as_gray(np.asarray(background, np.uint8))
    return _Params(win, max_features, min_features, float(np.clip(small / 5, 2.0, 6.0)), background)


def track_objects(frames: np.ndarray, start_pixels, windows=None, *, background: np.ndarray | None = None,
                  fps: float | None = None, max_features: int = 40, min_features: int = 4,
                  progress: bool = False, on_loss: str = "raise", first_frame: int = 0,
                  prelude: np.ndarray | None = None, redetect: bool = True) -> Tracks:
    """Track each object's centre through the video (KLT, see the module docstring).

    Args:
        frames: (N, H, W, 3) uint8 BGR or (N, H, W) uint8 grey frames.
        start_pixels: (n, 2) centre (u, v) of each object in frame 0, px.
        windows: per object a :class:`Window` (its image footprint in frame 0, px), or
            ``((half_along, half_across), angle)``; default a 30 px square.
        background: (H, W) or (H, W, 3) uint8 view without the objects
            (:func:`background_model`), or None. New features are then taken only on
            pixels unlike it, so a textured ramp or rail behind an object, which would hold
            a track still, is not tracked in its place.
        fps: frame rate, only for the times in error messages.
        max_features: features kept per object.
        min_features: fewest features that define a track.
        progress: show a progress bar.
        on_loss: "raise" a :class:`TrackingError` when a track is lost, or "hold" its last
            position (marked invalid) from then on.
        first_frame: video frame number of ``frames[0]`` (for error messages).
        prelude: frames just before ``frames[0]`` (in video order) in which the objects
            rest: features that move in them (a hand leaving) are not used.
        redetect: take new features when too few remain (else a track only loses them).

    Returns:
        :class:`Tracks` with (N, n, 2) pixels, (N, n) valid flags and feature counts. An
        object that leaves the image is marked invalid from then on; so are the frames
        between a pose the key frame's look confirmed and one the tether corrected
        (:func:`_tether`).

    Raises:
        TrackingError: no features at an object's start pixel, or a track lost inside the
            image (one line naming the object, frame and time).
    """
    start = np.asarray(start_pixels, float).reshape(-1, 2)
    n, N = len(start), len(frames)
    wins = _windows(n, windows)
    prm = _params(wins, max_features, min_features, background)._replace(redetect=redetect)
    tracks = [_Track(start[i].copy(), wins[i]) for i in range(n)]
    f0 = _frame(frames[0])
    for i, tr in enumerate(tracks):
        _add_features(f0.gray, tr, tracks[:i] + tracks[i + 1:], prm, initial=True)
        if prelude is not None and len(prelude):
            _keep_resting(tr, f0.image, prelude, prm)
        tr.look = _look(f0.gray, tr, prm.background)
        # a plain object's look is its outline alone, too little to hold a pose to
        textured = has_texture(f0.gray, tr.centre, tr.window.half, tr.window.angle)
        tr.key = key_look(f0.gray, tr.corners(shrink=0.8)) if textured else None
        if len(tr.pts) < min_features:
            raise TrackingError(f"object {i + 1}: only {len(tr.pts)} trackable features around its start pixel "
                                f"({start[i, 0]:.0f}, {start[i, 1]:.0f}) in frame {first_frame}; "
                                "check camera.start_pixels", object_index=i, at_start=True)
    pixels = np.zeros((N, n, 2))
    valid = np.zeros((N, n), bool)
    count = np.zeros((N, n), int)
    pixels[0], valid[0], count[0] = start, True, [len(t.pts) for t in tracks]
    trusted = np.zeros(n, int)  # last frame whose pose the key frame's look confirmed
    doubtful = np.zeros((N, n), bool)  # frames between a confirmed pose and a corrected one
    steps = range(1, N)
    if progress:
        from tqdm import tqdm
        steps = tqdm(steps, desc="tracking", unit="frame")
    for k in steps:
        f1 = _frame(frames[k])
        before = [copy.deepcopy(tr) for tr in tracks]
        for i, tr in enumerate(tracks):
            count[k, i] = _advance_or_hold(i, k + first_frame, tr, tracks, f0, f1, prm, fps, on_loss)
        for i, j in _overrunning(tracks, before):  # ran into another object: measure again
            for guess in (before[i].velocity, np.zeros(2)):  # its features kept out of the other; then from rest
                tracks[i] = copy.deepcopy(before[i])
                tracks[i].velocity = guess
                count[k, i] = _advance_or_hold(i, k + first_frame, tracks[i], tracks, f0, f1, prm, fps,
                                               on_loss, keep_out=[tracks[j].corners()])
                if _overlap(tracks[i].corners(), tracks[j].corners()) <= 0.25:
                    break
        for i, tr in enumerate(tracks):
            if tr.alive and tr.key is not None and count[k, i] > 0:
                rho, moved = _tether(tr, f1.gray, tracks[:i] + tracks[i + 1:])
                if moved:  # the frames since the last confirmed pose had the wrong one, by how much unknown
                    doubtful[trusted[i] + 1:k, i] = True
                if moved or rho >= TETHER_TRUST:
                    trusted[i] = k
            valid[k, i] = tr.alive and valid[k - 1, i]
            pixels[k, i] = tr.centre if valid[k, i] else pixels[k - 1, i]
        f0 = f1
    valid &= ~doubtful
    return Tracks(pixels, valid, count, np.where(valid, np.minimum(count / FULL_FEATURES, 1.0), 0.0))


def _advance_or_hold(i, k, tr: _Track, tracks, f0: _Frame, f1: _Frame, prm: _Params, fps, on_loss: str,
                     keep_out=()) -> int:
    if not tr.alive:
        return 0
    try:
        return _advance(i, k, tr, tracks, f0, f1, prm, fps, keep_out)
    except TrackingError:
        if on_loss == "raise":
            raise
        tr.alive = False
        return 0


def _overlap(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection of two convex polygons over the smaller one's area."""
    area, _ = cv2.intersectConvexConvex(a.astype(np.float32), b.astype(np.float32))
    return float(area) / max(min(cv2.contourArea(a.astype(np.float32)), cv2.contourArea(b.astype(np.float32))), 1e-9)


def _overrunning(tracks: list[_Track], before: list[_Track]) -> list[tuple[int, int]]:
    """Pairs (i, j): object i's track now overlaps object j's footprint by more than a
    quarter, and i was the faster before (it was predicted to move on, and its features
    were caught by j's texture, as when a sliding object hits a resting one and stops).
    Object i is then measured again with its features kept out of j, and if that does not
    part them, from rest."""
    out = []
    for i in range(len(tracks)):
        for j in range(i + 1, len(tracks)):
            if tracks[i].alive and tracks[j].alive and _overlap(tracks[i].corners(), tracks[j].corners()) > 0.25:
                fast = np.linalg.norm(before[i].velocity) >= np.linalg.norm(before[j].velocity)
                out.append((i, j) if fast else (j, i))
    return out


def _advance(i, k, tr: _Track, tracks, f0: _Frame, f1: _Frame, prm: _Params, fps, keep_out=()) -> int:
    """One frame of one object; handles leaving the image and lost tracks."""
    others = [o for o in tracks if o is not tr]
    predicted = tr.corners(t=tr.t + tr.velocity)
    if inside_fraction(predicted, f1.gray.shape) < 0.5:
        tr.alive = False
        return 0
    n = _step(tr, f0, f1, others, prm, keep_out)
    if n >= max(2, prm.min_features // 2) and inside_fraction(tr.corners(), f1.gray.shape) >= 0.5:
        speed, was_fast = float(np.linalg.norm(tr.velocity)), tr.recent_speed > 3.0
        tr.recent_speed = max(speed, 0.8 * tr.recent_speed)
        stopped = speed < 0.5 and (was_fast or tr.strikes > 0)
        tr.strikes = tr.strikes + 1 if stopped and _on_background(f1.gray, tr, prm) else 0
        if tr.strikes >= 2:
            raise TrackingError(_stuck_message(i, k, fps), object_index=i, frame=k)
        return n
    if inside_fraction(tr.corners(t=tr.t + tr.velocity), f1.gray.shape) < 0.75:
        tr.alive = False
        return 0
    raise TrackingError(lost_message(i, k, fps, n), object_index=i, frame=k)


