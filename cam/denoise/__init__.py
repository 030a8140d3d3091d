"""The `denoise` stage: MeshTGV (TGV on face normals by variable splitting and an augmented Lagrangian,
then the vertex update). `mesh_tgv` holds the entry point, `tgv` the normal filter, `vertices` the
vertex update; `shift` checks that the result is still the part."""

from cam.denoise.mesh_tgv import DenoiseResult, denoise_mesh
from cam.denoise.shift import Shift, measure_shift

__all__ = ["DenoiseResult", "Shift", "denoise_mesh", "measure_shift"]
