"""What every tracker returns, and the image geometry of a scene's objects.

* :class:`Tracks`: tracked image positions with their validity and per-frame quality.
* :class:`Window`: an object's image footprint (a turned rectangle) and its polygon helpers.
* :func:`background_model`: a grey view of the scene without the moving objects.
* :func:`frame_median`: the per-pixel median of a stack of frames.
* :func:`footprint`, :func:`footprints_along`, :func:`visible_fraction`, :func:`crop_box`,
  :func:`weighted_centroid`: an object's footprint in pixels, and the crops around it.
* :func:`estimate_noise_sd`: a track's noise SD from its third differences.
* :func:`has_texture`: whether an object shows texture KLT can follow inside its outline.
* :func:`parallel_map`, :func:`submit`: independent tracks run at once on the CPU's cores.
* :func:`object_windows`, :func:`path_direction`, :func:`expected_start_pixels`: where the
  scene's objects appear in the image and which way they start to move.

All pixel coordinates are (u, v): u to the right, v down, in px of the full-size frame.
"""

from __future__ import annotations

import concurrent.futures
import functools
import math
import os
import threading
from typing import NamedTuple

import cv2
import numpy as np

from galileo_jax.calibration import Calibration
from galileo_jax.physics.model import object_start_pose
from galileo_jax.scene import Scene


