"""How far denoising moved the part: the check that keeps a filter from passing on another shape.

MeshTGV removes noise, which moves a surface by about the noise's amplitude. On a mesh it was not made
for (a CAD export whose faces are mostly slivers) it can shrink the part instead: the bench's pocket
block lost 94 % of its volume and its walls moved 22 mm. Measured on Fandisk, Block and the Kinect cone
with their benchmark noise, the input's vertices end at most 1.8 % of the part's diagonal from the
filtered surface and a closed part keeps its volume to 0.1 %; the bounds below are well above that.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cam.mesh.closest import closest_points, mesh_index
from cam.mesh.rows import unique_pairs

__all__ = ["MAX_SHIFT_OF_DIAGONAL", "MAX_VOLUME_CHANGE", "Shift", "measure_shift"]

#: The farthest an input vertex may end from the filtered surface, as a share of the part's diagonal.
MAX_SHIFT_OF_DIAGONAL = 0.05
#: The largest relative change of a closed part's volume.
MAX_VOLUME_CHANGE = 0.05


@dataclass(frozen=True)
class Shift:
    """What the filter did to the shape.

    Attributes
    ----------
    max_mm : float
        Largest distance from an input vertex to the filtered surface, mm.
    diagonal_mm : float
        The input's bounding-box diagonal, mm.
    volume_ratio : float or None
        Filtered over input volume (None when the mesh is not closed: an open scan has none).
    """

    max_mm: float
    diagonal_mm: float
    volume_ratio: float | None

    @property
    def too_far(self) -> bool:
        """Whether the filtered mesh is another shape rather than the input without its noise."""
        moved = self.max_mm > MAX_SHIFT_OF_DIAGONAL * self.diagonal_mm
        shrunk = self.volume_ratio is not None and abs(self.volume_ratio - 1.0) > MAX_VOLUME_CHANGE
        return moved or shrunk

    def describe(self) -> str:
        """One sentence a user can read."""
        share = self.max_mm / self.diagonal_mm
        text = f"the surface moved by up to {self.max_mm:.3g} mm ({share:.1%} of the part's diagonal"
        if self.volume_ratio is not None:
            text += f"; volume ×{self.volume_ratio:.3f}"
        return text + ")"


def _volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def _closed(faces: np.ndarray) -> bool:
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = unique_pairs(edges, return_counts=True)
    return bool(np.all(counts == 2))


def measure_shift(vertices: np.ndarray, filtered: np.ndarray, faces: np.ndarray) -> Shift:
    """How far `filtered` (the same faces) lies from `vertices`.

    Parameters
    ----------
    vertices, filtered : (n, 3) float
        The mesh before and after filtering, mm.
    faces : (m, 3) int
        Its triangles.

    Returns
    -------
    Shift
    """
    V = np.asarray(vertices, dtype=np.float64)
    W = np.asarray(filtered, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    if V.shape != W.shape:
        raise ValueError(f"the filtered mesh must have the input's vertices, got {W.shape} for {V.shape}")
    moved = closest_points(mesh_index(W, F), V)[1]
    ratio = None
    if _closed(F):
        before = _volume(V, F)
        ratio = _volume(W, F) / before if abs(before) > 0 else None
    return Shift(max_mm=float(moved.max(initial=0.0)), diagonal_mm=float(np.linalg.norm(np.ptp(V, axis=0))),
                 volume_ratio=ratio)
