"""Tracking the objects through the frames, and finding them when the scene does not say where.

* :func:`track_objects`: from each object's centre in frame 0, KLT tracking (dissertation
  4.2.2: Shi-Tomasi corners from ``cv2.goodFeaturesToTrack`` inside a window the size of
  the object, moved frame to frame by ``cv2.calcOpticalFlowPyrLK`` with a forward-backward
  check). The object's motion in each frame is the rigid transform (rotation +
  translation) that best maps the features' positions in frame 0 to their current ones,
  fitted robustly (median start, then least squares on inliers); the centre is that
  transform applied to the start pixel. For pure translation this is the start pixel plus
  the median feature displacement; it stays right when the object turns (a box tipping
  onto the floor). Features are re-detected when too few remain, only on pixels unlike
  the background (:func:`background_model`); a track that is lost inside the image, or
  stops dead on the scenery while the object moves on, raises :class:`TrackingError`.
* :func:`track_circles`: rolling round objects (spheres), by their outline.
* :func:`track_scene`: each object of a scene by its kind, optionally from a later frame
  (forward and backward), clear of a hand.
* :func:`find_objects` / :func:`locate_objects`: the start pixels when the scene gives
  none, by motion and the scene's geometry.

All pixel coordinates are (u, v): u to the right, v down, in px of the full-size frame.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import NamedTuple

import cv2
import numpy as np

from galileo_jax.calibration import Calibration
from galileo_jax.errors import TrackingError
from galileo_jax.model import object_start_pose
from galileo_jax.scene import Scene

#: Forward-backward KLT error (px) above which a feature is dropped.
FB_MAX = 1.0
#: Residual (px) to the fitted rigid motion below which a feature is always an inlier.
RESIDUAL_MIN = 1.0
#: Default half size (px) of an object's window when the scene gives no size.
DEFAULT_HALF = 15.0


class Tracks(NamedTuple):
    """Tracked image positions.

    Attributes:
        pixels: (N, n, 2) centre (u, v) of each object in px, frame by frame; after an
            object leaves the image, its last tracked position.
        valid: (N, n) bool, True where the centre was measured.
        n_features: (N, n) number of KLT features that agreed on the object's motion.
    """

    pixels: np.ndarray
    valid: np.ndarray
    n_features: np.ndarray


class Window(NamedTuple):
    """An object's image footprint: a rectangle of half sizes (along, across) in px whose
    'along' axis is at ``angle`` rad from the image u axis (towards +v)."""

    half: tuple[float, float]
    angle: float


# ---------------------------------------------------------------------------- geometry


def _rot(phi: float) -> np.ndarray:
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[c, -s], [s, c]])


def window_corners(centre, window: Window, R: np.ndarray | None = None, shrink: float = 1.0) -> np.ndarray:
    """(4, 2) corners in px of ``window`` centred at ``centre``, rotated further by ``R``."""
    a, b = window.half[0] * shrink, window.half[1] * shrink
    local = np.array([[-a, -b], [a, -b], [a, b], [-a, b]])
    rot = _rot(window.angle) if R is None else R @ _rot(window.angle)
    return local @ rot.T + np.asarray(centre, float)


def _polygon_mask(shape, corners: np.ndarray, offset=(0, 0)) -> np.ndarray:
    mask = np.zeros(shape[:2], np.uint8)
    pts = np.round((corners - np.asarray(offset)) * 4).astype(np.int32)
    cv2.fillConvexPoly(mask, pts, 255, lineType=cv2.LINE_8, shift=2)
    return mask


def _inside_fraction(corners: np.ndarray, shape) -> float:
    """Fraction of the window polygon's bounding box inside the image."""
    lo, hi = corners.min(0), corners.max(0)
    h, w = shape[:2]
    area = max((hi - lo).prod(), 1e-9)
    inter = (np.clip(hi[0], 0, w) - np.clip(lo[0], 0, w)) * (np.clip(hi[1], 0, h) - np.clip(lo[1], 0, h))
    return float(max(inter, 0.0) / area)


# ---------------------------------------------------------------------------- rigid fit


