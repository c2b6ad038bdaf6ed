"""``python -m galileo_jax.sweep``: see :mod:`galileo_jax.sweep.app`."""

import sys

try:
    from galileo_jax.sweep.app import main
except ModuleNotFoundError as err:  # the sweep extra is not installed
    if err.name not in ("hydra", "omegaconf"):
        raise
    print("error: sweeps need Hydra; install them with: python -m pip install -e \".[sweep]\"", file=sys.stderr)
    sys.exit(2)

sys.exit(main())
