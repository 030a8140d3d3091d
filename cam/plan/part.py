"""The part as one setup's ball sees it: drop-cutter heights, closest points and the table it stands on.

The part is clamped on the machine table at its lowest point: the ball centre never goes below the
table plus its radius, so beside a wall that reaches the bottom of the part the ball rests at that
height (and touches the wall up from there), and nothing below it is reachable.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cam.gcode.setup import Setup
from cam.mesh.closest import MeshIndex, closest_points, mesh_index, triangle_normals
from cam.mesh.dropcutter import DropIndex, ball_clears, drop_ball, drop_index

__all__ = ["REACH_TOL_MM", "SetupPart", "setup_part"]

#: A ball within this of a surface counts as touching it (and a lowered ball as not cutting it).
REACH_TOL_MM = 1e-3


@dataclass(frozen=True, eq=False)
class SetupPart:
    """The part in a setup's machine frame, for one ball.

    Attributes
    ----------
    setup : Setup
        The setup whose machine frame the part is in.
    index : DropIndex
        The part's triangles bucketed for the ball.
    mesh : MeshIndex or None
        The same triangles for closest-point queries; None in a part made for reach alone
        (`setup_part(..., closest=False)`), whose `nearest` and `wall_normals` then raise.
    floor_z : float
        The table: the part's lowest z, mm. The ball centre stays at least r above it.
    """

    setup: Setup
    index: DropIndex
    mesh: MeshIndex | None
    floor_z: float

    @property
    def radius_mm(self) -> float:
        """The ball radius, mm."""
        return self.index.radius_mm

    def drop(self, xy: np.ndarray) -> np.ndarray:
        """Lowest ball-centre height over each point (n, 2) that cuts neither the part nor the table: (n,) mm."""
        return np.maximum(drop_ball(self.index, xy), self.floor_z + self.radius_mm)

    def clears(self, xy: np.ndarray, z: np.ndarray | float) -> np.ndarray:
        """bool (n,): ``self.drop(xy) <= z``, the ball centred at height z (n,) over each point (n, 2) cutting
        neither the table nor the part, answered without the drop heights (`ball_clears`)."""
        q = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        limit = np.broadcast_to(np.asarray(z, dtype=np.float64), (len(q),))
        return (self.floor_z + self.radius_mm <= limit) & ball_clears(self.index, q, limit)

    def contact(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Drop-cutter heights (n,) and the z of the part's normal where the ball touches it (NaN where the
        ball rests on the table rather than on the part)."""
        z, point = drop_ball(self.index, xy, contact=True)
        table = self.floor_z + self.radius_mm
        normal_z = np.where(z >= table, (z - point[:, 2]) / self.radius_mm, np.nan)
        return np.maximum(z, table), normal_z

    def nearest(self, centres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance (n,) mm from each ball centre (n, 3) to the part, and the part's unit normal (n, 3) where
        it is nearest (from the foot towards the centre: the contact normal of a ball touching it there)."""
        if self.mesh is None:
            raise ValueError("this SetupPart was made for reach alone (setup_part(..., closest=False))")
        foot, _, tri, _ = closest_points(self.mesh, centres)
        d = centres - foot
        length = np.linalg.norm(d, axis=1, keepdims=True)
        normal = np.where(length > 1e-9, d / np.maximum(length, 1e-300), triangle_normals(self.mesh, tri))
        return length[:, 0], normal

    def clear_between(self, a: np.ndarray, b: np.ndarray, *, tol_mm: float) -> bool:
        """Whether the ball centre can move straight from a (3,) to b (3,) (mm) without cutting the part or
        the table by more than about 2·tol_mm (`clear_moves` of one move)."""
        return bool(self.clear_moves(np.asarray(a)[None], np.asarray(b)[None], tol_mm=tol_mm)[0])

    def clear_moves(self, starts: np.ndarray, ends: np.ndarray, *, tol_mm: float) -> np.ndarray:
        """bool (k,): whether the ball centre can move straight from each start (k, 3) to its end (k, 3) (mm)
        without cutting the part or the table by more than about 2·tol_mm.

        The drop-cutter checks centres along the move (each may sit tol_mm low). A part point at least r
        from two centres s apart is at least √(r² − s²/4) ≈ r − s²/8r from the move between them, so the
        centres are spaced s = √(8 r tol) along the move's 3-D length, not its xy length: a steep move
        past the top of a wall is checked as finely as a flat one.
        """
        a, b = np.asarray(starts, dtype=np.float64).reshape(-1, 3), np.asarray(ends, dtype=np.float64).reshape(-1, 3)
        spacing = float(np.sqrt(8.0 * self.radius_mm * tol_mm))
        if not len(a):
            return np.zeros(0, dtype=bool)
        n = np.maximum(np.ceil(np.linalg.norm(b - a, axis=1) / spacing).astype(np.int64), 1)
        first = np.cumsum(n + 1) - (n + 1)  # each move's first centre among all of them
        move = np.repeat(np.arange(len(a)), n + 1)
        t = (np.arange(len(move)) - first[move]) / n[move]
        c = a[move] + t[:, None] * (b - a)[move]
        return np.logical_and.reduceat(self.clears(c[:, :2], c[:, 2] + tol_mm), first)

    def wall_normals(self, centres: np.ndarray) -> np.ndarray:
        """Unit normals (n, 3) of the part where it is nearest to each ball centre (n, 3)."""
        return self.nearest(centres)[1]

    def reaches(self, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """bool (k,): the ball touching each point (centre r along its outward normal) can be lowered there
        without cutting the part or the table (NaN rows: False)."""
        centre = np.asarray(points) + (self.radius_mm + REACH_TOL_MM) * np.asarray(normals)
        ok = np.all(np.isfinite(centre), axis=1)
        out = np.zeros(len(centre), dtype=bool)
        out[ok] = self.clears(centre[ok, :2], centre[ok, 2] + REACH_TOL_MM)
        return out


def setup_part(vertices: np.ndarray, faces: np.ndarray, setup: Setup, *, tool_radius_mm: float,
               closest: bool = True, cell_mm: float | None = None) -> SetupPart:
    """The closed part (part frame, outward) moved into the setup's machine frame, for a ball of this radius.

    Parameters
    ----------
    vertices : (n, 3) float
        mm, part frame.
    faces : (m, 3) int
        Triangles, outward.
    setup : Setup
    tool_radius_mm : float
    closest : bool
        Build the closest-point index too (`SetupPart.nearest`); reach (`SetupPart.reaches`) needs only
        the drop-cutter's, and the setup choice asks it of a dozen candidate axes.
    cell_mm : float or None
        The drop-cutter index's bucket size (`cam.mesh.dropcutter.drop_index`; None: its default). Heights
        and reach are the same for any size: coarser buckets build faster and answer each query slower.

    Returns
    -------
    SetupPart
    """
    V = setup.to_machine(vertices)
    F = np.asarray(faces, dtype=np.int64)
    # Every triangle, not only those facing the tool (enough for a valid solid): a reconstructed mesh can
    # fold over itself, and the README example's did, where a down-facing triangle is met first.
    return SetupPart(setup=setup, index=drop_index(V, F, radius_mm=tool_radius_mm, cell_mm=cell_mm),
                     mesh=mesh_index(V, F) if closest else None, floor_z=float(V[:, 2].min()))
