"""The observation stage: video -> tracks -> :class:`~galileo_jax.observation.Observation`.

* :mod:`.video`: :func:`read_video` (the only file I/O here).
* :mod:`.tracks`: what trackers return (:class:`Tracks`), object footprints
  (:class:`Window`, :func:`object_windows`) and the grey :func:`background_model`.
* :mod:`.klt`: :func:`track_objects`, KLT tracks of textured objects, held to their look in
  the start frame by :mod:`.tether`.
* :mod:`.matte`: :func:`track_matte`, objects without texture by their colour matte: its
  colour model in :mod:`.colour` (background, colours, the matte), one frame's centre in
  :mod:`.measure`, the rough pass that finds the object first in :mod:`.rough`.
* :mod:`.outline`: :func:`track_circles`, rolling round objects by their outline.
* :mod:`.track`: :func:`track_scene`, each object by the method that suits it.
* :mod:`.find`: :func:`find_objects` / :func:`locate_objects`, start pixels from motion and
  the scene's geometry.
* :mod:`.profile`: :func:`observe` (pixels -> metres, velocity profile, noise SD, release
  time, fit mask).
"""

from galileo_jax.observe.find import find_objects, locate_objects
from galileo_jax.observe.klt import track_objects
from galileo_jax.observe.matte import track_matte
from galileo_jax.observe.outline import track_circles
from galileo_jax.observe.profile import estimate_release_time, observation_from_tracks, observe
from galileo_jax.observe.track import SceneTracks, track_scene
from galileo_jax.observe.tracks import Tracks, Window, background_model, estimate_noise_sd, object_windows
from galileo_jax.observe.video import VideoClip, clip_from_frames, read_video

__all__ = [
    "SceneTracks", "Tracks", "VideoClip", "Window", "background_model", "clip_from_frames", "estimate_noise_sd",
    "estimate_release_time", "find_objects", "locate_objects", "object_windows", "observation_from_tracks",
    "observe", "read_video", "track_circles", "track_matte", "track_objects", "track_scene",
]
