"""Tracking every object of a scene, each by the method that suits it.

:func:`track_scene` follows each object from its start pixel by one of three methods:

* ``outline`` (:mod:`.outline`): round objects (spheres, a pipe seen end-on) by their round
  outline, since their texture turns with them;
* ``features`` (:mod:`.klt`): textured objects by KLT features (dissertation 4.2.2);
* ``colour`` (:mod:`.matte`): objects without texture (painted blocks, plastic, foam, a tape
  roll) by their colour matte against the static background.

``tracker: auto`` (the scene's default) picks ``outline`` for spheres; for the others it first
follows the object by its colour, then looks at the object in the clean frame the colour
tracker learned it from: with texture inside it (:func:`has_texture`), KLT follows it too (and
if KLT cannot, the colour track is kept, with the frames it could not measure left out) and
the two tracks are compared (:func:`_cross_check`): where they agree, the steadier one is kept
(frames in which they disagree by more than :data:`CROSS_CHECK_PX` are dropped from a kept KLT
track); where they do not, KLT is kept. Without texture, the colour track is the answer. Where
that was lost (a collision with a look-alike, heavy blur), KLT follows the object too, on
probation (:func:`_cross_check`): its track is kept only where it agrees with the colour track
before the loss and the other objects' colour tracks were not lost; else the colour track is,
its frames from the loss on left out of the fit (counted in ``result.json``'s tracking summary,
:meth:`~galileo_jax.observation.TrackingInfo.counts`). KLT on a plain object follows a few
corners of its outline, which may slide along the scenery or move onto a look-alike it collides
with (on the tracking videos such tracks ran 30 px off before the loss and 650 px after it, or
followed the look-alike after a collision that both colour tracks lost, unflagged). An object
whose colour does not stand out from the background, or is not measured in its start frame,
goes to KLT.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

from galileo_jax.calibration import Calibration
from galileo_jax.errors import TrackingError
from galileo_jax.observe.klt import track_objects
from galileo_jax.observe.matte import track_matte
from galileo_jax.observe.outline import track_circles
from galileo_jax.observe.tracks import (QUALITY_MIN, Tracks, Window, as_gray, estimate_noise_sd, has_texture,
                                        object_windows, parallel_map, path_direction, path_tilts, polygon_mask,
                                        submit, window_corners)
from galileo_jax.scene import Scene

#: Frames in which a KLT track and the colour track of the same object disagree by more than
#: this (px) are dropped (one of them caught something else) ...
CROSS_CHECK_PX = 2.0
#: ... when the two agree in general (median distance at most this, px); where they do not,
#: the colour model does not fit the textured object, and KLT is kept as it is.
CROSS_CHECK_AGREE_PX = 1.0
#: Frames in which a KLT track sits inside another object before the colour track replaces it
#: (features caught by a look-alike stay on it; a frame or two, e.g. the other object's track
#: at the image border, are dropped instead).
CAUGHT_FRAMES = 3
#: A colour track whose noise SD is under this fraction of the KLT track's replaces it.
STEADIER = 0.8
#: A KLT track whose offset from the colour track (where that one measured at least
#: :data:`STEP_QUALITY`) shifts by more than this (px, median of :data:`CAUGHT_FRAMES` compared
#: frames before against after) has jumped: its features were lost at a turn or an impact
#: and the centre was carried over wrongly, or it stuck to the scenery. The offset between the
#: two trackers' points drifts by at most 1-2 px across a wide perspective view (measured on
#: the tracking benchmark), a jump was 10-200 px.
STEP_PX = 4.0
STEP_QUALITY = 0.8
#: Colour measurements (of at least :data:`CENTRE_QUALITY`) in the first frames of a KLT track
#: that place KLT's start pixel at the object's centre (:func:`_centred_starts`).
CENTRE_FRAMES = 5
CENTRE_QUALITY = 0.8


class SceneTracks(NamedTuple):
    """The objects of a scene, tracked (:func:`track_scene`).

    Attributes:
        tracks: the :class:`~galileo_jax.observe.tracks.Tracks` of all objects, in the scene's
            order.
        methods: per object the method whose track is used: "features", "colour" or
            "outline" (a textured object that KLT followed reads "colour" when its colour
            track was the steadier; its ``cross_check_px`` is then not NaN).
        cross_check_px: (n,) median distance (px) between the KLT and colour tracks of an
            object followed by KLT with a colour track beside it, after removing their median
            offset; NaN where there was none.
        cross_check_dropped: (n,) frames dropped because the two disagreed.
    """

    tracks: Tracks
    methods: tuple[str, ...]
    cross_check_px: np.ndarray
    cross_check_dropped: np.ndarray


def is_round(scene: Scene, i: int) -> bool:
    """Whether object ``i`` is tracked by its round outline (:func:`track_circles`), not by
    KLT features that turn with it: ``tracker: outline``, or a sphere with ``tracker: auto``."""
    obj = scene.objects[i]
    return obj.tracker == "outline" or (obj.tracker == "auto" and obj.shape == "sphere")


def tracker_of(scene: Scene, i: int) -> str:
    """Object ``i``'s ``tracker`` with "outline" for a sphere under "auto" (:func:`is_round`)."""
    return "outline" if is_round(scene, i) else scene.objects[i].tracker


