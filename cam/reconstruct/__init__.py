"""IGR surface reconstruction: a point cloud in, a watertight triangle mesh out.

:func:`reconstruct_surface` is the entry point; the modules hold one step each:
``normals`` (estimate and orient), ``prior`` (closed-form start of the grid
field), ``fields`` (grid pyramid and the paper's MLP), ``train`` (the IGR loss
and Adam loop), ``extract`` (marching cubes and component selection),
``sharpen`` (the creases marching cubes bevels, restored), ``fidelity``
(the self-check: the mesh against its own cloud), ``presets`` (named option sets).
"""

from cam.reconstruct.fidelity import FidelityError
from cam.reconstruct.normals import NormalsError, estimate_normals
from cam.reconstruct.presets import PRESETS
from cam.reconstruct.surface import MIN_POINTS, Reconstruction, reconstruct_surface
from cam.reconstruct.train import DivergedError

__all__ = [
    "MIN_POINTS",
    "PRESETS",
    "DivergedError",
    "FidelityError",
    "NormalsError",
    "Reconstruction",
    "estimate_normals",
    "reconstruct_surface",
]
