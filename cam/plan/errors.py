"""What the planner reports instead of a plan: a patch it cannot finish, and why."""

from __future__ import annotations

import numpy as np

from cam import GeometryError

__all__ = ["SMALLEST_BALL_RADIUS_MM", "NotPlannable", "TooConcave", "Unreachable", "concave_message"]


class NotPlannable(GeometryError):
    """The planner found no pass layout that keeps its bound on this patch (degenerate geometry)."""


class Unreachable(GeometryError):
    """No part of the patch can be machined from this setup."""


class TooConcave(GeometryError):
    """The patch holds a concave radius of curvature not larger than the tool radius.

    Parameters
    ----------
    message : str
        What the user reads (`concave_message`).
    radius_mm : float
        The concave radius of curvature found, mm.
    point : (3,) float64
        Where it was found, mm.
    uv : (k, 2) float or None
        Parameters of every sample found too concave; default none.

    Attributes
    ----------
    radius_mm : float
        The concave radius of curvature found, mm.
    point : (3,) float64
        Where it was found, mm, in the frame of the surface it was found on (the planner names it in
        the part frame where it can).
    uv : (k, 2) float
        Every sample found too concave, as (u, v); empty (0, 2) when none was given.
    """

    def __init__(self, message: str, *, radius_mm: float, point: np.ndarray, uv: np.ndarray | None = None) -> None:
        super().__init__(message)
        self.radius_mm = radius_mm
        self.point = point
        self.uv = np.zeros((0, 2)) if uv is None else uv  # float (k, 2): every sample found too concave


# The smallest ball end mills sold are 0.1 mm across: a hollow tighter than that is no feature a ball can
# be bought for, and on a fitted surface it is far more often a ripple of the fit than of the part.
SMALLEST_BALL_RADIUS_MM = 0.05


def concave_message(radius_mm: float, tool_radius_mm: float, point: np.ndarray) -> str:
    """What a user reads about a hollow the ball does not fit.

    Parameters
    ----------
    radius_mm : float
        The concave radius of curvature found, mm.
    tool_radius_mm : float
        Ball radius, mm.
    point : (3,) float
        Where the hollow is, mm (named rounded to 3 decimals).

    Returns
    -------
    str
        The radius, the tool radius and the point, then the advice: below `SMALLEST_BALL_RADIUS_MM`
        that the fitted surface likely ripples there (no ball is that small), otherwise to use a
        smaller ball.
    """
    where = (f"concave radius of curvature {radius_mm:.3f} mm is not larger than the tool radius "
             f"{tool_radius_mm:g} mm near {np.round(point, 3).tolist()}")
    if radius_mm < SMALLEST_BALL_RADIUS_MM:
        return (f"{where}; no ball end mill is that small: if the part has no such corner there, the fitted "
                "surface ripples (surfaces.json gives each patch's fit error)")
    return f"{where}; use a smaller ball"