def track_scene(frames: np.ndarray, start_pixels, scene: Scene, calib: Calibration, *, start_frame: int = 0,
                background: np.ndarray | None = None, fps: float | None = None, progress: bool = False,
                colour_start: tuple[int, np.ndarray] | None = None) -> SceneTracks:
    """Track every object of a scene, each by its method (module docstring), with windows
    from the scene's sizes.

    With ``start_frame`` > 0 the objects rest at ``start_pixels`` in that frame (e.g. just
    before object 1 starts to move, when a hand that covered it in frame 0 has gone or is
    leaving) and are tracked forward to the end and backward to frame 0. KLT takes its
    features there, keeping only those that rested in the 3 frames before (not on a hand
    lifting off), and tracks backward without new features (a backward track that loses its
    features, the hand covering the object again, holds its position, marked invalid).

    On a machine with more than one core, KLT starts on the objects that show texture in the
    start frame while the colour tracks are computed (:func:`~galileo_jax.observe.tracks.submit`),
    and its forward and backward tracks run at once; the tracks are those of the serial order
    (measured on a 960x540 checker video: 103 -> 132 frames/s; a plain one, where KLT has
    nothing to follow, unchanged).

    Args:
        frames: (N, H, W, 3) uint8 BGR frames.
        start_pixels: (n, 2) centres in frame ``start_frame``, px.
        scene, calib: the scene and its calibration (scale, direction, roll).
        start_frame: frame in which tracking starts.
        background: grey background for :func:`track_objects`.
        fps: frame rate for error messages.
        progress: show progress bars.
        colour_start: optional (frame, (n, 2) centres) from which the colour tracker starts
            instead (objects clear of a hand there, :class:`~galileo_jax.observe.find.Located`).

    Returns:
        :class:`SceneTracks`.

    Raises:
        TrackingError: an object cannot be followed (see :func:`track_objects`,
            :func:`track_circles`, :func:`~galileo_jax.observe.matte.track_matte`).
    """
    start = np.asarray(start_pixels, float).reshape(-1, 2)
    n = scene.n_objects
    wins = object_windows(scene, calib)
    methods = [tracker_of(scene, i) for i in range(n)]
    k_colour, px_colour = (start_frame, start) if colour_start is None else (colour_start[0], colour_start[1])
    kw = dict(background=background, fps=fps, progress=progress, start_frame=start_frame)
    # KLT on the objects that show texture at their start, beside the colour tracks (on another
    # core): used below where the choice of methods asks for KLT on exactly those objects
    guess = [i for i in range(n) if methods[i] == "features" or (
        methods[i] == "auto" and has_texture(frames[start_frame], start[i], wins[i].half, wins[i].angle))]
    early = submit(lambda: _both_ways(track_objects, frames, start[guess], [wins[i] for i in guess], **kw)) \
        if guess else None
    colour = _colour_tracks(frames, np.asarray(px_colour, float).reshape(-1, 2), wins, methods, int(k_colour), fps,
                            path_tilts(scene, calib))
    on_probation: set[int] = set()
    for i in range(n):
        if methods[i] == "auto":
            k = int(colour[i][4]) if i in colour else -1
            # the colour track must also measure the start frame, where it anchors the track
            at_start = i in colour and bool(colour[i][1][start_frame])
            plain = at_start and k >= 0 and not has_texture(
                frames[k], colour[i][0][k], wins[i].half,
                wins[i].angle if k <= start_frame else _tilt(colour[i][0], k, wins[i].angle))
            if plain and colour[i][3] >= 0:  # its colour track was lost: KLT on probation
                on_probation.add(i)
                plain = False
            methods[i] = "colour" if plain else "features"
    klt = [i for i in range(n) if methods[i] == "features"]
    parts: dict[int, tuple] = {}
    while klt:  # KLT; an "auto" object it cannot follow falls back to its colour track
        try:
            if early is not None and klt == guess:  # the KLT run begun beside the colour tracks
                tr, early = early.result(), None
            else:
                tr = _both_ways(track_objects, frames, start[klt], [wins[i] for i in klt], **kw)
        except TrackingError as err:
            j = err.object_index
            i = None if j is None else klt[j]
            # the colour track stands in where KLT cannot even start (a small or plain object),
            # or where KLT lost the object and the colour tracker did not, or later (its frames
            # from there on are not measured)
            colour_lost = colour[i][3] if i in colour else -1
            if i is not None and err.at_start and scene.objects[i].tracker == "auto" and i not in colour:
                u, v = start[i]
                raise TrackingError(f"object {i + 1}: it shows too little texture to follow by its features and "
                                    "its colour does not stand out from the background, at its start pixel "
                                    f"({u:.0f}, {v:.0f}) in frame {start_frame}; check camera.start_pixels, or "
                                    "film it against a background of another colour", object_index=i,
                                    at_start=True) from None
            if i is None or scene.objects[i].tracker != "auto" or i not in colour or \
                    (colour_lost >= 0 and not err.at_start and (err.frame is None or colour_lost <= err.frame)
                     and i not in on_probation):  # a plain object keeps its colour track up to its loss
                raise _in_scene(err, klt) from None
            methods[i] = "colour"
            klt.remove(i)
            continue
        parts.update({i: tuple(f[:, j] for f in tr) for j, i in enumerate(klt)})
        centred = _centred_starts(start, tr, colour, klt, start_frame, wins)
        if centred is not None:  # again from the objects' centres
            try:
                tr = _both_ways(track_objects, frames, centred[klt], [wins[i] for i in klt], **kw)
                parts.update({i: tuple(f[:, j] for f in tr) for j, i in enumerate(klt)})
            except TrackingError:
                pass  # the first tracks stand
        break
    for i in range(n):
        if methods[i] == "colour":
            px, valid, quality = colour[i][:3]
            parts[i] = (px, valid, valid.astype(int), quality)
    circ = [i for i in range(n) if methods[i] == "outline"]
    if circ:
        try:
            tr = _both_ways(track_circles, frames, start[circ], [wins[i].half[0] for i in circ], **kw)
        except TrackingError as err:
            raise _in_scene(err, circ) from None
        parts.update({i: tuple(f[:, j] for f in tr) for j, i in enumerate(circ)})
    tracks = Tracks(*(np.stack([parts[i][m] for i in range(n)], axis=1) for m in range(4)))
    downhill = [path_direction(scene, calib, i) for i in range(n)]
    tracks, agree, dropped = _cross_check(tracks, colour, methods, downhill, start_frame,  # may switch to "colour"
                                          _pair_gaps(wins), scenery=(frames, background, wins),
                                          probation=on_probation)
    tracks = _with_streaks(tracks, colour, methods)
    cut = [i for i in range(n) if methods[i] != "outline"]
    return SceneTracks(_inside_only(tracks, wins, frames.shape[1:3], cut), tuple(methods), agree, dropped)


