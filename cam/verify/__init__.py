"""The `verify` stage: an independent measurement of what the G-code programs leave on the part.

`part` measures every program on samples of the part's mesh (what the stage reports: reachable share,
finished share of the reachable, gouge by cutting moves and rapids, unfinished area by reason);
`measure` does the same on fitted patches, for what a patch program claims (`claims`), with `solid`'s
reach test on the patches' samples (`part` lowers the ball onto the mesh's triangles: `cam.mesh.dropcutter`). The ball is swept along the parsed program (the capsules of `cam.gcode.sweep`).
Nothing here imports the planner.
"""

from cam.verify.claims import claimed_patches
from cam.verify.measure import Measurement, heat_colors, measure_program, pass_width_mm

__all__ = ["Measurement", "claimed_patches", "heat_colors", "measure_program", "pass_width_mm"]
