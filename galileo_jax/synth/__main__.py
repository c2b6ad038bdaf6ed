"""``python -m galileo_jax.synth``: see :mod:`galileo_jax.synth.cli`."""

import os
import sys

try:  # MuJoCo loads its OpenGL backend (MUJOCO_GL) on import: a missing libEGL fails here.
    import mujoco  # noqa: F401
except Exception as _err:  # noqa: BLE001
    print(f"error: cannot load MuJoCo with MUJOCO_GL={os.environ.get('MUJOCO_GL')} ({type(_err).__name__}: {_err}); "
          f"install libegl1 libegl-mesa0 libopengl0 libgl1-mesa-dri, or set MUJOCO_GL to a working backend",
          file=sys.stderr)
    raise SystemExit(2) from None

from galileo_jax.synth.cli import main  # noqa: E402

raise SystemExit(main())