def _with_streaks(tracks: Tracks, colour: dict, methods: list[str]) -> Tracks:
    """The tracks with each colour-tracked object's blur-streak corrections added
    (:class:`~galileo_jax.observe.matte.MatteTracks`'s ``streak``). Only there: where KLT
    follows an object, its colour track is a cross-check, and the checks were measured on
    (and tuned for) the plain centroids."""
    px = tracks.pixels.copy()
    for i in range(len(methods)):
        if methods[i] == "colour" and i in colour:
            px[:, i] += colour[i][5]
    return tracks._replace(pixels=px)


def _centred_starts(start: np.ndarray, tr: Tracks, colour: dict, ids: list[int], start_frame: int, wins
                    ) -> np.ndarray | None:
    """(n, 2) start pixels at the objects' centres for KLT, or None where none moves.

    KLT reports the point its features' rigid motion carries from the start pixel; a start
    pixel off the object's centre turns about it where the object turns at the ramp's foot
    (measured: checker_persp_960x540_blur_0, a start pixel found while the hand was leaving
    lay 11 px from the near face's centre; after the turn of about 20 degrees its point was
    2-3.4 px off). Where the colour track measured object ``ids[j]`` with quality >=
    :data:`CENTRE_QUALITY` in the first :data:`CENTRE_FRAMES` frames from ``start_frame`` in
    which KLT's track ``tr`` (its column j) is valid too, and the offset from KLT's point to the
    colour centre is the same in all of them (within 1 px of their median: no turn yet),
    between 1 px and the object's smaller half size, the start pixel moves by that offset."""
    out = np.array(start, float)
    moved = False
    for j, i in enumerate(ids):
        if i not in colour:
            continue
        px, valid, quality = colour[i][:3]
        ks = [k for k in range(start_frame, len(px))
              if tr.valid[k, j] and valid[k] and quality[k] >= CENTRE_QUALITY][:CENTRE_FRAMES]
        if len(ks) < CENTRE_FRAMES:
            continue
        offsets = px[ks] - tr.pixels[ks, j]
        d = np.median(offsets, axis=0)
        if np.abs(offsets - d).max() <= 1.0 and 1.0 <= float(np.linalg.norm(d)) <= min(wins[i].half):
            out[i] += d
            moved = True
    return out if moved else None


