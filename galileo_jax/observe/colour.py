"""The colour model of an object without texture (:mod:`galileo_jax.observe.matte`'s docstring
says why): the video's background in colour (:func:`colour_background`), an object's colours
and clean template (:func:`object_colours`, :func:`learn_template`), and its soft alpha matte
over the background, with the pixels that are neither (an occluder) marked (:func:`matte`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np

from galileo_jax.observe.tracks import (
    BACKGROUND_FRAMES,
    BACKGROUND_MIN,
    crop_box,
    footprint,
    frame_median,
    spread_indices,
    weighted_centroid,
)

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


#: Brightness change of an object's colours (relative) that the matte allows for the light on
#: it in one frame (the object passing into shade, or nearer a lamp: 0.66 measured on a
#: rendered cube at the edge of a spot-lit view).
GAIN = 0.35


#: Brightness change (relative) that the matte allows pixel by pixel about the light level of
#: the frame (:func:`light_level`): the object's near face, shaded alike all over, stays in;
#: a side or top face a perspective camera shows, in another shade, stays out instead of
#: flipping between object, background and occluder from frame to frame.
SHADE_SPREAD = 0.15


#: Object pixels (explained at some gain) that :func:`light_level` needs, else the level is
#: unknown.
LIGHT_PIXELS_MIN = 8


CROSS = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))


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


def unlearn_objects(background: ColourBackground, frames: np.ndarray, k: int, centres, halves, angles,
                    like: float = 0.5, grow: float = 3.0) -> ColourBackground:
    """The background with each object's own colour removed where it was learned as background.

    An object resting at ``centres`` in frame ``k`` must differ from the background there. Where
    more than ``like`` of its inner pixels (its footprint shrunk to 70%) are within the
    background threshold of it (:func:`thresholds`), and yet more than ``like`` of them change
    by more than that threshold in another frame (something there moved: not a patch of static
    scenery, which is background), the frames taken as showing those pixels free showed the
    object (a collision that the first track got wrong, so that the object's footprint was left
    out elsewhere): the background under its footprint (grown by ``grow`` px), and any
    background of the object's colour near it, is inpainted from the surroundings
    (``cv2.inpaint``, Telea), and kept if the object then stands out. An object whose colour is
    that of the true background stays as it was.
    Measured on the held-out tracking video world_11: a grey-blue cube struck 25 px to the
    side had the background across its start footprint learned in its own colour, and its 39
    resting frames measured at quality 0.25 (0.95 once unlearnt).

    Args:
        background: from :func:`colour_background`.
        frames: (N, H, W, 3) uint8 BGR frames; in frame ``k`` the objects rest at ``centres``
            (n, 2) px.
        halves: per object (half along, half across) of its footprint (px).
        angles: (n,) footprint tilts (rad).

    Returns:
        :class:`ColourBackground` (the same object if nothing changed).
    """
    bg_thr, _ = thresholds(background.noise_sd)
    image = None
    frame = frames[k]
    for c, half, a in zip(np.asarray(centres, float), halves, np.asarray(angles, float)):
        box = crop_box(frame.shape, c, math.hypot(*half) + grow + 8)
        if box is None:
            continue
        lo, hi = box
        img = frame[lo[1]:hi[1], lo[0]:hi[0]].astype(np.float32)
        inner = footprint(img.shape, c, np.asarray(half) * 0.7, a, offset=lo)

        def share_like(bg_crop):
            return float(np.mean(np.linalg.norm(img - bg_crop, axis=-1)[inner] < bg_thr)) if inner.any() else 0.0

        current = (background.image if image is None else image)[lo[1]:hi[1], lo[0]:hi[0]]
        if share_like(current) <= like:
            continue
        others = frames[spread_indices(len(frames), BACKGROUND_FRAMES), lo[1]:hi[1], lo[0]:hi[0]].astype(np.float32)
        changed = (np.linalg.norm(others - img, axis=-1) > bg_thr).any(axis=0)
        if changed[inner].mean() <= like:  # static scenery: it is background
            continue
        # the footprint, and any background near it of the object's colour (learnt where the
        # object stood in the frames taken as free, which need not be exactly here)
        colour = np.median(img[inner], axis=0)
        learnt = np.linalg.norm(current - colour, axis=-1) < bg_thr
        hole = (footprint(img.shape, c, half, a, grow=grow, offset=lo) | learnt).astype(np.uint8)
        hole = cv2.dilate(hole, CROSS)
        filled = cv2.inpaint(np.clip(current, 0, 255).astype(np.uint8), hole, 5, cv2.INPAINT_TELEA).astype(np.float32)
        if share_like(filled) <= like:
            image = background.image.copy() if image is None else image
            image[lo[1]:hi[1], lo[0]:hi[0]] = np.where(hole[..., None] > 0, filled, current)
    return background if image is None else background._replace(image=image)


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


def thresholds(noise_sd: float) -> tuple[float, float]:
    """(background, residual) colour-distance thresholds in grey levels for a noise SD."""
    return (max(BACKGROUND_SDS * math.sqrt(3.0) * noise_sd, BACKGROUND_MIN),
            max(RESIDUAL_SDS * math.sqrt(3.0) * noise_sd, RESIDUAL_MIN))


def matte(image: np.ndarray, background: np.ndarray, palette: Palette, noise_sd: float,
          min_lit: float = LIGHT_PIXELS_MIN) -> tuple[np.ndarray, np.ndarray]:
    """The object's matte over a known background.

    Args:
        image: (h, w, 3) float32 BGR pixels.
        background: (h, w, 3) float32 background at the same pixels.
        palette: the object's colours and their tolerance.
        noise_sd: pixel noise SD of one channel (grey levels).
        min_lit: object pixels the light level needs (below).

    The colours are taken at the frame's light level: as learned where at least ``min_lit``
    pixels (half covered or more) are explained by them, else :func:`light_level` of the
    pixels they do not explain; a pixel may differ from them by a gain of up to
    :data:`SHADE_SPREAD` (shade within the face), and where the level is unknown, by up to
    :data:`GAIN` from the learned colours.

    Returns:
        ``(alpha, unusable)``: (h, w) float32 alpha in [0, 1] (0 on background and unusable
        pixels) and (h, w) bool, pixels that are neither background nor explained by the
        object's colours (an occluder), or where every colour of the object is too close to
        the background's to tell (:mod:`galileo_jax.observe.matte`).
    """
    h, w = image.shape[:2]
    I, B = image.reshape(-1, 3), background.reshape(-1, 3)
    d = I - B
    dd = np.einsum("pc,pc->p", d, d)
    bg_thr, _ = thresholds(noise_sd)
    res_thr = palette.tolerance
    F = np.asarray(palette.colours, np.float32)  # (K, 3)
    alpha, best_r2, contrast2 = _unmix_all(F, d, dd, B)
    # the light level: as learned where enough of the object is explained as learned (a pale
    # object's blends with a pale background would pass for it at other gains); else from the
    # pixels wholly the object's at some gain, and the colours taken at that level
    differs = dd >= bg_thr * bg_thr
    level = 1.0
    if np.count_nonzero(differs & (best_r2 <= res_thr * res_thr) & (alpha >= 0.5)) < max(min_lit, LIGHT_PIXELS_MIN):
        level = light_level(I[differs & (best_r2 > res_thr * res_thr)], palette, min_lit)
    spread = GAIN if level is None else SHADE_SPREAD  # the light unknown: any gain within GAIN
    if level is not None and level != 1.0:
        F = F * np.float32(level)
        alpha, best_r2, _ = _unmix_all(F, d, dd, B)
    FF = np.einsum("kc,kc->k", F, F)
    # where no colour explains a pixel at the frame's light level, the colour as the light
    # there makes it (a gain in [1 - SHADE_SPREAD, 1 + SHADE_SPREAD] about that level, or within
    # GAIN of the learned colour where the level is unknown, from the pixel taken as wholly the
    # object's); edges already explained keep their alpha
    far = np.flatnonzero(best_r2 > res_thr * res_thr)
    if len(far):
        g = np.clip(F @ I[far].T / np.maximum(FF, 1e-6)[:, None], 1.0 - spread, 1.0 + spread)  # (K, m)
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
    odd = cv2.morphologyEx(odd, cv2.MORPH_OPEN, CROSS) > 0
    unusable = odd | (contrast < max(CONTRAST_MIN, 2 * bg_thr))
    alpha = np.where(is_bg | unusable, 0.0, alpha).astype(np.float32)
    return alpha, unusable


def light_level(pixels: np.ndarray, palette: Palette, min_pixels: float = LIGHT_PIXELS_MIN) -> float | None:
    """The light on an object in one frame, relative to its palette's: the median gain g (in
    [1 - GAIN, 1 + GAIN]) of the pixels that are wholly one of its colours at some gain
    (|I - g F_k| within the palette's tolerance, g = I.F_k / |F_k|^2 for the best k). Pixels
    mixed with the background at its edges, an occluder and faces in another shade mostly fail
    that test; the face that shows most (a cube's near face) sets the level.

    Args:
        pixels: (m, 3) float32 BGR pixels that differ from the background (in :func:`matte`,
            those its learned colours do not explain).
        palette: the object's colours.
        min_pixels: pixels that must pass the test, else the level is unknown: a motion-blurred
            object has few pixels wholly its own, and the blend of its colour with the
            background's at the others can pass for it at another gain (measured: a 12 px cube
            blurred over 10 px lost 16 frames when its level was taken from them).

    Returns:
        The gain, or None where fewer than ``min_pixels`` (and :data:`LIGHT_PIXELS_MIN`) pass.
    """
    need = max(float(min_pixels), LIGHT_PIXELS_MIN)
    if len(pixels) < need:
        return None
    g, r2 = best_gain(pixels, palette.colours)
    ok = r2 <= palette.tolerance ** 2
    if ok.sum() < need:
        return None
    return float(np.median(g[ok]))


def best_gain(pixels: np.ndarray, colours: np.ndarray, spread: float = GAIN) -> tuple[np.ndarray, np.ndarray]:
    """Each pixel as the nearest of ``colours`` brightened or darkened: for (m, 3) BGR
    ``pixels`` and (K, 3) ``colours`` F_k, the gain g = clip(I.F_k / |F_k|^2, 1 - ``spread``,
    1 + ``spread``) and squared distance |I - g F_k|^2 (grey levels^2) of the colour that
    leaves the least: ``(gain, distance^2)``, each (m,)."""
    pixels = np.asarray(pixels, np.float32)
    F = np.asarray(colours, np.float32)
    FF = np.maximum(np.einsum("kc,kc->k", F, F), 1e-6)
    proj = pixels @ F.T  # (m, K)
    g = np.clip(proj / FF[None], 1.0 - spread, 1.0 + spread)
    r2 = np.maximum(np.einsum("mc,mc->m", pixels, pixels)[:, None] - 2 * g * proj + g * g * FF[None], 0.0)
    k = np.argmin(r2, axis=1)
    rows = np.arange(len(pixels))
    return g[rows, k], r2[rows, k]


def _unmix_all(F: np.ndarray, d: np.ndarray, dd: np.ndarray, B: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_unmix` of P pixels (``d`` (P, 3) = I - B, ``dd`` (P,) = |d|^2, ``B`` (P, 3)) with
    K colours ``F`` (K, 3): ``(alpha, residual^2, contrast^2)``, each (P,), contrast^2 the
    largest |F_k - B|^2."""
    FF = np.einsum("kc,kc->k", F, F)
    # with e_k = F_k - B: d.e_k = d.F_k - d.B and |e_k|^2 = |F_k|^2 - 2 F_k.B + |B|^2, as (K, P)
    # products (no (K, P, 3) arrays)
    ee = np.maximum(FF[:, None] - 2.0 * (F @ B.T) + np.einsum("pc,pc->p", B, B)[None], 0.0)
    alpha, best_r2 = _unmix(F @ d.T - np.einsum("pc,pc->p", d, B)[None], dd, ee)
    return alpha, best_r2, ee.max(axis=0)


def _unmix(de: np.ndarray, dd: np.ndarray, ee: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The best of K colours for each of P pixels: with d = I - B a pixel's difference from
    the background (``dd`` (P,) = |d|^2) and e_k = F_k - B each colour's (``de`` (K, P) =
    d.e_k, ``ee`` (K, P) = |e_k|^2), the alpha a_k = clip(d.e_k / |e_k|^2, 0, 1) and squared
    residual |d - a_k e_k|^2 of the colour that leaves the least (the first on ties):
    ``(alpha, residual^2)``, each (P,)."""
    best_a = best_r2 = None
    for de_k, ee_k in zip(de, ee):  # K is a few colours: a running best, no (K, P) index arrays
        a = np.clip(de_k / np.maximum(ee_k, 1e-6), 0.0, 1.0)
        r2 = dd - 2 * a * de_k + a * a * ee_k
        if best_a is None:
            best_a, best_r2 = a, r2
        else:
            better = r2 < best_r2
            best_a, best_r2 = np.where(better, a, best_a), np.where(better, r2, best_r2)
    return best_a, best_r2


def place_template(template: np.ndarray, t_centre, angle: float, at, shape) -> np.ndarray:
    """The upright ``template`` turned by ``angle`` rad about its centroid ``t_centre`` and
    placed with that centroid at ``at`` (px) in an array of ``shape`` (h, w)."""
    c, s = math.cos(angle), math.sin(angle)
    R = np.array([[c, -s], [s, c]])
    M = np.hstack([R, (np.asarray(at, float) - R @ np.asarray(t_centre, float))[:, None]])
    return cv2.warpAffine(template, M, (shape[1], shape[0]), flags=cv2.INTER_LINEAR, borderValue=0.0)


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
    upright = place_template(alpha.astype(np.float32), c, -angle, ((size - 1) / 2, (size - 1) / 2), (size, size))
    tc = weighted_centroid(upright)
    return Look(palette, upright.astype(np.float32), tc, float(upright.sum()))
