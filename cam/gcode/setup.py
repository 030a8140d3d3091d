"""A setup: how the part sits on the machine, the frame its program's coordinates are written in."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Setup"]


@dataclass(frozen=True, eq=False)
class Setup:
    """How the part sits on the machine: machine point = rotation · part point + translation; tool axis =
    machine +Z.

    Attributes
    ----------
    id : int
        The setup id of `setup.json`.
    rotation : (3, 3) float64
        Proper rotation from the part frame to the machine frame.
    translation : (3,) float64
        In mm.
    """

    id: int
    rotation: np.ndarray
    translation: np.ndarray

    @property
    def tool_axis_part(self) -> np.ndarray:
        """The tool axis (machine +Z) in the part frame: (3,) float64, unit."""
        return self.rotation.T @ np.array([0.0, 0.0, 1.0])

    def to_part(self, point: np.ndarray) -> np.ndarray:
        """The part-frame point of a machine-frame one.

        Parameters
        ----------
        point : (3,) array_like of float
            Machine-frame point in mm.

        Returns
        -------
        point : (3,) float64
            Part-frame point in mm.
        """
        return self.rotation.T @ (np.asarray(point, dtype=np.float64) - self.translation)

    def to_machine(self, points: np.ndarray, *, direction: bool = False) -> np.ndarray:
        """Machine-frame coordinates of part-frame points (or, with `direction`, of vectors: no translation).

        Parameters
        ----------
        points : (..., 3) array_like of float
            Part-frame points in mm (or unit vectors).
        direction : bool
            Rotate only (normals, axes).

        Returns
        -------
        (..., 3) float64
        """
        out = np.asarray(points, dtype=np.float64) @ self.rotation.T
        return out if direction else out + self.translation
