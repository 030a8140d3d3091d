"""The `verify` stage: an independent measurement of what the G-code programs leave on the part.

`measure` sweeps the ball along the parsed program (the capsules of `cam.gcode.sweep`) and measures
scallop, gouge and reach; `claims` reads what each setup's program claims to finish. Nothing here
imports the planner.
"""

from cam.verify.claims import claimed_patches
from cam.verify.measure import Measurement, heat_colors, measure_program, pass_width_mm

__all__ = ["Measurement", "claimed_patches", "heat_colors", "measure_program", "pass_width_mm"]
