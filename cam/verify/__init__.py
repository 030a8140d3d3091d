"""Verify: an independent measurement of a G-code program against the fitted surfaces (see measure.py)."""

from cam.verify.measure import Measurement, heat_colors, measure_program

__all__ = ["Measurement", "heat_colors", "measure_program"]
