"""galileo_jax: infer physical properties of objects on an inclined plane from video.

Pipeline, one subpackage (or module) per stage:

    video --observe/--> tracks --> velocity profiles (observation.py: observed, with noise)
    scene.py --physics/--> MuJoCo model --> velocity profiles (simulated; effects/ extend it)
    likelihood.py(observed, simulated) --inference/ (grad | mh | cnn)--> posterior / estimate
    criticism/: residuals per phase, verdict; diagnose: which physical effect is missing
    report/ (console, JSON, posterior.nc, figures, overlay video; predict.py)
    command lines: fit.py, diagnose.py, train.py, sweep/ (thin, over pipeline.py); synth/ renders
    test videos with exact ground truth

Only the mass ratio phi = (m1 - m2) / (m1 + m2) is identifiable from velocities; the
absolute mass scale is fixed only by a known mass in the scene file.
"""

import os as _os

# MuJoCo picks its OpenGL backend when it is imported: EGL renders offscreen on a machine without
# a display (with Mesa, also without a GPU). The one place this is set; a user's choice stands.
_os.environ.setdefault("MUJOCO_GL", "egl")

# FFmpeg (inside OpenCV) logs container errors itself; we report them as one-line errors.
_os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
_os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")

# Double precision for the whole package (JAX's default is float32). Measured on the 20 degree
# two-box scene, 2.5 s at 240 Hz (issue 3 note): with float32, scaling both masses by 10
# moved the simulated objects by up to 7.9 mm (the profile must depend on m1/m2 only), with
# float64 by 2e-8 m; the batched MJX rollout is also 1.2-1.4x FASTER on CPU in float64
# (batch 16: 155 vs 133 rollouts/s), and equally fast to compile. This is a process-wide JAX
# setting: set it before creating arrays (importing galileo_jax does).
import jax as _jax  # noqa: E402

_jax.config.update("jax_enable_x64", True)

__version__ = "0.1.0"