def _usable_cores() -> int:
    """Cores this process may run on (``os.sched_getaffinity`` where the platform has it, as on
    Linux; else ``os.cpu_count()``, e.g. on macOS)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


#: Threads of :func:`parallel_map` at most (``GALILEO_JAX_TRACK_THREADS`` overrides; 1: serial).
TRACK_THREADS = int(os.environ.get("GALILEO_JAX_TRACK_THREADS", "0")) or min(_usable_cores(), 4)


@functools.lru_cache(maxsize=1)
def _pool(workers: int) -> concurrent.futures.ThreadPoolExecutor:
    return concurrent.futures.ThreadPoolExecutor(max_workers=workers, thread_name_prefix="galileo-track")


def _serial() -> bool:
    """Whether :func:`parallel_map` and :func:`submit` run their work in the calling thread:
    one thread allowed, or the caller is itself one of the pool's threads (nested work could
    wait on itself)."""
    return TRACK_THREADS <= 1 or threading.current_thread().name.startswith("galileo-track")


def parallel_map(fn, items) -> list:
    """``[fn(x) for x in items]``, the calls spread over :data:`TRACK_THREADS` threads: for a
    few large independent jobs (a track forwards and one backwards) that spend most of their
    time in OpenCV, which releases the GIL. The results, and any exception (the first item's
    that raised), are those of the serial loop. Not for per-frame work: the colour tracker's
    measurements in two threads ran slower than serially (82 against 90 frames/s on a plain
    960x540 video), its small NumPy calls holding the GIL."""
    items = list(items)
    if len(items) < 2 or _serial():
        return [fn(x) for x in items]
    return list(_pool(TRACK_THREADS).map(fn, items))


def submit(fn) -> concurrent.futures.Future:
    """``fn()`` started on one of :func:`parallel_map`'s threads (run at once, in this thread,
    where there is only one, or inside one of them); its ``result()`` returns or raises what
    ``fn()`` did."""
    if _serial():
        out: concurrent.futures.Future = concurrent.futures.Future()
        try:
            out.set_result(fn())
        except Exception as err:  # noqa: BLE001 - handed to the caller through result()
            out.set_exception(err)
        return out
    return _pool(TRACK_THREADS).submit(fn)


#: Smallest eigenvalue of the structure tensor (``cv2.cornerMinEigenVal``, block 5, on 8-bit
#: grey) that counts as texture: a plain patch with pixel noise of SD 6 grey levels stays
#: below 0.0006, a 10 px checker of contrast 70 reaches 0.02 (measured).
TEXTURE_EIGENVALUE = 0.002
#: Share of the object's inner pixels (its footprint shrunk to 60%, and at least
#: :data:`TEXTURE_MARGIN` px inside its outline) that must be textured for KLT to follow it.
TEXTURE_SHARE = 0.1
TEXTURE_MARGIN = 4.0


class Tracks(NamedTuple):
    """Tracked image positions.

    Attributes:
        pixels: (N, n, 2) centre (u, v) of each object in px, frame by frame; after an
            object leaves the image, its last tracked position.
        valid: (N, n) bool, True where the centre was measured.
        n_features: (N, n) number of KLT features that agreed on the object's motion (1
            for a measurement by another method, 0 where none was made).
        quality: (N, n) each measurement's quality in [0, 1] (0 where none was made): for
            KLT the share of a full set of agreeing features (8 or more: 1), for the outline
            1 where the circle was found, for the colour matte its agreement with the
            object's clean appearance (:mod:`.matte`).
    """

    pixels: np.ndarray
    valid: np.ndarray
    n_features: np.ndarray
    quality: np.ndarray


#: Measurements of lower quality (:class:`Tracks`) are left out of the fit and of the
#: cross-checks: half of a clean measurement's agreement (half the object seen, or 4 of 8 KLT
#: features).
QUALITY_MIN = 0.5


class Window(NamedTuple):
    """An object's image footprint: a rectangle of half sizes (along, across) in px whose
    'along' axis is at ``angle`` rad from the image u axis (towards +v)."""

    half: tuple[float, float]
    angle: float


# ---------------------------------------------------------------------------- geometry


def rotation(phi: float) -> np.ndarray:
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[c, -s], [s, c]])


def window_corners(centre, window: Window, R: np.ndarray | None = None, shrink: float = 1.0) -> np.ndarray:
    """(4, 2) corners in px of ``window`` centred at ``centre``, rotated further by ``R``."""
    a, b = window.half[0] * shrink, window.half[1] * shrink
    local = np.array([[-a, -b], [a, -b], [a, b], [-a, b]])
    rot = rotation(window.angle) if R is None else R @ rotation(window.angle)
    return local @ rot.T + np.asarray(centre, float)


def polygon_mask(shape, corners: np.ndarray, offset=(0, 0)) -> np.ndarray:
    """(h, w) uint8 mask, 255 inside the convex polygon ``corners`` (m, 2) px (sub-pixel, in an
    array whose pixel (0, 0) is ``offset``); empty where the corners are not finite."""
    mask = np.zeros(shape[:2], np.uint8)
    if not np.all(np.isfinite(corners)):
        return mask
    pts = np.round((corners - np.asarray(offset)) * 4).astype(np.int32)
    cv2.fillConvexPoly(mask, pts, 255, lineType=cv2.LINE_8, shift=2)
    return mask


def inside_fraction(corners: np.ndarray, shape) -> float:
    """Fraction of the window polygon's bounding box inside the image."""
    lo, hi = corners.min(0), corners.max(0)
    h, w = shape[:2]
    area = max((hi - lo).prod(), 1e-9)
    inter = (np.clip(hi[0], 0, w) - np.clip(lo[0], 0, w)) * (np.clip(hi[1], 0, h) - np.clip(lo[1], 0, h))
    return float(max(inter, 0.0) / area)


