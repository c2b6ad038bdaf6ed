"""The videos of a sweep and the scene file of each.

Two sources, used together (explicit videos first, then the dataset's, each sorted as given
or by path, so that a video's index is the same in every process of a sweep):

* ``videos``: explicit video files; each entry a path (its scene is the video's name with
  ``.yaml``, as ``fit`` finds it) or ``{path: VIDEO, scene: SCENE.yaml}``.
* ``dataset``: a folder in the Physics 101 layout,
  ``<dataset>/scenarios/ramp/<setting>/<object>/<trial>/<camera>.mp4`` (or the ``ramp``
  folder itself). The ramp angle is fixed per setting, so the scene comes from the folders,
  nearest first: ``<camera>.yaml`` next to the video, then ``scene.yaml`` in the trial, object
  or setting folder, then the sweep config's ``scenes`` map from setting name (exact, else the
  first matching glob pattern such as ``"20_*"``) to scene file. A setting with none of these
  is a one-line error naming the folder and the fix.

Relative paths are read against the directory the sweep was started in, and a scene file
not found there against the repository root (so ``scenes/ramp_20.yaml`` works anywhere).
"""

from __future__ import annotations

import fnmatch
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

from galileo_jax.errors import GalileoError

METHODS = ("grad", "mh", "cnn", "seed")
#: Repository root: relative scene files not found from the working directory are looked up here.
ROOT = Path(__file__).resolve().parents[2]
#: Scene file looked for in a trial, object or setting folder of a dataset.
FOLDER_SCENE = "scene.yaml"


@dataclass(frozen=True)
class VideoItem:
    """One video of a sweep.

    Attributes:
        id: a stable name: ``<setting>/<object>/<trial>`` for dataset videos, the path as given
            for explicit ones.
        video: absolute path of the video.
        scene: absolute path of its scene file.
        setting: the Physics 101 setting folder's name (None for explicit videos).
        scene_from: where the scene came from: ``video`` (next to the video), ``folder``
            (a ``scene.yaml`` in the dataset), ``config`` (the ``scenes`` map) or ``explicit``.
    """

    id: str
    video: Path
    scene: Path
    setting: str | None = None
    scene_from: str = "video"


def absolute(path: str | Path, base: Path | None = None) -> Path:
    """``path`` made absolute against ``base`` (default: the current directory)."""
    path = Path(path).expanduser()
    return path if path.is_absolute() else (base or Path.cwd()) / path


def scene_file(path: str | Path, base: Path | None = None) -> Path:
    """A scene file given in the sweep config: against ``base``, else the repository root.

    Raises:
        GalileoError: found in neither place.
    """
    first = absolute(path, base)
    for candidate in (first, ROOT / path):
        if candidate.is_file():
            return candidate.resolve()
    raise GalileoError(f"scene file {path} not found (looked in {first.parent} and {ROOT}); fix the path in the "
                       f"sweep config (see scenes/ramp_20.yaml)")


def explicit_videos(videos: Iterable[str | Mapping], base: Path | None = None) -> list[VideoItem]:
    """The explicit videos of a sweep: paths, or mappings ``{path, scene}``.

    Raises:
        GalileoError: a missing video or scene file, or a malformed entry.
    """
    from galileo_jax.cli import check_video, scene_path

    out = []
    for entry in videos:
        if isinstance(entry, Mapping):
            if "path" not in entry or set(entry) - {"path", "scene"}:
                raise GalileoError(f"videos entry {dict(entry)}: give a path, or {{path: VIDEO, scene: SCENE.yaml}}")
            name, scene = str(entry["path"]), entry.get("scene")
        else:
            name, scene = str(entry), None
        video = check_video(absolute(name, base)).resolve()
        if scene is None:
            out.append(VideoItem(name, video, scene_path(video, None).resolve(), None, "video"))
        else:
            out.append(VideoItem(name, video, scene_file(scene, base), None, "explicit"))
    return out


