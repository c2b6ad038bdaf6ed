"""Reporting at the edge: console summary (``console.py``), a fit's files (``fit_files.py``:
``result.json``, ``posterior.nc``, figures, overlay), atomic JSON and netCDF writes
(``results.py``), figures (``figures.py``) and the overlay video (``overlay.py``)."""