def estimate_noise_sd(trace: np.ndarray, moving: np.ndarray | None = None) -> float:
    """Tracking-noise SD of one position trace, from its third differences.

    For white noise of SD sigma, the third difference p[k+3] - 3 p[k+2] + 3 p[k+1] - p[k]
    has SD sqrt(20) sigma, while a motion of piecewise-constant acceleration (sliding on the
    ramp or the floor, resting) contributes exactly zero except in the few samples around a
    change of acceleration (release, the ramp's foot, the collision, the stop), and a slowly
    varying acceleration (drag, rolling, tipping over the foot) contributes only its tiny
    jerk. So no model of the motion is needed: a robust scale (1.4826 x the median absolute
    third difference) flags those few samples (beyond 3.5 robust SDs), and the root mean
    square of the others, over sqrt(20), is the estimate. Measured on white noise: bias -2%,
    relative SD 0.17 for 40 samples (the MAD alone: 0.25). Fitting quadratics to chunks of
    the trace would scatter less (0.13) but mistakes any unflagged kink for noise (it
    doubled the estimate across a ramp's foot), so it is not used. Where ``moving`` marks
    enough frames (>= 8 windows of 4), only windows of moving frames are used: a resting
    object's KLT track is much steadier than a moving one's, and the moving part is what
    the fit is about.

    Args:
        trace: (N,) positions (any unit; the SD comes back in the same unit).
        moving: (N,) bool, frames in which the object moves, or None.

    Returns:
        The SD (>= 0; 0 for traces shorter than 4 samples).
    """
    x = np.asarray(trace, float)
    if len(x) < 4:
        return 0.0
    d3 = np.diff(x, 3)
    if moving is not None:
        m = np.asarray(moving, bool)
        window_moving = m[:-3] & m[1:-2] & m[2:-1] & m[3:]
        if window_moving.sum() >= 8:
            d3 = d3[window_moving]
    robust = 1.4826 * float(np.median(np.abs(d3)))
    kept = d3[np.abs(d3) <= 3.5 * robust]
    if robust == 0 or len(kept) == 0:
        return robust / math.sqrt(20.0)
    return math.sqrt(float(np.mean(kept ** 2)) / 20.0)


def lost_message(i: int, k: int, fps: float | None, n: int) -> str:
    """One line for a track lost in frame ``k`` with ``n`` features left."""
    when = f" (t = {k / fps:.2f} s)" if fps else ""
    return (f"object {i + 1} track lost at frame {k}{when}: only {n} features still follow it "
            "(occluded, blurred or featureless); give camera.start_pixels or check the video")


def background_model(frames: np.ndarray, n: int = 25) -> np.ndarray:
    """(H, W) uint8 grey background: the per-pixel median of up to ``n`` frames spread over
    the second half of the video. By then the objects have left their start positions
    (object 1 slid away, the hand is gone), and a moving object vanishes from the median
    wherever it spends less than half that time; where one rests (its final position, or an
    object that never moves) it stays in, and :func:`track_objects` then ignores the
    background there."""
    first = len(frames) // 2
    idx = np.unique(np.linspace(first, len(frames) - 1, min(n, len(frames) - first)).round().astype(int))
    return np.round(frame_median([as_gray(frames[k]) for k in idx])).astype(np.uint8)