def _in_scene(err: TrackingError, ids: list[int]) -> TrackingError:
    """A tracker's error about object ``j`` of the subset ``ids`` it followed, told with the
    object's number in the scene (its messages start "object {j + 1}")."""
    j = err.object_index
    if j is None or not 0 <= j < len(ids):
        return err
    return TrackingError(str(err).replace(f"object {j + 1}", f"object {ids[j] + 1}", 1), object_index=ids[j],
                         at_start=err.at_start, frame=err.frame)


def _inside_only(tracks: Tracks, wins, shape, objects) -> Tracks:
    """Frames in which one of ``objects``' footprint (its window at the tracked centre, grown
    by 1 px) is not wholly inside the image are not measured (valid False, quality 0): an
    object cut by the image's border is seen only in part, and KLT's and the colour matte's
    centres are then biased towards the part they see (a circle fitted to the visible part of
    an outline is not, so outline-tracked objects are not in ``objects``)."""
    px = tracks.pixels
    h, w = shape
    valid, quality = tracks.valid.copy(), tracks.quality.copy()
    for i in objects:
        win = wins[i]
        grown = Window((win.half[0] + 1, win.half[1] + 1), win.angle)
        for k in np.flatnonzero(valid[:, i]):
            c = window_corners(px[k, i], grown)
            if c.min() < 0 or c[:, 0].max() > w - 1 or c[:, 1].max() > h - 1:
                valid[k, i], quality[k, i] = False, 0.0
    return tracks._replace(valid=valid, quality=quality)


def _tilt(px: np.ndarray, k: int, angle0: float) -> float:
    """Tilt (rad) of a track's direction of motion at frame ``k`` (``angle0`` when it rests)."""
    j0, j1 = max(k - 1, 0), min(k + 1, len(px) - 1)
    v = px[j1] - px[j0]
    if not np.all(np.isfinite(v)) or np.linalg.norm(v) < 1.5 * (j1 - j0):
        return angle0
    b = np.arctan2(v[1], v[0])
    return float((b - angle0 + np.pi / 2) % np.pi - np.pi / 2 + angle0)


