"""The `plan` stage: programs that finish the part within the scallop height, per setup and ball.

`job.plan_job` is the stage without its files. The mesh strategies: `part` (the part in a setup for one
ball: drop-cutter, closest points, the table), `setups` (tool axes chosen for reach), `raster`,
`waterline`, `cleanup`, `finish` (the three for one setup), `cusps` (the scallop between two balls,
measured on the part), `lines` (passes that follow the part), `coverage` (what passes leave on the
part's samples), `link` (order and linking). The patch passes (the paper's): `patch_job` and `patch`
(one patch's rings, certified), `scallop` (the exact relations), `grid` (Algorithm 1), `rings`, `edge`,
`chord`, `gouge`, `reach`, `region`, `access`, `errors`.
"""

from cam.plan.job import JobPlan, ProgramPlan, SurfacesIn, plan_job
from cam.plan.patch import PatchPlan, plan_patch
from cam.plan.patch_job import program_name

__all__ = ["JobPlan", "PatchPlan", "ProgramPlan", "SurfacesIn", "plan_job", "plan_patch", "program_name"]
