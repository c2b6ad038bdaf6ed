"""A KLT track's tether to the object's look in its first frame (the key frame).

KLT follows an object by its features from frame to frame, so an error in its pose is kept
by every feature it takes afterwards: new features get their frame-0 positions through the
pose of the frame they are found in. Motion blur makes such errors where the object turns.
Measured on the tracking benchmark's checker_persp_960x540_blur_3: a 46 px checker cube
sliding off the ramp at 45 px per frame, its rigid fit's rotation jumped to 12-19 degrees in
the blurred frames of the turn onto the floor and settled at 14.5 degrees for a turn of about
23 degrees; the centre, which the features surround only partly, stayed 12-13.6 px off to the
end. The Open Source Physics Tracker's autotracker keeps such a "tether" to its key frame:
the template from the key frame is matched again where the evolving one may have drifted.

Here the key frame's look (:class:`Look`, grey, the object's footprint) is compared with each
frame at the track's pose (:func:`look_ncc`); where it no longer matches, the pose is searched
again against the look (:func:`realign`: rotations about the track's centre, shifts up to a
search radius, by ``cv2.matchTemplate``, then sub-pixel by ``cv2.findTransformECCWithMask``,
Euclidean). :mod:`galileo_jax.observe.klt` decides when to take the result.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np

from galileo_jax.observe.tracks import polygon_mask, rotation

#: Rotations tried about the track's own (degrees): its pose may be this far off.
SEARCH_DEG = 30.0
#: Step between the rotations tried (degrees); ECC refines the best one.
STEP_DEG = 2.0


class Look(NamedTuple):
    """An object's appearance in the key frame: grey crop from ``lo`` (px, frame coordinates
    of its top-left pixel) and the footprint inside it (bool, same shape)."""

    lo: np.ndarray
    template: np.ndarray
    mask: np.ndarray


def crop_look(gray: np.ndarray, corners: np.ndarray) -> Look:
    """The look inside a footprint polygon ``corners`` ((4, 2) px) of a grey frame: its
    bounding crop (clipped to the frame) and the polygon's pixels in it."""
    lo = np.maximum(np.floor(corners.min(0)).astype(int), 0)
    hi = np.minimum(np.ceil(corners.max(0)).astype(int) + 1, gray.shape[::-1])
    crop = gray[lo[1]:hi[1], lo[0]:hi[0]].astype(np.float32)
    return Look(lo, crop, polygon_mask(crop.shape, corners, lo) > 0)


def key_look(gray: np.ndarray, corners: np.ndarray) -> Look | None:
    """:func:`crop_look`, or None when the footprint leaves too little inside the frame (under
    9 px) or is uniform (SD under 1 grey level): nothing to hold a pose to."""
    look = crop_look(gray, corners)
    if look.mask.sum() < 9 or float(look.template[look.mask].std()) < 1.0:
        return None
    return look


def _into_look(gray: np.ndarray, look: Look, R: np.ndarray, t: np.ndarray, pad: int = 0) -> np.ndarray:
    """The frame resampled into the look's crop coordinates under the pose x -> R x + t
    (frame-0 px -> this frame's px), with ``pad`` px more on each side."""
    M = np.hstack([R, (R @ (look.lo - pad) + t)[:, None]])
    h, w = look.template.shape
    return cv2.warpAffine(gray, M, (w + 2 * pad, h + 2 * pad), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)


def look_ncc(gray: np.ndarray, look: Look, R: np.ndarray, t: np.ndarray) -> float:
    """Normalised cross-correlation (-1..1) of the look with the frame under the pose
    x -> R x + t, over the look's footprint."""
    now = _into_look(np.asarray(gray, np.float32), look, R, t)
    a, b = now[look.mask], look.template[look.mask]
    a, b = a - a.mean(), b - b.mean()
    den = math.sqrt(float((a * a).sum() * (b * b).sum()))
    return float((a * b).sum() / den) if den > 0 else 0.0