def _colour_tracks(frames, start: np.ndarray, wins, methods: list[str], start_frame: int, fps, tilts=None) -> dict:
    """Colour tracks of the objects whose method is "colour" or "auto", followed together
    (each keeps out of the others' footprints): ``{i: (pixels, valid, quality, lost,
    look_frame, streak)}`` (``lost`` >= 0: the frame from which the track was lost; ``streak``
    (N, 2) px, :class:`~galileo_jax.observe.matte.MatteTracks`'s, for the object's own track only). An "auto" object
    whose colour does not stand out is left out (KLT takes it); a "colour" one raises, as does
    a lost "colour" track. ``tilts``: the path's image tilts (:func:`~galileo_jax.observe.tracks.path_tilts`).

    Raises:
        TrackingError: a ``tracker: colour`` object's colour does not stand out from the
            background at its start, or its track is lost inside the image.
    """
    group = [i for i, m in enumerate(methods) if m in ("colour", "auto")]
    while group:
        try:
            mt = track_matte(frames, start[group], [wins[i].half for i in group], [wins[i].angle for i in group],
                             start_frame=start_frame, fps=fps, on_loss="hold", path_tilts=tilts)
        except TrackingError as err:
            j = err.object_index
            if j is None or methods[group[j]] != "auto":
                raise
            group.pop(j)
            continue
        out = {}
        for j, i in enumerate(group):
            if mt.lost[j] >= 0 and methods[i] == "colour":
                when = f" (t = {mt.lost[j] / fps:.2f} s)" if fps else ""
                raise TrackingError(f"object {i + 1} track lost at frame {mt.lost[j]}{when}: its colour no longer "
                                    "stands out from the background (occluded, or out of the light?); check the "
                                    "video, or try tracker: features")
            out[i] = (mt.pixels[:, j], mt.valid[:, j], mt.quality[:, j], mt.lost[j], mt.look_frame[j], mt.streak[:, j])
        return out
    return {}


def _both_ways(track, frames, start, windows, *, start_frame: int, background, fps, progress) -> Tracks:
    """``track`` (:func:`track_objects` or :func:`track_circles`) forward from ``start_frame``
    and, if it is > 0, backward to frame 0 (see :func:`track_scene`)."""
    kw = dict(fps=fps, progress=progress)
    if track is track_objects:
        prelude = frames[max(0, start_frame - 3): start_frame]
        kw.update(background=background, prelude=prelude)
    if start_frame <= 0:
        return track(frames[start_frame:], start, windows, first_frame=start_frame, **kw)
    back = dict(kw, redetect=False) if track is track_objects else kw
    forward, backward = parallel_map(  # at once (the forward track's loss raises as it would alone)
        lambda way: track(frames[start_frame:], start, windows, first_frame=start_frame, **kw) if way > 0 else
        track(frames[start_frame::-1], start, windows, on_loss="hold", **back), (+1, -1))
    merged = Tracks(*(np.concatenate([b[::-1][:-1], f]) for b, f in zip(backward, forward)))
    return _slower_before(merged, start_frame)


def _slower_before(tracks: Tracks, k0: int) -> Tracks:
    """Before frame ``k0`` the objects rest or start from rest, so they move no faster than
    just after it: a backward track that jumps faster (it caught a hand moving over the
    object) holds its last good position instead, marked invalid."""
    px, valid, count, quality = (np.array(f, copy=True) for f in tracks)
    for i in range(px.shape[1]):
        limit = max(1.0, 1.5 * np.linalg.norm(px[min(k0 + 1, len(px) - 1), i] - px[k0, i]))
        for k in range(k0 - 1, -1, -1):
            if not valid[k, i] or np.linalg.norm(px[k, i] - px[k + 1, i]) > limit:
                px[: k + 1, i], valid[: k + 1, i], count[: k + 1, i], quality[: k + 1, i] = px[k + 1, i], False, 0, 0
                break
    return Tracks(px, valid, count, quality)


def _reach_along(px: np.ndarray, valid: np.ndarray, k0: int, direction: np.ndarray) -> tuple[float, float]:
    """(farthest downhill, farthest uphill) travel in px of a track along ``direction`` from
    its pixel in frame ``k0``, over its valid frames."""
    if not valid.any() or not np.all(np.isfinite(px[k0])):
        return 0.0, 0.0
    along = (px[valid] - px[k0]) @ direction
    return float(max(along.max(), 0.0)), float(max(-along.min(), 0.0))