def frame_median(frames, valid: np.ndarray | None = None) -> np.ndarray:
    """The per-pixel median of m images, as ``np.median(frames, axis=0)`` (the mean of the two
    middle values for an even count) but in float32 and ~10x faster: a sorting network of
    element-wise min/max over whole images (Batcher's odd-even merge sort, Knuth TAOCP vol. 3
    section 5.3.4) instead of a partition per pixel (for m <= 64; more are sorted).

    Args:
        frames: m >= 1 images of one shape and integer dtype (a list or an (m, ...) array),
            e.g. (m, H, W, 3) uint8.
        valid: optional (m, ...) bool of the same shape: the values to use (e.g. the frames
            in which no object covers a pixel); the median is then over those alone, and NaN
            where none is valid.

    Returns:
        float32 array of one image's shape.
    """
    if valid is None:
        v = [np.array(f) for f in frames]
    else:
        v = [np.where(ok, f, np.float32(np.inf)).astype(np.float32) for f, ok in zip(frames, valid)]
    m = len(v)
    if m <= 64:
        for a, b in _merge_sort_network(m):
            v[a], v[b] = np.minimum(v[a], v[b]), np.maximum(v[a], v[b])
    else:  # the network's comparators grow as m log^2 m: a sort along the stack instead
        v = np.sort(np.stack(v), axis=0)
    if valid is None:
        lo, hi = v[(m - 1) // 2].astype(np.float32), v[m // 2]
    else:  # the invalid values (+inf) sorted last: the middle of the first ``count``
        count = np.sum(valid, axis=0)
        s = np.asarray(v)
        lo = np.take_along_axis(s, np.maximum((count - 1) // 2, 0)[None], axis=0)[0]
        hi = np.take_along_axis(s, np.maximum(count // 2, 0)[None], axis=0)[0]
        hi = np.where(count > 0, hi, np.nan)
    return (lo + hi) * np.float32(0.5)


@functools.lru_cache(maxsize=None)
def _merge_sort_network(n: int) -> tuple[tuple[int, int], ...]:
    """Comparators (a, b), a < b, of Batcher's odd-even merge sort for n inputs (the network
    for the next power of two, without comparators touching the missing inputs: those would
    hold +inf and never move)."""
    size = 1 << max(n - 1, 0).bit_length()
    pairs = []
    p = 1
    while p < size:
        k = p
        while k >= 1:
            for j in range(k % p, size - k, 2 * k):
                for i in range(min(k, size - j - k)):
                    a, b = i + j, i + j + k
                    if a // (2 * p) == b // (2 * p) and b < n:
                        pairs.append((a, b))
            k //= 2
        p *= 2
    return tuple(pairs)


def as_gray(frame: np.ndarray) -> np.ndarray:
    return frame if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)



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



def path_tilts(scene: Scene, calib: Calibration) -> tuple[float, float]:
    """Image tilts (rad, from the u axis, in (-pi, pi]) of the path's two straight segments,
    the ramp (downhill) and the floor (away from the ramp): an object sliding from one onto
    the other turns from the first tilt to the second."""
    th = scene.ramp.angle
    return tuple(float(math.atan2(d[1], d[0])) for d in (_image_direction(calib, (math.cos(th), -math.sin(th))),
                                                         _image_direction(calib, (1.0, 0.0))))


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


# ------------------------------------------------------------------------------ footprints in the image
#: Smallest background threshold in grey levels (compressed video hides small noise in static
#: areas, and its blocks differ by a few levels).
BACKGROUND_MIN = 8.0
#: Frames, spread evenly over the video, whose per-pixel median is the static background.
BACKGROUND_FRAMES = 15


def spread_indices(n_frames: int, n: int) -> np.ndarray:
    """Up to ``n`` frame indices spread evenly over ``n_frames`` frames (first and last included)."""
    return np.unique(np.linspace(0, n_frames - 1, min(n, n_frames)).round().astype(int))


def footprint(shape, centre, half, angle: float, grow: float = 0.0, offset=(0, 0)) -> np.ndarray:
    """(h, w) bool: the rectangle of half sizes ``half`` (along, across; px) grown by ``grow``
    px, turned by ``angle`` rad, centred at ``centre`` (px, full-frame), in an array of
    ``shape`` whose pixel (0, 0) is full-frame pixel ``offset``."""
    window = Window((half[0] + grow, half[1] + grow), angle)
    return polygon_mask(shape, window_corners(centre, window), offset) > 0


def crop_box(shape, centre, radius: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Integer corners (lo, hi) of the square of ``radius`` px around ``centre``, clamped to
    the image; None if it is empty or the centre is not finite."""
    if not np.all(np.isfinite(centre)):
        return None
    h, w = shape[:2]
    lo = np.maximum(np.floor(np.asarray(centre) - radius).astype(int), 0)
    hi = np.minimum(np.ceil(np.asarray(centre) + radius).astype(int) + 1, [w, h])
    if np.any(hi - lo < 3):
        return None
    return lo, hi


def weighted_centroid(weights: np.ndarray) -> np.ndarray | None:
    """(2,) centroid (u, v) of an (h, w) weight image (``cv2.moments``), in its own pixels;
    None where its total weight is about 0."""
    m = cv2.moments(weights.astype(np.float32), binaryImage=False)
    if m["m00"] <= 1e-6:
        return None
    return np.array([m["m10"] / m["m00"], m["m01"] / m["m00"]])


def visible_fraction(shape, centre, half, angle) -> float:
    """Fraction of the footprint's area inside the image."""
    if not np.all(np.isfinite(centre)):
        return 0.0
    r = math.hypot(*half) + 2
    lo = np.floor(np.asarray(centre) - r).astype(int)
    size = int(2 * math.ceil(r) + 2)
    h, w = shape[:2]
    if min(half) >= 1.0 and lo[0] >= 0 and lo[1] >= 0 and lo[0] + size <= w and lo[1] + size <= h:
        return 1.0  # the footprint's whole box (below) lies in the image: no need to draw it
    fp = footprint((size, size), centre, half, angle, offset=lo)
    total = fp.sum()
    if total == 0:
        return 0.0
    ys, xs = np.nonzero(fp)
    ys, xs = ys + lo[1], xs + lo[0]
    return float(((xs >= 0) & (xs < w) & (ys >= 0) & (ys < h)).sum() / total)


def footprints_along(px: np.ndarray, halves, angles: np.ndarray, shape, grow: np.ndarray):
    """``covered(k)``: (H, W) bool, the objects' footprints along (N, n, 2) tracks ``px``,
    grown by ``grow`` (N, n) px (NaN positions cover nothing)."""
    def covered(k):
        out = np.zeros(shape[:2], bool)
        for i in range(px.shape[1]):
            c = px[k, i]
            if np.all(np.isfinite(c)):
                r = math.hypot(*halves[i]) + grow[k, i] + 2
                box = crop_box(shape, c, r)
                if box is not None:
                    lo, hi = box
                    out[lo[1]:hi[1], lo[0]:hi[0]] |= footprint((hi[1] - lo[1], hi[0] - lo[0]), c, halves[i],
                                                               angles[k, i], grow=grow[k, i], offset=lo)
        return out
    return covered


def has_texture(frame: np.ndarray, centre, half, angle: float) -> bool:
    """Whether an object shows texture KLT can follow inside its outline: at least
    :data:`TEXTURE_SHARE` of the pixels of its footprint shrunk to 60% and
    :data:`TEXTURE_MARGIN` px inside its outline (``centre`` (2,) px, ``half`` (along, across)
    px, tilt ``angle`` rad) have a structure-tensor eigenvalue above
    :data:`TEXTURE_EIGENVALUE` (Shi & Tomasi 1994's corner measure); an object too small to
    leave such a region has none."""
    gray = as_gray(frame)
    r = int(np.ceil(np.hypot(*half))) + 4
    c = np.asarray(centre, float)
    lo = np.maximum(np.floor(c - r).astype(int), 0)
    hi = np.minimum(np.ceil(c + r).astype(int) + 1, gray.shape[::-1])
    crop = gray[lo[1]:hi[1], lo[0]:hi[0]]
    if crop.shape[0] < 7 or crop.shape[1] < 7:
        return False
    # well inside the outline: the 5 px block of the corner measure must not reach the edges
    inner_half = np.minimum(0.6 * np.asarray(half, float), np.asarray(half, float) - TEXTURE_MARGIN)
    if inner_half.min() < 2.0:
        return False  # too small to hold KLT features inside it
    inner = footprint(crop.shape, c, inner_half, angle, offset=lo)
    if inner.sum() < 4:
        return False
    eig = cv2.cornerMinEigenVal(np.ascontiguousarray(crop), 5)
    return bool((eig[inner] > TEXTURE_EIGENVALUE).mean() >= TEXTURE_SHARE)
