"""Reporting at the edge: console summary, JSON result, figures, overlay video."""