def _follows_a_hand(klt_track, colour_track, k0: int, direction: np.ndarray) -> bool:
    """The KLT track goes up the ramp more than down it (its features were on a hand that
    let go and moved away) while the colour track goes down it (at least 3 px, and twice
    as far as up): the object was released and slid, so the colour track is the
    object's. Tracks are ``(pixels (N, 2), valid (N,))``."""
    down_k, up_k = _reach_along(*klt_track, k0, direction)
    down_c, up_c = _reach_along(*colour_track, k0, direction)
    return up_k > down_k and down_c > max(3.0, 2.0 * up_c)


def _overlaps(px: np.ndarray, valid: np.ndarray, others: list, gaps: list) -> np.ndarray:
    """(N,) frames in which a track's centre comes closer to another object's centre than
    that pair's ``gap`` (px): two rigid objects cannot sit inside each other, so the track
    has caught the other object (KLT features of one checkered cube moving onto the other
    at their collision). ``others``: the other objects' ``(pixels (N, 2), valid (N,))``."""
    out = np.zeros(len(px), bool)
    for (px_j, valid_j), gap in zip(others, gaps):
        both = valid & valid_j
        if both.any():
            out[both] |= np.linalg.norm(px[both] - px_j[both], axis=-1) < gap
    return out


def _offset_residuals(px_a: np.ndarray, px_b: np.ndarray, both: np.ndarray) -> np.ndarray:
    """(N,) distance (px) between two tracks of one object after removing the offset between
    the points they measure, modelled as affine in the image position (fitted over ``both``,
    twice, the second time without the frames more than 3 robust SDs off): the two methods
    see different points of the object (KLT the features of its textured front face, the
    colour matte the centre of its silhouette, which with a perspective camera also shows a
    top or side face whose share changes across the image), so their offset drifts smoothly
    with the position, by several px over a wide view; a jump is what a caught feature or a
    lost matte looks like. The first fit uses only the frames whose offset is near the median
    offset (within 3 robust SDs, at least 3 px)."""
    diff = px_a - px_b
    pos = px_a[both]
    centre = pos.mean(axis=0)
    # slopes along the principal axes of the path that it spans (> 10 px SD): along a straight
    # path the other axis would let the offset model absorb any jump off the line
    _, sv, axes = np.linalg.svd(pos - centre, full_matrices=False)
    spread = sv / np.sqrt(len(pos))
    keep = spread > 10.0
    design = np.concatenate([np.ones((len(px_a), 1)), (px_a - centre) @ axes[keep].T / spread[keep]], axis=1)
    # start from the frames near the median offset: a least-squares start would be pulled by a
    # long stretch of a stuck track (hundreds of px off) until most frames look off
    resid = np.linalg.norm(diff - np.median(diff[both], axis=0), axis=-1)
    use = both & (resid <= max(3.0 * 1.4826 * float(np.median(resid[both])), 3.0))
    if use.sum() < 8:
        use = both.copy()
    for _ in range(2):
        coef, *_ = np.linalg.lstsq(design[use], diff[use], rcond=None)
        fit = design @ coef
        resid = np.linalg.norm(diff - fit, axis=-1)
        scale = max(1.4826 * float(np.median(resid[both])), 0.2)
        use = both & (resid <= 3.0 * scale)
        if use.sum() < 8:
            break
    return np.where(np.isfinite(resid), resid, np.inf)


def _klt_stepped(px_k: np.ndarray, valid_k: np.ndarray, px_c: np.ndarray, good_c: np.ndarray,
                 run: int = CAUGHT_FRAMES) -> bool:
    """Whether a KLT track's offset from the colour track of the same object shifts by more
    than :data:`STEP_PX` somewhere: the median offset over ``run`` compared frames (KLT
    ``valid_k``, colour ``good_c``, both (N,) bool; pixels (N, 2)) before a frame against the
    median over ``run`` from it. Two trackers on one object measure two of its points, whose
    offset drifts slowly with the position; a shift that persists for ``run`` frames is one of
    them leaving the object, and a colour track measured well there (its matte has the
    object's colours and shape) is not the one that left."""
    both = valid_k & good_c & np.all(np.isfinite(px_k), axis=-1) & np.all(np.isfinite(px_c), axis=-1)
    ks = np.flatnonzero(both)
    if len(ks) < 2 * run:
        return False
    off = px_k[ks] - px_c[ks]
    for j in range(run, len(ks) - run + 1):
        shift = np.median(off[j: j + run], axis=0) - np.median(off[j - run: j], axis=0)
        if float(np.hypot(*shift)) > STEP_PX:
            return True
    return False


