"""Tracking objects by their colour against the static background (objects without texture).

KLT (:mod:`.track`) needs texture inside an object; a plain-coloured block, a foam cube or a
tape roll has none, and its outline's corners slide along the background. This module measures
such an object in every frame from its *colour matte* instead:

* **Background** (:func:`colour_background`): the per-pixel median of frames spread over the
  video, leaving out, pixel by pixel, the frames in which an object covers it (its footprint
  along a first, rough track); pixels no frame shows free (an object that never moves) are
  filled from their surroundings (``cv2.inpaint``).
* **Matte** (:func:`matte`): a pixel I in front of the background B is explained by the object
  if it lies on the segment from B to one of the object's colours F_k (or F_k brightened or
  darkened by up to :data:`GAIN`, as light and shade change along the path), I = B + alpha (F_k - B):
  alpha in [0, 1] is the fraction of the pixel the object covers (anti-aliased edges, motion
  blur), the linear "difference matting" of a single-colour object over a known background
  (Smith & Blinn, "Blue screen matting", SIGGRAPH 1996, eq. 3, with a per-pixel background).
  A pixel far from every segment and from the background (a hand, a shadow, another object)
  is *unusable*, as is one where the object's colour is too close to the background's there.
* **Centre** (:func:`measure`): with every pixel of the object's footprint usable, the
  alpha-weighted centroid (``cv2.moments``) of the matte around the object, re-centred twice;
  a blurred object's centroid is its mean position over the exposure. Where part of the
  footprint is unusable (occluded), the centroid would be pulled away from the hidden part,
  so the object's clean matte (its *template*, from an unoccluded frame) is aligned by
  Gauss-Newton (Lucas & Kanade 1981) to the usable pixels only. A frame in which too little
  of the object is seen gets a low quality and is dropped by the caller, not guessed.

Each measurement carries a quality in [0, 1]: the fraction of the object's matte that was
seen and agreed with its template (:class:`Measurement`).

* **Track** (:func:`track_matte`): every frame is measured where a rough track (template
  matching, :mod:`galileo_jax.observe.rough`) puts the object; a centre that walked farther from it than its margin plus the
  object's size is not taken. Where the rough track lost an object, it is followed on from
  its own measurements (:func:`_bridge`). Frames in which two objects are out of their start's
  order (:func:`_in_order`: they cannot pass through each other) and lone measured frames
  (:func:`_not_isolated`) are dropped.

All pixel coordinates are (u, v): u to the right, v down, in px of the full-size frame.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np

from galileo_jax.errors import TrackingError
from galileo_jax.observe.rough import rough_pass, static_scenery
from galileo_jax.observe.tracks import (BACKGROUND_FRAMES, BACKGROUND_MIN, crop_box, footprint, footprints_along,
                                        frame_median, spread_indices, visible_fraction, weighted_centroid)

#: Unusable pixels (occluded or without contrast) in the footprint above which the centre comes
#: from aligning the template instead of the centroid.
OCCLUSION_MAX = 0.03
#: A frame whose matte around the object holds no unusable pixel and this close to the
#: object's clean area (relative) is measured by the plain centroid, without the template.
CLEAN_SEEN = 0.03
#: Colour distance to the background (in noise SDs of one channel) below which a pixel is
#: background: its alpha is set to 0 (noise alone would otherwise add a small positive alpha
#: everywhere after clipping).
BACKGROUND_SDS = 3.0
#: Residual (in noise SDs of one channel, 3 channels) beyond which a pixel is not explained
#: by the object's colours over the background.
RESIDUAL_SDS = 5.0
#: Smallest residual threshold in grey levels (video compression adds error at edges).
RESIDUAL_MIN = 14.0
#: Object colours closer than this (grey levels) to the background give no usable alpha.
CONTRAST_MIN = 20.0
#: Relative change of an object's colour along its path (light, shading) that its palette
#: still explains (measured: 10% between the two ends of a rendered perspective scene).
SHADING = 0.12
#: Brightness change of an object's colours (relative) that the matte allows pixel by pixel
#: (the object passing into shade, or nearer a lamp).
GAIN = 0.35
#: A direction of motion within this (rad) of a straight segment of the path is the object's
#: tilt there (:func:`_angles`); one farther from every segment is not a slide.
PATH_TILT_SNAP = math.radians(20.0)
#: Quality a measurement needs where no rough match confirms it (:func:`_bridge`).
BRIDGE_QUALITY = 0.6
_CROSS = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))


class ColourBackground(NamedTuple):
    """The static scene without the objects.

    Attributes:
        image: (H, W, 3) float32 BGR background.
        noise_sd: pixel noise SD of one channel (grey levels), from frames minus background.
        median: (h, w, 3) float32 plain per-pixel median of the sampled frames over the region
            computed (objects not left out), or None; a later call may reuse it.
    """

    image: np.ndarray
    noise_sd: float
    median: np.ndarray | None = None


class Palette(NamedTuple):
    """An object's colours.

    Attributes:
        colours: (K, 3) float32 BGR colours of its surfaces (K <= 4; k-means centres).
        tolerance: colour distance (grey levels) within which a pixel counts as explained by
            them: the largest of the residual threshold for the noise, twice the 90th
            percentile of the object's own pixels' distance to their nearest colour (texture),
            and :data:`SHADING` times its brightest colour's length (the light on it changes
            along its path).
    """

    colours: np.ndarray
    tolerance: float


class Look(NamedTuple):
    """An object's appearance.

    Attributes:
        palette: its :class:`Palette`.
        template: (h, w) float32 matte of the object in a clean frame, turned upright
            (rotated by -``angle`` of that frame), its centroid at ``centre``.
        centre: (2,) centroid (px) of ``template`` in its own coordinates.
        area: sum of ``template`` (px^2): the object's image area.
    """

    palette: Palette
    template: np.ndarray
    centre: np.ndarray
    area: float


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


# ------------------------------------------------------------------------------ background



def colour_background(frames: np.ndarray, covered=None, n: int = BACKGROUND_FRAMES, region=None,
                      median: np.ndarray | None = None) -> ColourBackground:
    """The static background of a video, in colour.

    Args:
        frames: (N, H, W, 3) uint8 BGR frames.
        covered: optional function ``covered(k) -> (H, W) bool``: pixels an object covers in
            frame k (left out of that frame's vote); None: every frame votes everywhere (a
            moving object then drops out of the median wherever it spends less than half of
            the sampled frames).
        n: frames sampled, evenly over the video.
        region: optional ``(lo, hi)`` corners (u, v) in px of the rectangle to compute (the
            objects' paths); outside it the background is left 0.
        median: optional float32 plain median of the sampled frames, (h, w, 3) over ``region``
            (:attr:`ColourBackground.median` of an earlier call with the same frames, ``n``
            and ``region``) or (H, W, 3) over the whole frame (cropped here), reused instead
            of computed again.

    Returns:
        :class:`ColourBackground`; pixels covered in every sampled frame are taken from the
        other frames that show them free, else inpainted from their surroundings.
    """
    H, W = frames.shape[1:3]
    (x0, y0), (x1, y1) = region if region is not None else ((0, 0), (W, H))
    x0, y0, x1, y1 = max(int(x0), 0), max(int(y0), 0), min(int(x1), W), min(int(y1), H)
    part = frames[:, y0:y1, x0:x1]
    cut = (lambda k: covered(k)[y0:y1, x0:x1]) if covered is not None else None
    idx = spread_indices(len(frames), n)
    if median is None:
        median = frame_median(part[idx])
    elif median.shape[:2] == (H, W):
        median = median[y0:y1, x0:x1]
    inner = median.copy()
    if cut is not None:
        masks = np.stack([cut(k) for k in idx])  # (n, h, w)
        hit = masks.any(axis=0)
        if hit.any():
            ys, xs = np.nonzero(hit)
            vals = part[idx[:, None], ys[None], xs[None]]  # (n, m, 3)
            shown = np.repeat(~masks[:, ys, xs, None], 3, axis=2)
            free = shown[..., 0].any(axis=0)
            inner[ys[free], xs[free]] = frame_median(vals[:, free], shown[:, free])
            never = np.zeros(hit.shape, bool)
            never[ys[~free], xs[~free]] = True
            if never.any():
                never = _fill_from_all_frames(part, cut, never, inner)
            if never.any():
                img = np.clip(inner, 0, 255).astype(np.uint8)
                inner = cv2.inpaint(img, cv2.dilate(never.astype(np.uint8), np.ones((3, 3), np.uint8)), 5,
                                    cv2.INPAINT_TELEA).astype(np.float32)
    out = np.zeros((H, W, 3), np.float32)
    out[y0:y1, x0:x1] = inner
    return ColourBackground(out, _noise_sd(part, inner, cut, idx), median)


def _fill_from_all_frames(frames, covered, never: np.ndarray, out: np.ndarray) -> np.ndarray:
    """Fill ``never`` pixels (covered in every sampled frame) from any frame that shows them
    free (median); returns the pixels still never seen."""
    ys, xs = np.nonzero(never)
    shown = np.stack([~covered(k)[ys, xs] for k in range(len(frames))])  # (N, m)
    seen = shown.any(axis=0)
    if seen.any():
        shown = np.repeat(shown[:, seen, None], 3, axis=2)
        out[ys[seen], xs[seen]] = frame_median(frames[:, ys[seen], xs[seen]], shown)
    left = np.zeros_like(never)
    left[ys[~seen], xs[~seen]] = True
    return left


def _noise_sd(frames, background: np.ndarray, covered, idx) -> float:
    """Pixel noise SD of one channel (grey levels): robust scale of frame - background over
    the pixels no object covers, in a few frames."""
    vals = []
    h, w = background.shape[:2]
    every_7th = np.divmod(np.arange(0, h * w, 7), w)
    for k in idx[:: max(1, len(idx) // 4)]:
        ys, xs = every_7th
        if covered is not None:
            free = ~covered(k)[ys, xs]
            ys, xs = ys[free], xs[free]
        vals.append(frames[k][ys, xs].astype(np.float32) - background[ys, xs])
    d = np.concatenate(vals)
    return float(max(1.4826 * np.median(np.abs(d - np.median(d, axis=0))), 0.5))


# ------------------------------------------------------------------------------ matte


def thresholds(noise_sd: float) -> tuple[float, float]:
    """(background, residual) colour-distance thresholds in grey levels for a noise SD."""
    return (max(BACKGROUND_SDS * math.sqrt(3.0) * noise_sd, BACKGROUND_MIN),
            max(RESIDUAL_SDS * math.sqrt(3.0) * noise_sd, RESIDUAL_MIN))


def matte(image: np.ndarray, background: np.ndarray, palette: Palette, noise_sd: float
          ) -> tuple[np.ndarray, np.ndarray]:
    """The object's matte over a known background.

    Args:
        image: (h, w, 3) float32 BGR pixels.
        background: (h, w, 3) float32 background at the same pixels.
        palette: the object's colours and their tolerance.
        noise_sd: pixel noise SD of one channel (grey levels).

    Returns:
        ``(alpha, unusable)``: (h, w) float32 alpha in [0, 1] (0 on background and unusable
        pixels) and (h, w) bool, pixels that are neither background nor explained by the
        object's colours (an occluder), or where every colour of the object is too close to
        the background's to tell (module docstring).
    """
    h, w = image.shape[:2]
    I, B = image.reshape(-1, 3), background.reshape(-1, 3)
    d = I - B
    dd = np.einsum("pc,pc->p", d, d)
    bg_thr, _ = thresholds(noise_sd)
    res_thr = palette.tolerance
    F = np.asarray(palette.colours, np.float32)  # (K, 3)
    FF = np.einsum("kc,kc->k", F, F)
    # with e_k = F_k - B: d.e_k = d.F_k - d.B and |e_k|^2 = |F_k|^2 - 2 F_k.B + |B|^2, as (K, P)
    # products (no (K, P, 3) arrays)
    ee = np.maximum(FF[:, None] - 2.0 * (F @ B.T) + np.einsum("pc,pc->p", B, B)[None], 0.0)
    alpha, best_r2 = _unmix(F @ d.T - np.einsum("pc,pc->p", d, B)[None], dd, ee)
    contrast2 = ee.max(axis=0)
    # where no colour explains a pixel as learned, the colour as the light there makes it (a
    # gain in [1 - GAIN, 1 + GAIN], from the pixel taken as wholly the object's): shade, a lamp
    # to one side; edges already explained keep their alpha
    far = np.flatnonzero(best_r2 > res_thr * res_thr)
    if len(far):
        g = np.clip(F @ I[far].T / np.maximum(FF, 1e-6)[:, None], 1.0 - GAIN, 1.0 + GAIN)  # (K, m)
        e = g[..., None] * F[:, None] - B[far][None]  # (K, m, 3)
        a, r2 = _unmix(np.einsum("mc,kmc->km", d[far], e), dd[far], np.einsum("kmc,kmc->km", e, e))
        take = r2 < best_r2[far]
        best_r2[far[take]], alpha[far[take]] = r2[take], a[take]
    best_r2, alpha, contrast2, dd = (x.reshape(h, w) for x in (best_r2, alpha, contrast2, dd))
    best_r = np.sqrt(np.maximum(best_r2, 0.0))
    contrast = np.sqrt(contrast2)
    is_bg = dd < bg_thr * bg_thr
    # Unexplained pixels in thin lines (1-2 px) are the object's own edges, where video
    # compression blurs the colour (4:2:0 chroma) but not the brightness; an occluder is larger.
    odd = (~is_bg & (best_r > res_thr)).astype(np.uint8)
    odd = cv2.morphologyEx(odd, cv2.MORPH_OPEN, _CROSS) > 0
    unusable = odd | (contrast < max(CONTRAST_MIN, 2 * bg_thr))
    alpha = np.where(is_bg | unusable, 0.0, alpha).astype(np.float32)
    return alpha, unusable


def _unmix(de: np.ndarray, dd: np.ndarray, ee: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The best of K colours for each of P pixels: with d = I - B a pixel's difference from
    the background (``dd`` (P,) = |d|^2) and e_k = F_k - B each colour's (``de`` (K, P) =
    d.e_k, ``ee`` (K, P) = |e_k|^2), the alpha a_k = clip(d.e_k / |e_k|^2, 0, 1) and squared
    residual |d - a_k e_k|^2 of the colour that leaves the least (the first on ties):
    ``(alpha, residual^2)``, each (P,)."""
    a = np.clip(de / np.maximum(ee, 1e-6), 0.0, 1.0)
    r2 = dd[None] - 2 * a * de + a * a * ee
    if len(r2) == 1:
        return a[0], r2[0]
    k = np.argmin(r2, axis=0)[None]
    return np.take_along_axis(a, k, 0)[0], np.take_along_axis(r2, k, 0)[0]


# ------------------------------------------------------------------------------ alignment


def _place(template: np.ndarray, t_centre, angle: float, at, shape) -> np.ndarray:
    """The upright ``template`` turned by ``angle`` rad about its centroid ``t_centre`` and
    placed with that centroid at ``at`` (px) in an array of ``shape`` (h, w)."""
    c, s = math.cos(angle), math.sin(angle)
    R = np.array([[c, -s], [s, c]])
    M = np.hstack([R, (np.asarray(at, float) - R @ np.asarray(t_centre, float))[:, None]])
    return cv2.warpAffine(template, M, (shape[1], shape[0]), flags=cv2.INTER_LINEAR, borderValue=0.0)


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
        look: the object's :class:`Look`.
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
        T = _place(look.template, look.centre, angle, c, alpha.shape)
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
    return c, _place(look.template, look.centre, angle, c, alpha.shape)


# ------------------------------------------------------------------------------ measurement


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
    """Measure one object's centre in one frame (module docstring).

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
        background: the video's :class:`ColourBackground`.
        look: the object's :class:`Look` (colours, clean template).
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
    alpha, unusable = matte(img, background.image[lo[1]:hi[1], lo[0]:hi[0]], look.palette, background.noise_sd)
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
        wrong = cv2.morphologyEx(wrong.astype(np.uint8), cv2.MORPH_OPEN, _CROSS) > 0
        new_bad = unusable | wrong
        if np.array_equal(new_bad, bad):
            break
        bad = new_bad
    T = _place(look.template, look.centre, angle, c, alpha.shape)
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


# ------------------------------------------------------------------------------ appearance


def _colours(pixels: np.ndarray, k_max: int = 4, min_share: float = 0.08) -> np.ndarray:
    """(K, 3) cluster centres (k-means) of (m, 3) pixel colours, leaving out clusters holding
    fewer than ``min_share`` of the pixels."""
    pixels = np.asarray(pixels, np.float32).reshape(-1, 3)
    k = int(min(k_max, max(1, len(pixels) // 20)))
    if k == 1:
        return np.median(pixels, axis=0, keepdims=True)
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 30, 0.5)
    cv2.setRNGSeed(0)
    _, labels, centres = cv2.kmeans(pixels, k, None, crit, 3, cv2.KMEANS_PP_CENTERS)
    share = np.bincount(labels.ravel(), minlength=k) / len(labels)
    return centres[share >= min_share].astype(np.float32)


def object_colours(frames, background: ColourBackground, centres, half, angles, min_share: float = 0.08
                   ) -> Palette:
    """The :class:`Palette` of an object, from the pixels well inside its footprint that
    differ from the background, pooled over frames (``frames`` (m, H, W, 3) with the object
    at ``centres`` (m, 2), tilted by ``angles`` (m,)); colours of fewer than ``min_share`` of
    those pixels are left out.

    Raises:
        ValueError: fewer than 3 such pixels."""
    bg_thr, res_thr = thresholds(background.noise_sd)
    pool = []
    for frame, c, a in zip(frames, centres, angles):
        box = crop_box(frame.shape, c, math.hypot(*half) + 2)
        if box is None:
            continue
        lo, hi = box
        img = frame[lo[1]:hi[1], lo[0]:hi[0]].astype(np.float32)
        inner = footprint(img.shape, c, np.asarray(half) * 0.7, a, offset=lo)
        diff = np.linalg.norm(img - background.image[lo[1]:hi[1], lo[0]:hi[0]], axis=-1)
        pool.append(img[inner & (diff > bg_thr)])
    pool = np.concatenate(pool) if pool else np.zeros((0, 3), np.float32)
    if len(pool) < 3:
        raise ValueError("the object does not differ from the background")
    colours = _colours(pool, min_share=min_share)
    spread = np.min(np.linalg.norm(pool[:, None, :] - colours[None], axis=-1), axis=1)
    shading = SHADING * float(np.linalg.norm(colours, axis=1).max())
    return Palette(colours, float(max(res_thr, 2.0 * np.quantile(spread, 0.9), shading)))


def learn_template(frame, background: ColourBackground, palette: Palette, centre, half, angle: float,
                   margin: float = 2.0) -> Look:
    """The :class:`Look` of an object from one clean frame: its matte around ``centre``,
    turned upright (by -``angle``), and its centroid and area."""
    reach = math.hypot(*half) + margin + 3
    box = crop_box(frame.shape, centre, reach)
    lo, hi = box
    img = frame[lo[1]:hi[1], lo[0]:hi[0]].astype(np.float32)
    alpha, _ = matte(img, background.image[lo[1]:hi[1], lo[0]:hi[0]], palette, background.noise_sd)
    c = np.asarray(centre, float) - lo
    for _ in range(10):  # re-centred on the matte, in case ``centre`` is a rough one
        cut = np.where(footprint(alpha.shape, c + lo, half, angle, grow=margin, offset=lo), alpha, 0.0)
        c = weighted_centroid(cut)
        if c is None:
            raise ValueError("no matte at the object's position")
    alpha = cut
    size = int(2 * math.ceil(reach) + 1)
    upright = _place(alpha.astype(np.float32), c, -angle, ((size - 1) / 2, (size - 1) / 2), (size, size))
    tc = weighted_centroid(upright)
    return Look(palette, upright.astype(np.float32), tc, float(upright.sum()))


# ------------------------------------------------------------------------------ tracking


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
    """

    pixels: np.ndarray
    valid: np.ndarray
    quality: np.ndarray
    aligned: np.ndarray
    lost: np.ndarray
    rough: np.ndarray
    look_frame: np.ndarray


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
    moved = ok & (np.linalg.norm(px[:, i] - start[i], axis=-1) > diag) & (np.linalg.norm(px[:, i] - rest, axis=-1) > diag)
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


def _learn_looks(frames, bg: ColourBackground, px: np.ndarray, ks, half, angles: np.ndarray, n_looks: int = 8,
                 n_palette: int = 12) -> list[tuple[np.ndarray, Look]]:
    """An object's looks from its clean frames ``ks`` (slowest first; object at ``px`` (N, 2),
    tilted by ``angles`` (N,)): one palette from the ``n_palette`` slowest, and a template
    from each of up to ``n_looks`` of them spread along its path, with the position it was
    taken at. Where the camera is perspective or the object turns, its silhouette changes
    along its path; each frame is then measured with the nearest look (:func:`_nearest`).
    Templates whose area is not 0.5 to 1.6 times the object's footprint (a frame in which
    something else was taken for it, or most of it was missed) are left out.

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
    if not kept:
        raise ValueError("no matte at the object's position")
    return kept


def _nearest(looks: list[tuple[np.ndarray, Look]], at) -> Look:
    """The look (:func:`_learn_looks`) taken nearest the position ``at`` (px)."""
    return min(looks, key=lambda pl: float(np.linalg.norm(pl[0] - at)))[1]


def _measure_all(frames, bg: ColourBackground, looks, px: np.ndarray, halves, angles: np.ndarray, speed: np.ndarray,
                 rough: np.ndarray, ks=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every frame (or the frames ``ks``) of every object measured (:func:`measure`) around
    ``px`` (N, n, 2), each keeping out of the others' footprints there: (N, n, 2) centres
    (``px`` where not measured), (N, n) qualities (0: not measured, or not wholly inside the
    image), (N, n) aligned flags.

    A centre farther from the ``rough`` track (N, n, 2) than the measurement's margin plus the
    object's smaller size (2 x its smaller half) is not measured: the centroid walked off the
    object the rough pass followed, onto another thing (the scenery where an object that left
    the image was last matched: the real clip sliding_plain_R4 after its object tumbled out)."""
    N, n = px.shape[:2]
    shape = frames.shape[1:3]
    known = np.all(np.isfinite(px), axis=-1)
    pixels, quality, aligned = px.copy(), np.zeros((N, n)), np.zeros((N, n), bool)
    for k in range(N) if ks is None else ks:
        for i in range(n):
            if not known[k, i] or visible_fraction(shape, px[k, i], halves[i], angles[k, i]) < 0.999:
                continue
            others = [(px[k, j], halves[j], angles[k, j]) for j in range(n) if j != i and known[k, j]]
            margin = 2.0 + 0.6 * speed[k, i]
            m = measure(frames[k], bg, _nearest(looks[i], px[k, i]), px[k, i], halves[i], angles[k, i],
                        margin=margin, blur=speed[k, i], keep_out=others)
            if np.linalg.norm(m.centre - rough[k, i]) <= margin + 2.0 * min(halves[i]):
                pixels[k, i], quality[k, i], aligned[k, i] = m.centre, m.quality, m.aligned
    return pixels, quality, aligned


def track_matte(frames: np.ndarray, start_pixels, halves, angles, *, start_frame: int = 0, fps: float | None = None,
                quality_min: float = 0.5, on_loss: str = "raise", first_frame: int = 0,
                measure_frames=None, path_tilts=None) -> MatteTracks:
    """Follow objects without texture by their colour matte (module docstring).

    Three passes: (1) a rough track from ``start_frame`` forwards and backwards, matching each
    object's look in that frame (:func:`rough_pass`); (2) the background (the median of the
    frames, leaving out the objects' footprints along the rough track), and each object's
    colours and clean template from frames in which it is seen whole and alone; (3) every
    frame measured (:func:`measure`) at the rough track's position.

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
    # clean-frame candidates: the object confirmed against the scenery (:func:`~galileo_jax.observe.rough._recentre`), else
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
        pixels, quality, aligned = _measure_all(frames, bg, looks, px, halves, angles, speed, rough, measure_frames)
        if measure_frames is None:
            good = quality >= 0.8
        else:  # frames not measured keep their rough-pass verdict
            ks = np.asarray(list(measure_frames), int)
            good[ks] = quality[ks] >= 0.8
        px = np.where((quality >= quality_min)[..., None], pixels, px)
    if measure_frames is None:
        _bridge(frames, bg, looks, pixels, quality, aligned, halves, angles, quality_min)
    valid = _not_isolated((quality >= quality_min) & _in_order(pixels, start))
    lost = lost_f.copy()
    if measure_frames is None:
        lost = np.where(lost >= 0, lost, _unseen_till_end(valid, rough, halves, angles, shape, start_frame))
    return MatteTracks(pixels, valid, quality, aligned, lost, rough, look_frame)


def _bridge(frames, bg: ColourBackground, looks, pixels: np.ndarray, quality: np.ndarray, aligned: np.ndarray,
            halves, angles: np.ndarray, quality_min: float, coast: int = 3) -> None:
    """Follow each object on from its own measurements where the rough track left it (in place).

    After the last frame of a measured run, each next frame is measured (:func:`measure`) where
    the object's last two measured centres (constant velocity) put it, keeping out of the other
    objects' footprints where they are measured; a measurement of quality >=
    :data:`BRIDGE_QUALITY` (stricter than ``quality_min``: no rough match confirms it) is taken
    and moves the prediction on. After ``coast`` frames running without one, or where the
    object would leave the image, the run ends. Measured on the tracking benchmark: the rough
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
    for i in range(n):
        k = 2
        while k < N:
            if quality[k, i] >= quality_min or quality[k - 1, i] < quality_min:
                k += 1
                continue
            p = pixels[k - 1, i].copy()
            v = p - pixels[k - 2, i] if quality[k - 2, i] >= quality_min else np.zeros(2)
            missed = 0
            while k < N and quality[k, i] < quality_min and missed < coast:
                guess = p + v
                if visible_fraction(shape, guess, halves[i], angles[k, i]) < 0.999:
                    break
                speed = float(np.linalg.norm(v))
                margin = 2.0 + 0.6 * speed
                others = [(pixels[k, j], halves[j], angles[k, j]) for j in range(n)
                          if j != i and quality[k, j] >= quality_min]
                m = measure(frames[k], bg, _nearest(looks[i], guess), guess, halves[i], angles[k, i],
                            margin=margin, blur=speed, keep_out=others)
                if m.quality >= BRIDGE_QUALITY and np.linalg.norm(m.centre - guess) <= margin + min(halves[i]):
                    pixels[k, i], quality[k, i], aligned[k, i] = m.centre, m.quality, m.aligned
                    v, p, missed = m.centre - p, m.centre, 0
                else:
                    p, missed = guess, missed + 1
                k += 1
            while k < N and quality[k, i] < quality_min:
                k += 1


def _in_order(pixels: np.ndarray, start: np.ndarray) -> np.ndarray:
    """(N, n) bool: False for both objects of a pair in the frames where their measured
    centres (N, n, 2) are no longer in the order of their ``start`` (n, 2): the vector from
    one to the other has turned by 90 degrees or more from where it pointed there. Two objects
    on one ramp cannot pass through each other, so their identities are in doubt there (look-
    alikes after a collision at speed: the rough pass keeps their order frame to frame, but a
    measurement or a bridge can still take the other's place)."""
    N, n = pixels.shape[:2]
    ok = np.ones((N, n), bool)
    for i in range(n):
        for j in range(i + 1, n):
            swapped = np.einsum("kc,c->k", pixels[:, j] - pixels[:, i], start[j] - start[i]) <= 0.0
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