def ramp_folder(dataset: str | Path, base: Path | None = None) -> Path:
    """``<dataset>/scenarios/ramp``, or ``dataset`` itself when it is that ramp folder.

    Raises:
        GalileoError: the folder does not exist.
    """
    root = absolute(dataset, base)
    if not root.is_dir():
        raise GalileoError(f"dataset folder {root} not found; give dataset=DIR, the Physics 101 folder that holds "
                           f"scenarios/ramp/<setting>/<object>/<trial>/Camera_1.mp4")
    ramp = root / "scenarios" / "ramp"
    return ramp if ramp.is_dir() else root


def _setting_scene(video: Path, setting_dir: Path, scenes: Mapping[str, str],
                   base: Path | None) -> tuple[Path, str]:
    """(scene file, where from) of a dataset video (module docstring's order)."""
    own = video.with_suffix(".yaml")
    if own.is_file():
        return own.resolve(), "video"
    for folder in (video.parent, video.parent.parent, setting_dir):
        if (folder / FOLDER_SCENE).is_file():
            return (folder / FOLDER_SCENE).resolve(), "folder"
    name = setting_dir.name
    keys = [k for k in scenes if str(k) == name] or [k for k in scenes if fnmatch.fnmatchcase(name, str(k))]
    if keys:
        return scene_file(scenes[keys[0]], base), "config"
    raise GalileoError(f"setting folder {setting_dir} has no scene: put a {FOLDER_SCENE} in it (see "
                       f"scenes/ramp_20.yaml) or map the setting in the sweep config: +scenes.{name}=SCENE.yaml")


def enumerate_dataset(dataset: str | Path, scenes: Mapping[str, str] | None = None, camera: str = "Camera_1",
                      base: Path | None = None) -> list[VideoItem]:
    """Every ``<setting>/<object>/<trial>/<camera>.mp4`` of a Physics 101 ramp folder, sorted, with its scene.

    Args:
        dataset: the dataset folder (or its ``scenarios/ramp`` folder).
        scenes: setting name (or glob pattern) -> scene file, used when the folders hold none.
        camera: the video file's stem (Physics 101 has Camera_1 ... per trial).
        base: folder that relative paths are read against (default: the current directory).

    Raises:
        GalileoError: missing dataset folder, no video in it, a setting without a scene, or a
            missing scene file.
    """
    ramp = ramp_folder(dataset, base)
    videos = sorted(p for p in ramp.glob(f"*/*/*/{camera}.mp4") if p.is_file())
    if not videos:
        raise GalileoError(f"dataset {ramp} holds no videos: expected <setting>/<object>/<trial>/{camera}.mp4 "
                           f"under it; check dataset= and camera=")
    out = []
    for video in videos:
        setting_dir = video.parents[2]
        scene, where = _setting_scene(video, setting_dir, scenes or {}, base)
        vid = "/".join(video.relative_to(ramp).parts[:3])
        out.append(VideoItem(vid, video.resolve(), scene, setting_dir.name, where))
    return out


def sweep_inputs(videos: Iterable[str | Mapping] = (), dataset: str | Path | None = None,
                 scenes: Mapping[str, str] | None = None, camera: str = "Camera_1",
                 base: Path | None = None) -> list[VideoItem]:
    """The sweep's videos: the explicit ones, then the dataset's; every scene file is loaded once
    (so a bad scene stops the sweep before any job starts).

    Raises:
        GalileoError: nothing to fit, or any error of :func:`explicit_videos`,
            :func:`enumerate_dataset` or :func:`galileo_jax.scene.load_scene`.
    """
    from galileo_jax.scene import load_scene

    items = explicit_videos(list(videos), base)
    if dataset is not None and str(dataset) != "":
        items += enumerate_dataset(dataset, scenes, camera, base)
    if not items:
        raise GalileoError("nothing to fit: give dataset=DIR (Physics 101 layout) or videos=[a.mp4,b.mp4]")
    for scene in dict.fromkeys(item.scene for item in items):
        load_scene(scene)
    return items


def check_method(method: str) -> str:
    """``method`` if it is one of :data:`METHODS`.

    Raises:
        GalileoError: an unknown method.
    """
    if method not in METHODS:
        raise GalileoError(f"unknown method {method!r}; choose one or more of {', '.join(METHODS)} "
                           f"(method=grad,mh sweeps several)")
    return method