def _on_scenery(frames: np.ndarray, background: np.ndarray, tracks: list, frames_asked: np.ndarray,
                win: Window) -> np.ndarray:
    """(m, N) bool: per track of ``tracks`` (m tracks' pixels (N, 2)) the frames among
    ``frames_asked`` (N,) in which its footprint (the window at its pixel, shrunk to 80%) shows
    the static ``background`` (grey): fewer than 15% of its pixels differ from it by more than
    12 grey levels and 4 robust SDs of the whole frame's difference from it (its noise, as the
    scenery is most of the frame). Each frame's difference is taken once for all tracks."""
    out = np.zeros((len(tracks), len(frames_asked)), bool)
    for k in np.flatnonzero(frames_asked):
        d = cv2.absdiff(as_gray(frames[k]), background)
        thr = max(12.0, 4.0 * 1.4826 * float(np.median(d[::4, ::4])))
        for t, px in enumerate(tracks):
            if np.all(np.isfinite(px[k])):
                inside = polygon_mask(d.shape, window_corners(px[k], win, shrink=0.8)) > 0
                out[t, k] = bool(inside.any()) and float((d[inside] > thr).mean()) < 0.15
    return out


def _cross_check(tracks: Tracks, colour: dict, methods: list[str], directions=None, k0: int = 0, gaps=None,
                 scenery=None, probation=()) -> tuple[Tracks, np.ndarray, np.ndarray]:
    """Compare each KLT-tracked object with its colour track where both measured well
    (colour quality >= 0.9), after removing the offset between the points the two measure
    (:func:`_offset_residuals`: affine in the image position; the motion is what must agree).

    First, with ``directions`` ((n,) unit image vectors down each object's path) and the
    frame ``k0`` in which the objects rest: a KLT track that goes up the path while the
    colour track goes down it (:func:`_follows_a_hand`) is replaced by the colour track.
    With ``gaps`` ((n, n) px; :func:`_pair_gaps`): a KLT track that sits inside another
    object (:func:`_overlaps`; its features moved onto the other object at a collision) is
    replaced by the colour track if that one never does and the KLT track does in at least
    :data:`CAUGHT_FRAMES` frames; else those frames are dropped.

    A KLT track whose offset from a well-measured colour track shifts by more than
    :data:`STEP_PX` (:func:`_klt_stepped`: it jumped at a turn or an impact, or stuck to the
    scenery) is replaced by the colour track.

    Where they disagree in general (median distance over :data:`CROSS_CHECK_AGREE_PX`), KLT is
    kept, unless (with ``scenery`` = (frames (N, H, W, 3), grey background or None, (n,)
    windows)) its footprint shows the background (:func:`_on_scenery`: its features caught
    on an edge of the scenery while the object moved on) in at least :data:`CAUGHT_FRAMES`
    frames in which the colour track's does not: the colour track replaces it.

    Where they agree in general (median distance at most :data:`CROSS_CHECK_AGREE_PX`): if
    the colour track is the steadier of the two (its noise SD from third differences,
    :func:`estimate_noise_sd`, under :data:`STEADIER` times KLT's), it replaces the KLT track
    (``methods[i]`` becomes "colour"; a textured object measured by its whole matte is often
    more precise than by a few features, under motion blur and perspective); else the KLT
    frames farther than :data:`CROSS_CHECK_PX` from it are dropped (invalid, quality 0).
    ``methods`` is updated in place.

    Objects in ``probation`` (plain objects whose colour track was lost, followed by KLT after
    it) keep their KLT track only where it agreed with the colour track (median distance at
    most :data:`CROSS_CHECK_AGREE_PX`) and no other object's colour track was lost: only where
    the others are measured can a KLT track that moved onto one of them be caught. Else the
    colour track replaces it, its frames from the loss on unmeasured. A steadier colour track
    does not replace a KLT track on probation: it stops where it was lost, and KLT goes on
    (measured: fit_world's plain_persp_9, object 1 measured in 40 of 65 frames instead of 65,
    and phi, which needs the frames after the impact, unidentified).

    Returns:
        the tracks, (n,) median distances (px; NaN where not compared), (n,) frames dropped.
    """
    n = tracks.pixels.shape[1]
    agree, dropped = np.full(n, np.nan), np.zeros(n, int)
    px, valid, count, quality = (np.array(f, copy=True) for f in tracks)

    def take_colour(i, px_c, valid_c, q_c):
        methods[i] = "colour"
        px[:, i], valid[:, i], count[:, i], quality[:, i] = px_c, valid_c, valid_c.astype(int), q_c

    def others(i):  # the other objects where measured well, by their colour tracks where they have one
        js = [j for j in range(n) if j != i]
        return ([(colour[j][0], colour[j][1] & (colour[j][2] >= QUALITY_MIN)) if j in colour
                 else (px[:, j], valid[:, j] & (quality[:, j] >= QUALITY_MIN)) for j in js],
                [gaps[i][j] for j in js])

    for i in range(n):
        if methods[i] != "features" or i not in colour:
            continue
        px_c, valid_c, q_c = colour[i][:3]
        if directions is not None and _follows_a_hand((px[:, i], valid[:, i]), (px_c, valid_c), k0, directions[i]):
            take_colour(i, px_c, valid_c, q_c)
            continue
        if gaps is not None and n > 1:
            around = others(i)
            inside = _overlaps(px[:, i], valid[:, i], *around)
            if inside.any():
                if inside.sum() >= CAUGHT_FRAMES and not _overlaps(px_c, valid_c & (q_c >= QUALITY_MIN), *around).any():
                    take_colour(i, px_c, valid_c, q_c)
                    continue
                dropped[i] += int(inside.sum())
                valid[inside, i], quality[inside, i] = False, 0.0
        if _klt_stepped(px[:, i], valid[:, i], px_c, valid_c & (q_c >= STEP_QUALITY)):
            take_colour(i, px_c, valid_c, q_c)
            continue
        both = valid[:, i] & (q_c >= 0.9)
        if both.sum() < 8:
            continue
        d = _offset_residuals(px[:, i], px_c, both)
        agree[i] = float(np.median(d[both]))
        if agree[i] > CROSS_CHECK_AGREE_PX:  # they disagree everywhere: the colour track is the suspect one ...
            if scenery is not None and scenery[1] is not None:  # ... unless KLT sits on the scenery
                frames, background, wins = scenery
                apart = valid[:, i] & valid_c & (d > CROSS_CHECK_PX)
                klt_on, colour_on = _on_scenery(frames, background, [px[:, i], px_c], apart, wins[i])
                if (klt_on & ~colour_on).sum() >= CAUGHT_FRAMES:
                    take_colour(i, px_c, valid_c, q_c)
            continue
        sd_klt = max(estimate_noise_sd(px[both, i, j]) for j in range(2))
        sd_col = max(estimate_noise_sd(px_c[both, j]) for j in range(2))
        # the steadier track, but not a colour track that was lost (KLT on probation goes on after it)
        if sd_col < STEADIER * sd_klt and i not in probation:
            take_colour(i, px_c, valid_c, q_c)
            continue
        bad = both & (d > CROSS_CHECK_PX)
        dropped[i] += int(bad.sum())
        valid[bad, i], quality[bad, i] = False, 0.0
    for i in probation:  # KLT kept only where it agreed before the colour track was lost and the others go on
        others_lost = any(j != i and (j not in colour or colour[j][3] >= 0) for j in range(n))
        if methods[i] == "features" and (others_lost or not agree[i] <= CROSS_CHECK_AGREE_PX):
            take_colour(i, *colour[i][:3])
    return Tracks(px, valid, count, quality), agree, dropped


def _pair_gaps(wins) -> np.ndarray:
    """(n, n) px: centres of two objects closer than half their touching distance along the
    path (half the sum of their half lengths) mean one track sits inside the other object."""
    half = np.array([float(w.half[0]) for w in wins])
    return 0.5 * (half[:, None] + half[None, :])
