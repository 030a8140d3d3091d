"""The `denoise` stage: MeshTGV (TGV on face normals by variable splitting and an augmented Lagrangian,
then the vertex update). `mesh_tgv` holds the entry point, `tgv` the normal filter, `vertices` the
vertex update."""

from cam.denoise.mesh_tgv import DenoiseResult, denoise_mesh

__all__ = ["DenoiseResult", "denoise_mesh"]
