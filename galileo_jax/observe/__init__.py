"""The observation stage: video -> tracks -> :class:`~galileo_jax.observation.Observation`.

* :mod:`.video`: :func:`read_video` (the only file I/O here).
* :mod:`.track`: :func:`find_objects` / :func:`locate_objects` (start pixels from motion
  and the scene's geometry), :func:`track_objects` (KLT tracks of each object's centre),
  :func:`track_circles` (rolling spheres, by their outline), :func:`track_scene` (each
  object by its kind).
* :mod:`.profile`: :func:`observe` (pixels -> metres, velocity profile, noise SD, release
  time, fit mask).
"""

from galileo_jax.observe.profile import estimate_noise_sd, estimate_release_time, observation_from_tracks, observe
from galileo_jax.observe.track import (Tracks, Window, background_model, find_objects, locate_objects, object_windows,
                                      track_circles, track_objects, track_scene)
from galileo_jax.observe.video import VideoClip, clip_from_frames, read_video

__all__ = [
    "Tracks", "VideoClip", "Window", "background_model", "clip_from_frames", "estimate_noise_sd",
    "estimate_release_time", "find_objects", "locate_objects", "object_windows", "observation_from_tracks",
    "observe", "read_video", "track_circles", "track_objects", "track_scene",
]
