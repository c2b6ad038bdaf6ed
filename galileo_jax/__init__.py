"""galileo_jax: infer physical properties of objects on an inclined plane from video.

Pipeline (one module each):

    video --observe--> tracks --profile--> velocity profiles (observed)
    scene --model--> MuJoCo model --simulate--> velocity profiles (simulated)
    likelihood(observed, simulated) --inference (mh | grad)--> posterior / estimate
    report (console, JSON, figures, overlay video, prediction)

Only the mass ratio phi = (m1 - m2) / (m1 + m2) is identifiable from velocities; the
absolute mass scale is fixed only by a known mass in the scene file.
"""

import os as _os

# FFmpeg (inside OpenCV) logs container errors itself; we report them as one-line errors.
_os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
_os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")

__version__ = "0.1.0"