def _compose(R: np.ndarray, t: np.ndarray, lo: np.ndarray, Rw: np.ndarray, tw: np.ndarray):
    """The pose whose look sits at crop coordinates x -> Rw x + tw of the look resampled under
    (R, t): frame = R (lo + Rw x + tw) + t for the frame-0 point lo + x."""
    R_new = R @ Rw
    return R_new, R @ (lo + tw) + t - R_new @ lo


def realign(gray: np.ndarray, look: Look, R: np.ndarray, t: np.ndarray, centre0: np.ndarray,
            search_px: float) -> tuple[float, np.ndarray, np.ndarray]:
    """Search the pose under which the look best matches the frame, near a track's pose.

    Rotations within :data:`SEARCH_DEG` of the track's, about the track's centre (``R @
    centre0 + t``), every third :data:`STEP_DEG` step and then the steps beside the best of
    them; for each, every whole-pixel shift up to
    ``search_px`` (``cv2.matchTemplate``, normalised correlation over the footprint); the best
    is refined by ECC (``cv2.findTransformECCWithMask``, Euclidean; Evangelidis & Psarakis
    2008), kept if it correlates better.

    Args:
        gray: (H, W) grey frame.
        look: the key frame's look.
        R, t: (2, 2), (2,) the track's pose (frame-0 px -> this frame's px).
        centre0: (2,) the object's centre in frame 0 (px).
        search_px: largest shift tried (px).

    Returns:
        ``(ncc, R, t)`` of the best pose.
    """
    gray = np.asarray(gray, np.float32)
    pad = max(int(math.ceil(search_px)), 1)
    centre = R @ centre0 + t
    a0 = math.atan2(R[1, 0], R[0, 0])
    mask = look.mask.astype(np.uint8)
    best = None

    def match(da):  # the best shift at rotation a0 + da (degrees), as (ncc, rotation offset, R, t)
        Ra = rotation(a0 + math.radians(da))
        ta = centre - Ra @ centre0
        res = cv2.matchTemplate(_into_look(gray, look, Ra, ta, pad), look.template, cv2.TM_CCOEFF_NORMED, mask=mask)
        res[~np.isfinite(res)] = -1.0
        _, top, _, (x, y) = cv2.minMaxLoc(res)
        return (top, da, *_compose(Ra, ta, look.lo, np.eye(2), np.array([x - pad, y - pad], float)))

    coarse = 3 * STEP_DEG  # every third rotation, then the steps beside the best of them
    for da in np.arange(-SEARCH_DEG, SEARCH_DEG + 1e-9, coarse):
        cand = match(da)
        best = cand if best is None or cand[0] > best[0] else best
    for da in (best[1] - 2 * STEP_DEG, best[1] - STEP_DEG, best[1] + STEP_DEG, best[1] + 2 * STEP_DEG):
        cand = match(da)
        best = cand if cand[0] > best[0] else best
    top, _, Rb, tb = best
    refined = refine(gray, look, Rb, tb)
    if refined is not None and refined[0] > top and \
            np.linalg.norm(refined[1] @ centre0 + refined[2] - (Rb @ centre0 + tb)) <= 2.0:
        return refined
    return float(top), Rb, tb


def refine(gray: np.ndarray, look: Look, R: np.ndarray, t: np.ndarray
           ) -> tuple[float, np.ndarray, np.ndarray] | None:
    """The pose near (R, t) under which the look best matches the frame, to a fraction of a
    pixel: ECC (``cv2.findTransformECCWithMask``, Euclidean, over the look's footprint;
    Evangelidis & Psarakis 2008) from (R, t). Returns ``(ncc, R, t)``, or None when ECC does
    not converge."""
    gray = np.asarray(gray, np.float32)
    warp = np.eye(2, 3, dtype=np.float32)
    try:
        _, warp = cv2.findTransformECCWithMask(look.template, _into_look(gray, look, R, t),
                                               look.mask.astype(np.uint8),
                                               np.full(look.template.shape, 255, np.uint8), warp,
                                               cv2.MOTION_EUCLIDEAN,
                                               (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4), 1)
    except cv2.error:
        return None
    Rr, tr_ = _compose(R, t, look.lo, warp[:, :2].astype(float), warp[:, 2].astype(float))
    return look_ncc(gray, look, Rr, tr_), Rr, tr_
