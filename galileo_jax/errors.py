"""User-facing errors.

Every mistake a user can make (missing file, not a video, bad scene file, unknown option,
object never moves, track lost) is raised as a :class:`GalileoError` whose message is one
line naming the problem and the fix. The command-line entry points catch it, print the line
and exit with a non-zero status; no traceback is shown.
"""

from __future__ import annotations

import functools
import sys
from typing import Callable


class GalileoError(Exception):
    """A user mistake or unusable input; ``str(err)`` is one line: problem, then fix."""

    exit_code = 2


class SceneError(GalileoError):
    """The scene file is missing, unreadable, or describes an impossible scene."""


class VideoError(GalileoError):
    """The video is missing, unreadable, or too short."""


class TrackingError(GalileoError):
    """An object could not be found or its track was lost, or it never moves.

    ``object_index`` is the 0-based index (within the tracked group) of the object concerned,
    or None; ``at_start`` is True when the tracker could not start on it at all (too few
    features, no colour of its own), False when it lost it later; ``frame`` the video frame at
    which it was lost, where the tracker knows it (else None)."""

    def __init__(self, message: str, object_index: int | None = None, at_start: bool = False,
                 frame: int | None = None):
        super().__init__(message)
        self.object_index = object_index
        self.at_start = at_start
        self.frame = frame


def cli_entry(main: Callable[[list[str] | None], int]) -> Callable[[list[str] | None], int]:
    """Wrap a CLI ``main(argv) -> exit code`` so user errors print one line and exit non-zero."""

    @functools.wraps(main)
    def wrapped(argv: list[str] | None = None) -> int:
        try:
            return main(argv)
        except GalileoError as err:
            print(f"error: {err}", file=sys.stderr)
            return err.exit_code
        except KeyboardInterrupt:
            print("error: interrupted; no result was written", file=sys.stderr)
            return 130

    return wrapped
