"""The `plan` stage: tool paths with a certified scallop height, programs per setup.

`job.plan_job` plans every patch of every setup; `patch.plan_patch` one patch. One concept per
module: `scallop` (the exact scallop relations), `grid` (Algorithm 1 rings), `rings` (contour-parallel
rings joined into a spiral, corner pockets), `edge` (the first ring's inset), `chord` (points along the
passes), `gouge` (checks against every patch), `reach` (the rectangle the ball reaches), `region`
(the rectangle free of folds and tight hollows), `access` (setups), `link` (retracts and order),
`errors` (what is reported instead of a plan).
"""

from cam.plan.job import Plan, SetupPlan, plan_job, program_name
from cam.plan.patch import PatchPlan, plan_patch

__all__ = ["PatchPlan", "Plan", "SetupPlan", "plan_job", "plan_patch", "program_name"]
