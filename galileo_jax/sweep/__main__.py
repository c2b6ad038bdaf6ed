"""``python -m galileo_jax.sweep`` and the ``galileo-sweep`` command: see :mod:`galileo_jax.sweep.app`."""

import sys


def main() -> int:
    """Run a sweep (:func:`galileo_jax.sweep.app.main`); without the ``sweep`` extra (Hydra),
    print one line that says how to install it and return 2."""
    try:
        from galileo_jax.sweep.app import main as app_main
    except ModuleNotFoundError as err:  # the sweep extra is not installed
        if err.name not in ("hydra", "omegaconf"):
            raise
        print("error: sweeps need Hydra; install them with: python -m pip install -e \".[sweep]\"", file=sys.stderr)
        return 2
    return app_main()


if __name__ == "__main__":
    sys.exit(main())