def _kabsch(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation R and translation t minimising |b - (a R^T + t)| (2-D, least squares)."""
    ca, cb = a.mean(0), b.mean(0)
    p, q = a - ca, b - cb
    phi = math.atan2(np.sum(p[:, 0] * q[:, 1] - p[:, 1] * q[:, 0]), np.sum(p * q))
    R = _rot(phi)
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
    look: "_Look | None" = None
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
    mask = _polygon_mask(crop.shape, corners, lo)
    if background is not None:
        mask = _foreground(crop, background[lo[1]:hi[1], lo[0]:hi[0]], mask)
    for o in others:
        if o.alive:
            mask[_polygon_mask(crop.shape, o.corners(shrink=1.1), lo) > 0] = 0
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
    kw = dict(winSize=(prm.win, prm.win), maxLevel=2, criteria=crit, flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
    p0 = pts.astype(np.float32).reshape(-1, 1, 2)
    p1, st, _ = cv2.calcOpticalFlowPyrLK(img0, img1, p0, guess.astype(np.float32).reshape(-1, 1, 2), **kw)
    pb, stb, _ = cv2.calcOpticalFlowPyrLK(img1, img0, p1, p0.copy(), **kw)
    p1, pb = p1.reshape(-1, 2).astype(float), pb.reshape(-1, 2).astype(float)
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


class _Look(NamedTuple):
    """An object's appearance in frame 0: grey crop from ``lo`` (px) and its footprint."""

    lo: np.ndarray
    template: np.ndarray
    mask: np.ndarray


def _fg_fraction(gray: np.ndarray, background: np.ndarray, corners: np.ndarray) -> float:
    """Fraction of the polygon's pixels that differ from the background."""
    lo = np.maximum(np.floor(corners.min(0)).astype(int) - 2, 0)
    hi = np.minimum(np.ceil(corners.max(0)).astype(int) + 3, gray.shape[::-1])
    if np.any(hi - lo < 2):
        return 0.0
    d = cv2.absdiff(gray[lo[1]:hi[1], lo[0]:hi[0]], background[lo[1]:hi[1], lo[0]:hi[0]])
    inside = _polygon_mask(d.shape, corners, lo) > 0
    if not inside.any():
        return 0.0
    return float((d[inside] > max(12.0, 4.0 * 1.4826 * float(np.median(d)))).mean())


def _look(gray: np.ndarray, tr: _Track, background) -> _Look | None:
    """The object's frame-0 appearance, or None when it cannot serve (no background, or
    the background holds the object itself at its start)."""
    corners = tr.corners(shrink=0.8)
    if background is None or _fg_fraction(gray, background, corners) < 0.3:
        return None
    lo = np.maximum(np.floor(corners.min(0)).astype(int), 0)
    hi = np.minimum(np.ceil(corners.max(0)).astype(int) + 1, gray.shape[::-1])
    crop = gray[lo[1]:hi[1], lo[0]:hi[0]].astype(np.float32)
    return _Look(lo, crop, _polygon_mask(crop.shape, corners, lo) > 0)


def _ncc(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(), b - b.mean()
    den = math.sqrt(float((a * a).sum() * (b * b).sum()))
    return float((a * b).sum() / den) if den > 0 else 0.0


def _on_background(gray: np.ndarray, tr: _Track, prm: _Params) -> bool:
    """True if the track sits on scenery: its footprint looks like the background and
    unlike the object's frame-0 appearance (features caught on a static edge while the
    object moved on). Only asked when a fast track suddenly stops."""
    if tr.look is None or _fg_fraction(gray, prm.background, tr.corners(shrink=0.8)) >= 0.15:
        return False
    look = tr.look
    M = np.hstack([tr.R, (tr.R @ look.lo + tr.t)[:, None]])  # frame-0 crop coords -> this frame
    h, w = look.template.shape
    now = cv2.warpAffine(gray.astype(np.float32), M, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
    return _ncc(now[look.mask], look.template[look.mask]) < 0.4


def _stuck_message(i: int, k: int, fps: float | None) -> str:
    when = f" (t = {k / fps:.2f} s)" if fps else ""
    return (f"object {i + 1} track lost at frame {k}{when}: its features stayed on the scenery while the object "
            "moved on (fast, blurred or rolling?); check the video and the object's size in the scene")


# ---------------------------------------------------------------------------- public


def background_model(frames: np.ndarray, n: int = 25) -> np.ndarray:
    """(H, W) uint8 grey background: the per-pixel median of up to ``n`` frames spread over
    the second half of the video. By then the objects have left their start positions
    (object 1 slid away, the hand is gone), and a moving object vanishes from the median
    wherever it spends less than half that time; where one rests (its final position, or an
    object that never moves) it stays in, and :func:`track_objects` then ignores the
    background there."""
    first = len(frames) // 2
    idx = np.unique(np.linspace(first, len(frames) - 1, min(n, len(frames) - first)).round().astype(int))
    grey = np.stack([_as_gray(frames[k]) for k in idx])
    out = np.empty(grey.shape[1:], np.uint8)
    for r in range(0, grey.shape[1], 64):  # in bands of rows, to bound the float copy
        out[r:r + 64] = np.median(grey[:, r:r + 64], axis=0).round().astype(np.uint8)
    return out


def _as_gray(frame: np.ndarray) -> np.ndarray:
    return frame if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)


class _Frame(NamedTuple):
    """A frame as the tracker uses it: grey for corners and background, the original
    (colour) image for KLT."""

    gray: np.ndarray
    image: np.ndarray


def _frame(frame: np.ndarray) -> _Frame:
    return _Frame(_as_gray(frame), frame)


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
        background = _as_gray(np.asarray(background, np.uint8))
    return _Params(win, max_features, min_features, float(np.clip(small / 5, 2.0, 6.0)), background)


def _lost_message(i: int, k: int, fps: float | None, n: int) -> str:
    when = f" (t = {k / fps:.2f} s)" if fps else ""
    return (f"object {i + 1} track lost at frame {k}{when}: only {n} features still follow it "
            "(occluded, blurred or featureless); give camera.start_pixels or check the video")


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
        object that leaves the image is marked invalid from then on.

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
        if len(tr.pts) < min_features:
            raise TrackingError(f"object {i + 1}: only {len(tr.pts)} trackable features around its start pixel "
                                f"({start[i, 0]:.0f}, {start[i, 1]:.0f}) in frame 0; check camera.start_pixels")
    pixels = np.zeros((N, n, 2))
    valid = np.zeros((N, n), bool)
    count = np.zeros((N, n), int)
    pixels[0], valid[0], count[0] = start, True, [len(t.pts) for t in tracks]
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
            valid[k, i] = tr.alive and valid[k - 1, i]
            pixels[k, i] = tr.centre if valid[k, i] else pixels[k - 1, i]
        f0 = f1
    return Tracks(pixels, valid, count)


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
    if _inside_fraction(predicted, f1.gray.shape) < 0.5:
        tr.alive = False
        return 0
    n = _step(tr, f0, f1, others, prm, keep_out)
    if n >= max(2, prm.min_features // 2) and _inside_fraction(tr.corners(), f1.gray.shape) >= 0.5:
        speed, was_fast = float(np.linalg.norm(tr.velocity)), tr.recent_speed > 3.0
        tr.recent_speed = max(speed, 0.8 * tr.recent_speed)
        stopped = speed < 0.5 and (was_fast or tr.strikes > 0)
        tr.strikes = tr.strikes + 1 if stopped and _on_background(f1.gray, tr, prm) else 0
        if tr.strikes >= 2:
            raise TrackingError(_stuck_message(i, k, fps))
        return n
    if _inside_fraction(tr.corners(t=tr.t + tr.velocity), f1.gray.shape) < 0.75:
        tr.alive = False
        return 0
    raise TrackingError(_lost_message(i, k, fps, n))


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
    gray0 = _as_gray(frames[0])
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
        gray = _as_gray(frames[k])
        for i in np.flatnonzero(alive):
            predicted = pixels[k - 1, i] + velocity[i]
            box = np.array([predicted - radii[i], predicted + radii[i]])
            if _inside_fraction(box, gray.shape) < 0.5:
                alive[i] = False
                pixels[k:, i] = pixels[k - 1, i]
                continue
            gate = max(0.5 * radii[i], 0.5 * np.linalg.norm(velocity[i]), 3.0)
            found = _find_circle(gray, predicted, radii[i], gate)
            if found is None:
                misses[i] += 1
                if misses[i] >= 2 and on_loss == "raise":
                    raise TrackingError(_lost_message(i, k + first_frame, fps, 0))
                if misses[i] >= 2:
                    alive[i] = False
                    pixels[k:, i] = pixels[k - 1, i]
                    continue
                pixels[k, i] = predicted
                continue
            misses[i] = 0
            velocity[i] = found - pixels[k - 1, i]
            pixels[k, i], valid[k, i], count[k, i] = found, True, 1
    return Tracks(pixels, valid, count)


# ---------------------------------------------------------------------------- scene geometry


def _image_direction(calib: Calibration, world_dir) -> np.ndarray:
    """Unit image vector (du, dv) of a world (x, y_up) direction."""
    d = calib.world_to_pixel(np.asarray(world_dir, float)) - calib.world_to_pixel(np.zeros(2))
    return d / np.linalg.norm(d)


def path_direction(scene: Scene, calib: Calibration, i: int) -> np.ndarray:
    """Unit image vector in which object ``i`` starts to move (down the ramp, or along the
    floor away from the ramp)."""
    th = scene.ramp.angle if scene.placement(i) == "ramp" else 0.0
    return _image_direction(calib, (math.cos(th), -math.sin(th)))


def is_round(scene: Scene, i: int) -> bool:
    """Whether object ``i`` is tracked by its round outline (:func:`track_circles`), not by
    KLT features that turn with it: ``tracker: outline``, or a sphere with ``tracker: auto``."""
    obj = scene.objects[i]
    return obj.tracker == "outline" or (obj.tracker == "auto" and obj.shape == "sphere")


def track_scene(frames: np.ndarray, start_pixels, scene: Scene, calib: Calibration, *, start_frame: int = 0,
                background: np.ndarray | None = None, fps: float | None = None, progress: bool = False) -> Tracks:
    """Track every object of a scene: spheres by :func:`track_circles`, the others by
    :func:`track_objects` (KLT), with windows from the scene's sizes.

    With ``start_frame`` > 0 the features are taken in that frame (the objects at rest
    there, at ``start_pixels``; e.g. just before object 1 starts to move, when a hand that
    covered it in frame 0 has gone or is leaving), keeping only those that rested in the
    3 frames before (not on a hand lifting off), and tracked forward to the end and
    backward to frame 0 (without new features; a backward track that loses its features,
    the hand covering the object again, holds its position, marked invalid).

    Args:
        frames: (N, H, W, 3) uint8 BGR frames.
        start_pixels: (n, 2) centres in frame ``start_frame``, px.
        scene, calib: the scene and its calibration (scale, direction, roll).
        start_frame: frame in which tracking starts.
        background: grey background for :func:`track_objects`.
        fps: frame rate for error messages.
        progress: show progress bars.

    Returns:
        :class:`Tracks` of all objects, in the scene's order.

    Raises:
        TrackingError: see :func:`track_objects` and :func:`track_circles`.
    """
    kw = dict(background=background, fps=fps, progress=progress)
    prelude = frames[max(0, start_frame - 3): start_frame]
    forward = _track_kinds(frames[start_frame:], start_pixels, scene, calib, first_frame=start_frame,
                           prelude=prelude, **kw)
    if start_frame <= 0:
        return forward
    backward = _track_kinds(frames[start_frame::-1], start_pixels, scene, calib, on_loss="hold", prelude=prelude,
                            redetect=False, **kw)
    merged = Tracks(*(np.concatenate([b[::-1][:-1], f]) for b, f in zip(backward, forward)))
    return _slower_before(merged, start_frame)


def _slower_before(tracks: Tracks, k0: int) -> Tracks:
    """Before frame ``k0`` the objects rest or start from rest, so they move no faster than
    just after it: a backward track that jumps faster (it caught a hand moving over the
    object) holds its last good position instead, marked invalid."""
    px, valid, count = tracks.pixels.copy(), tracks.valid.copy(), tracks.n_features.copy()
    for i in range(px.shape[1]):
        limit = max(1.0, 1.5 * np.linalg.norm(px[min(k0 + 1, len(px) - 1), i] - px[k0, i]))
        for k in range(k0 - 1, -1, -1):
            if not valid[k, i] or np.linalg.norm(px[k, i] - px[k + 1, i]) > limit:
                px[: k + 1, i], valid[: k + 1, i], count[: k + 1, i] = px[k + 1, i], False, 0
                break
    return Tracks(px, valid, count)


def _track_kinds(frames, start_pixels, scene: Scene, calib: Calibration, *, background=None, fps=None,
                 progress=False, on_loss="raise", first_frame=0, prelude=None, redetect=True) -> Tracks:
    """:func:`track_scene` in one direction from ``frames[0]``."""
    start = np.asarray(start_pixels, float).reshape(-1, 2)
    wins = object_windows(scene, calib)
    kw = dict(fps=fps, progress=progress, on_loss=on_loss, first_frame=first_frame)
    parts = {}
    klt = [i for i in range(scene.n_objects) if not is_round(scene, i)]
    if klt:
        tr = track_objects(frames, start[klt], [wins[i] for i in klt], background=background, prelude=prelude,
                           redetect=redetect, **kw)
        parts.update({i: (tr.pixels[:, j], tr.valid[:, j], tr.n_features[:, j]) for j, i in enumerate(klt)})
    circ = [i for i in range(scene.n_objects) if is_round(scene, i)]
    if circ:
        tr = track_circles(frames, start[circ], [wins[i].half[0] for i in circ], **kw)
        parts.update({i: (tr.pixels[:, j], tr.valid[:, j], tr.n_features[:, j]) for j, i in enumerate(circ)})
    order = [parts[i] for i in range(scene.n_objects)]
    return Tracks(*(np.stack([o[m] for o in order], axis=1) for m in range(3)))


def object_windows(scene: Scene, calib: Calibration) -> list[Window]:
    """Each object's image footprint at its start (half sizes in px along and across its
    direction of motion), from the scene's sizes and the calibration's scale."""
    out = []
    for i, obj in enumerate(scene.objects):
        half = (obj.length / 2 * calib.scale, obj.height / 2 * calib.scale)
        d = path_direction(scene, calib, i)
        out.append(Window(half, math.atan2(d[1], d[0])))
    return out


def expected_start_pixels(scene: Scene, calib: Calibration, first: np.ndarray | None = None) -> np.ndarray:
    """(n, 2) start pixels the scene predicts: absolute when the calibration is anchored
    (``camera.foot_pixel``), else relative to object 1's pixel ``first``."""
    world = np.array([[p[0], p[2]] for p in (object_start_pose(scene, i)[0] for i in range(scene.n_objects))])
    px = calib.world_to_pixel(world)
    if first is not None:
        px = px - px[0] + np.asarray(first, float)
    return px


# ---------------------------------------------------------------------------- finding objects

#: Longest side (px) of the downscaled frames used for motion detection.
WORK_SIZE = 640
#: A moving pixel's flow must be within this angle (deg) of the expected direction.
MAX_ANGLE_DEG = 40.0


class _Small(NamedTuple):
    """Downscaled grey frames for motion detection; ``f`` = small px per full px."""

    gray: np.ndarray
    f: float

    def to_full(self, uv) -> np.ndarray:
        return (np.asarray(uv, float) + 0.5) / self.f - 0.5

    def to_small(self, uv) -> np.ndarray:
        return (np.asarray(uv, float) + 0.5) * self.f - 0.5


def _downscale(frames: np.ndarray) -> _Small:
    h, w = frames.shape[1:3]
    f = min(1.0, WORK_SIZE / max(h, w))
    size = (max(1, round(w * f)), max(1, round(h * f)))
    gray = np.stack([cv2.resize(_as_gray(fr), size, interpolation=cv2.INTER_AREA) if f < 1 else _as_gray(fr)
                     for fr in frames])
    return _Small(gray, size[0] / w)


class _Blob(NamedTuple):
    centroid: np.ndarray  # (2,) small px
    area: float
    flow: np.ndarray  # (2,) mean flow, small px / frame
    border: bool


def _changed(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(h, w) bool: pixels near a real change between two grey frames (above the noise),
    grown by a few pixels so that flat patches inside a moving object count too."""
    d = cv2.absdiff(a, b)
    noise = 1.4826 * float(np.median(d)) + 1.0
    changed = (d > max(6.0, 4.0 * noise)).astype(np.uint8)
    return cv2.dilate(changed, np.ones((7, 7), np.uint8)) > 0


def _moving_blobs(flow: np.ndarray, direction: np.ndarray, allowed: np.ndarray, min_speed: float,
                  min_area: float, offset: np.ndarray) -> list[_Blob]:
    """Connected regions (of ``allowed`` pixels) whose optical flow points along ``direction``
    (within :data:`MAX_ANGLE_DEG`) faster than ``min_speed`` px/frame, at least ``min_area`` px."""
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
        blobs.append(_Blob(cents[j] + offset, float(area), flow[sel].mean(0), bool(border)))
    return blobs


def _roi_box(shape, centre, radius) -> tuple[np.ndarray, np.ndarray]:
    h, w = shape
    if centre is None:
        return np.array([0, 0]), np.array([w, h])
    lo = np.maximum(np.floor(np.asarray(centre) - radius).astype(int), 0)
    hi = np.minimum(np.ceil(np.asarray(centre) + radius).astype(int) + 1, [w, h])
    return lo, hi


def _flow(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return cv2.calcOpticalFlowFarneback(a, b, None, 0.5, 3, 15, 3, 5, 1.2, 0)


def _extends(chain: list[_Blob], blob: _Blob, direction: np.ndarray, gate: float) -> bool:
    last = chain[-1]
    predicted = last.centroid + last.flow
    close = np.linalg.norm(blob.centroid - predicted) <= max(gate, 2 * np.linalg.norm(last.flow))
    return bool(close and (blob.centroid - last.centroid) @ direction >= -1.0)


def _on_path(chain: list[_Blob], direction: np.ndarray) -> bool:
    """The blob moved along ``direction`` (not off it) over the chain."""
    d = chain[-1].centroid - chain[0].centroid
    along = d @ direction
    across = abs(d @ np.array([-direction[1], direction[0]]))
    return bool(along > -1.0 and across <= 0.5 * max(along, 0.0) + 2.0)


def _first_motion(small: _Small, direction, centre, radius, min_area, k_start: int = 0,
                  exclude=None, min_speed: float = 0.4, run: int = 3):
    """First frame at which a region starts a steady motion along ``direction``.

    Dense (Farneback) flow between consecutive downscaled frames, inside a square of
    ``radius`` (small px) around ``centre`` (or everywhere); moving regions are chained
    from frame to frame. A chain counts once it lasts ``run`` frames, keeps to the
    direction and did not start at the image border (a hand or arm entering or leaving the
    picture). ``exclude(k)`` may return a (h, w) bool mask of small pixels to ignore.

    Returns:
        ``(k, centroid)``: the chain's first frame and its centroid there (small px), or None.
    """
    lo, hi = _roi_box(small.gray.shape[1:], centre, radius)
    chains: list[list[_Blob]] = []
    gate = max(6.0, math.sqrt(min_area))
    for k in range(k_start, len(small.gray) - 1):
        a = small.gray[k, lo[1]:hi[1], lo[0]:hi[0]]
        b = small.gray[k + 1, lo[1]:hi[1], lo[0]:hi[0]]
        if a.size == 0:
            return None
        allowed = _changed(a, b)
        if exclude is not None:
            allowed &= ~exclude(k)[lo[1]:hi[1], lo[0]:hi[0]]
        blobs = _moving_blobs(_flow(a, b), direction, allowed, min_speed, min_area, lo.astype(float))
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
                return k - len(chain) + 1, chain[0].centroid
        chains = [c for c in grown if len(c) < run or _on_path(c, direction)]
    return None


def _diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Largest per-channel absolute difference of two images (int)."""
    d = np.abs(a.astype(np.int16) - b.astype(np.int16))
    return d.max(axis=-1) if d.ndim == 3 else d


def _crop_radius(window: Window) -> int:
    """Half size (px) of the square searched for an object's silhouette."""
    return int(2 * max(window.half) + 10)


def silhouette_centre(pre: np.ndarray, background: np.ndarray, rough, window: Window) -> np.ndarray | None:
    """Centre (px) of a resting object's silhouette, by background subtraction.

    Args:
        pre: (m, H, W, 3) frames in which the object rests at ``rough``.
        background: (H, W, 3) the same view without the object.
        rough: (2,) approximate centre (px), inside the object.
        window: its expected footprint (for the search region and a size check).

    Returns:
        The centroid of the filled region that differs from the background in every frame
        of ``pre`` and does not change between them (so a hand moving over it is left
        out), or None if no region of plausible size contains ``rough``.
    """
    lo, hi = _roi_box(background.shape[:2], rough, _crop_radius(window))
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
    best = None
    for c in contours:
        area = cv2.contourArea(c)
        dist = cv2.pointPolygonTest(c, (float(here[0]), float(here[1])), True)
        if 0.4 * expected <= area <= 2.5 * expected and dist > -0.5 * min(window.half):
            if best is None or area > cv2.contourArea(best):
                best = c
    if best is None:
        return None
    filled = np.zeros(mask.shape, np.uint8)
    cv2.drawContours(filled, [best], -1, 1, -1)
    m = cv2.moments(filled, binaryImage=True)
    return np.array([m["m10"] / m["m00"], m["m01"] / m["m00"]]) + lo


def _displacements(frames, k_from: int, start, window: Window, background=None, round_: bool = False) -> np.ndarray:
    """(N, 2) displacement of an object from frame ``k_from`` on (zeros before), px; a
    ``round_`` object (a rolling sphere) is followed by its outline."""
    if round_:
        tr = track_circles(frames[k_from:], [start], [window.half[0]])
    else:
        tr = track_objects(frames[k_from:], [start], [window], background=background, min_features=3)
    out = np.zeros((len(frames), 2))
    out[k_from:] = tr.pixels[:, 0] - np.asarray(start, float)
    out[k_from + len(tr.pixels):] = out[k_from + len(tr.pixels) - 1]
    return out


def _refine(frames, k_on: int, rough, window: Window, disp: np.ndarray, clear=None) -> np.ndarray | None:
    """Start pixel from the silhouette at the start: background taken from frames where the
    object has moved off its start (and ``clear(k)``, no other object there, holds). None
    if that is not possible."""
    far = 2 * math.hypot(*window.half) + 4
    ks = [k for k in range(k_on, len(frames)) if np.linalg.norm(disp[k]) > far and (clear is None or clear(k))]
    if not ks:
        return None
    background = np.median(frames[ks[:5]], axis=0).astype(np.uint8)
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
        if np.linalg.norm(disp[k]) <= far or _inside_fraction(window_corners(at, window), frames.shape[1:]) < 1:
            continue
        if clear is not None and not all(clear(j, at) for j in ks_bg + [k]):
            continue
        if background is None:
            background = np.median(frames[ks_bg], axis=0).astype(np.uint8)
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
    start, k = locate_objects(frames, scene, calib, background)
    if k == 0:
        return start
    return track_scene(frames[: k + 1], start, scene, calib, start_frame=k, background=background).pixels[0]


def locate_objects(frames: np.ndarray, scene: Scene, calib: Calibration,
                   background: np.ndarray | None = None) -> tuple[np.ndarray, int]:
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
        ``(start_pixels, k)``: (n_objects, 2) centres (u, v) in px in frame k, the last
        frame in which object 1 rests before it starts to slide (a hand that let go and
        left is gone or leaving); track from there (:func:`track_scene`).

    Raises:
        TrackingError: nothing moves down the ramp (object 1 never moves, or is not seen
            to), or object 1 cannot be tracked.
    """
    small = _downscale(frames)
    wins = object_windows(scene, calib)
    bg = background_model(frames) if background is None else background
    prior = expected_start_pixels(scene, calib) if scene.camera.foot_pixel is not None else None
    p1, k1 = _find_first(small, scene, calib, wins[0], prior)
    k_start = _rest_frame(small, k1, p1, wins[0], path_direction(scene, calib, 0))  # tracked from here
    for _ in range(2):  # again from the refined centre if the rough one was far off (a smooth object)
        disp1 = _displacements(frames, k_start, p1, wins[0], bg, is_round(scene, 0))
        refined = _refine_in_motion(frames, k1, p1, wins[0], disp1)
        if refined is None:
            refined = _refine(frames, k1, p1, wins[0], disp1)
        if refined is None or np.linalg.norm(refined - p1) < 0.25 * max(wins[0].half):
            p1 = p1 if refined is None else refined
            break
        p1 = refined
    out = [p1]
    if scene.n_objects == 2:
        out.append(_find_second(frames, small, scene, calib, wins, p1, p1 + disp1, k1, prior, bg))
    return np.array(out), k_start


def _rest_frame(small: _Small, k: int, centre, window: Window, direction: np.ndarray) -> int:
    """The last frame, going back from ``k``, in which the object at ``centre`` (px) is still
    at rest: fewer than 15% of its footprint's pixels flow down its path (> 0.3 px/frame
    at the working scale) into the next frame. A smooth or low-contrast object (an air-track
    cart) is seen moving steadily only frames after it started."""
    region = _polygon_mask(small.gray.shape[1:], small.to_small(window_corners(centre, window))) > 0
    ys, xs = np.nonzero(region)
    if not len(ys):
        return max(0, k - 2)
    lo, hi = np.array([xs.min(), ys.min()]) - 8, np.array([xs.max(), ys.max()]) + 9
    lo, hi = np.maximum(lo, 0), np.minimum(hi, small.gray.shape[:0:-1])
    inside = region[lo[1]:hi[1], lo[0]:hi[0]]
    cos = math.cos(math.radians(MAX_ANGLE_DEG))
    for j in range(k - 1, -1, -1):
        flow = _flow(small.gray[j, lo[1]:hi[1], lo[0]:hi[0]], small.gray[j + 1, lo[1]:hi[1], lo[0]:hi[0]])
        along = flow @ direction
        moving = (along > 0.3) & (along >= cos * np.linalg.norm(flow, axis=-1))
        if moving[inside].mean() < 0.15:
            return j
    return 0


def _min_area(small: _Small, window: Window) -> float:
    return max(6.0, 0.25 * 4 * window.half[0] * window.half[1] * small.f ** 2)


def _find_first(small: _Small, scene, calib, window: Window, prior) -> tuple[np.ndarray, int]:
    """Object 1's rough centre (px) and the frame its steady motion starts."""
    direction = path_direction(scene, calib, 0)
    area = _min_area(small, window)
    found = None
    if prior is not None:
        radius = max(3 * max(window.half), 0.1 * calib.scale) * small.f
        found = _first_motion(small, direction, small.to_small(prior[0]), radius, area)
    if found is None:
        found = _first_motion(small, direction, None, None, area)
    if found is None:
        raise never_moves_error(scene)
    k, centroid = found
    rough = small.to_full(centroid)
    if prior is not None and np.linalg.norm(rough - prior[0]) < max(window.half):
        rough = prior[0]  # the calibrated scene's prediction, when the motion confirms it
    return rough, k


def _footprints(track: np.ndarray, window: Window, small: _Small):
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
            masks[k] = _polygon_mask(shape, small.to_small(window_corners(track[k], w))) > 0
        return masks[k]

    return mask


def _change_onset(small: _Small, centre, window: Window, k_start: int, exclude) -> int | None:
    """First frame k > ``k_start`` at which at least a fifth of the object's footprint
    around ``centre`` (px) changes from frame k-1, and again from k to k+1 (pixels that
    ``exclude(k)`` marks are ignored). Changes, not flow: object 2 is set moving by an impact
    and may jump tens of pixels in a frame, which dense flow does not follow."""
    grown = Window((window.half[0] * 1.3, window.half[1] * 1.3), window.angle)
    region = _polygon_mask(small.gray.shape[1:], small.to_small(window_corners(centre, grown))) > 0
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


def _find_second(frames, small: _Small, scene, calib, wins, p1, track1, k1, prior, bg) -> np.ndarray:
    """Object 2's start pixel (see :func:`find_objects`); ``track1`` (N, 2) object 1's pixels."""
    expected = prior[1] if prior is not None else expected_start_pixels(scene, calib, p1)[1]
    w1, w2 = wins
    footprints = _footprints(track1, w1, small)
    k2 = _change_onset(small, expected, w2, k1, lambda k: footprints(k))
    if k2 is None:
        return expected
    try:
        disp2 = _displacements(frames, 0, expected, w2, bg, is_round(scene, 1))
    except TrackingError:
        return expected
    clear_r = math.hypot(*w1.half) + _crop_radius(w2) + 2  # object 1 outside the silhouette's crop
    refined = _refine_in_motion(frames, k2, expected, w2, disp2,
                                clear=lambda k, at: np.linalg.norm(track1[k] - at) > clear_r)
    if refined is None:
        refined = _refine(frames, k2, expected, w2, disp2,
                          clear=lambda k: np.linalg.norm(track1[k] - expected) > clear_r)
    return expected if refined is None else refined
