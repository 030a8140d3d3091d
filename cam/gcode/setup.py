"""A setup: how the part sits on the machine, the frame its program's coordinates are written in."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Setup"]


@dataclass(frozen=True, eq=False)
class Setup:
    """machine point = rotation · part point + translation; tool axis = machine +Z."""

    id: int
    rotation: np.ndarray
    translation: np.ndarray

    @property
    def tool_axis_part(self) -> np.ndarray:
        """The tool axis (machine +Z) in the part frame: float64 (3,), unit."""
        return self.rotation.T @ np.array([0.0, 0.0, 1.0])

    def to_part(self, point: np.ndarray) -> np.ndarray:
        """The part-frame point (float64 (3,), mm) of a machine-frame one."""
        return self.rotation.T @ (np.asarray(point, dtype=np.float64) - self.translation)
